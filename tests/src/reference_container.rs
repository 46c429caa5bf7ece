//! The container plumbing both reference packers share (FORMAT.md §1): reading a file's header
//! and section table without trusting them, and writing a file laid out by §12.1's rule. Written
//! from the text, like the packers (`reference_packed`, `reference_packed_jpeg`), not from
//! nmat-core's code.

use nmat_core::internals::file_checksum;

/// §1.1: the header is 32 bytes.
pub(crate) const HEADER_LEN: usize = 32;
/// §1.2: a section table entry is 16 bytes.
pub(crate) const ENTRY_LEN: usize = 16;
/// §1.2: bit 0 of a section's flags.
pub(crate) const REQUIRED: u32 = 1;

pub(crate) const KIND_MATERIAL: u32 = 1;
pub(crate) const KIND_LEVELS: u32 = 2;
pub(crate) const KIND_MLP: u32 = 3;
pub(crate) const KIND_LATENTS: u32 = 4;
pub(crate) const KIND_JPEG: u32 = 5;
pub(crate) const KIND_PACKED_LATENTS: u32 = 6;
pub(crate) const KIND_PACKED_JPEG: u32 = 7;

/// §12.1, §12.5: a packed section's header is 8 bytes (length u32, coder u8, reserved u8,
/// unpacked_minor u16), then its payload.
pub(crate) const PACKED_HEADER_LEN: usize = 8;
/// The `version_minor` a packed file carries (§1.1).
pub(crate) const PACKED_VERSION_MINOR: u16 = 2;

// ---------------------------------------------------------------------------------------------
// Reading and writing the container (§1)
// ---------------------------------------------------------------------------------------------

pub(crate) fn u16_at(bytes: &[u8], offset: usize) -> Result<u16, String> {
    match bytes.get(offset..offset + 2) {
        Some(b) => Ok(u16::from_le_bytes([b[0], b[1]])),
        None => Err(format!("u16 at {offset} is past the end ({} bytes)", bytes.len())),
    }
}

pub(crate) fn u32_at(bytes: &[u8], offset: usize) -> Result<u32, String> {
    match bytes.get(offset..offset + 4) {
        Some(b) => Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        None => Err(format!("u32 at {offset} is past the end ({} bytes)", bytes.len())),
    }
}

pub(crate) fn u8_at(bytes: &[u8], offset: usize) -> Result<u8, String> {
    bytes.get(offset).copied().ok_or_else(|| format!("byte {offset} is past the end"))
}

pub(crate) fn align4(n: usize) -> usize {
    n.div_ceil(4) * 4
}

/// One entry of the section table and the bytes it points at.
pub(crate) struct Section<'a> {
    pub(crate) kind: u32,
    pub(crate) flags: u32,
    pub(crate) data: &'a [u8],
}

/// The header (verbatim) and the sections of a file, in table order, after checking what §1 asks
/// of every file: magic, major version, header flags and reserved fields, `file_length`, the
/// section count, the table entries (alignment, bounds, no overlap) and the checksum.
pub(crate) fn read_container(bytes: &[u8]) -> Result<([u8; HEADER_LEN], Vec<Section<'_>>), String> {
    let header: [u8; HEADER_LEN] = match bytes.get(..HEADER_LEN) {
        Some(h) => h.try_into().map_err(|_| "header".to_string())?,
        None => return Err(format!("{} bytes: shorter than the header", bytes.len())),
    };
    if &header[0..4] != b"NMAT" {
        return Err("bad magic".into());
    }
    let version_major = u16_at(&header, 4)?;
    if version_major != 2 {
        return Err(format!("version_major {version_major}: only 2 is handled here"));
    }
    // §1.1: bit 0 (2.3's scaled LOD feature) is the only flag.
    if u32_at(&header, 8)? & !1 != 0 {
        return Err("unknown header flags".into());
    }
    let file_length = u32_at(&header, 12)? as usize;
    if file_length != bytes.len() {
        return Err(format!("file_length {file_length} but {} bytes", bytes.len()));
    }
    let section_count = u32_at(&header, 16)? as usize;
    if !(1..=16).contains(&section_count) {
        return Err(format!("section_count {section_count}"));
    }
    if header[24..32].iter().any(|&b| b != 0) {
        return Err("reserved header bytes are not 0".into());
    }
    let table_end = HEADER_LEN + ENTRY_LEN * section_count;
    if table_end > bytes.len() {
        return Err("the section table is past the end".into());
    }
    let stored_checksum = u32_at(&header, 20)?;
    let computed = checksum(bytes);
    if stored_checksum != computed {
        return Err(format!("checksum {stored_checksum:#010x}, computed {computed:#010x}"));
    }

    let mut sections = Vec::new();
    let mut spans: Vec<(usize, usize)> = Vec::new();
    for i in 0..section_count {
        let entry = HEADER_LEN + ENTRY_LEN * i;
        let kind = u32_at(bytes, entry)?;
        let flags = u32_at(bytes, entry + 4)?;
        let offset = u32_at(bytes, entry + 8)? as usize;
        let length = u32_at(bytes, entry + 12)? as usize;
        if flags & !REQUIRED != 0 {
            return Err(format!("section {i}: unknown flags {flags:#x}"));
        }
        if !offset.is_multiple_of(4) || offset < table_end {
            return Err(format!("section {i}: offset {offset}"));
        }
        if offset + length > bytes.len() {
            return Err(format!("section {i}: {offset} + {length} is past the end"));
        }
        for &(start, end) in &spans {
            if offset < end && start < offset + length {
                return Err(format!("section {i} overlaps another"));
            }
        }
        spans.push((offset, offset + length));
        sections.push(Section { kind, flags, data: &bytes[offset..offset + length] });
    }
    Ok((header, sections))
}

/// §1.4: CRC-32 over the whole file with the checksum field taken as zero.
pub(crate) fn checksum(bytes: &[u8]) -> u32 {
    let mut copy = bytes.to_vec();
    copy[20..24].fill(0);
    file_checksum(&copy)
}

/// A file laid out by §12.1's rule: the given header with `version_minor` replaced, the table in
/// the given order, the sections in table order — the first right after the table, each at the
/// next multiple of 4, zero padding (also after the last section, so the length is
/// `32 + 16·count + Σ align4(length)`) — then `file_length` and checksum filled in.
pub(crate) fn write_container(
    header: &[u8; HEADER_LEN],
    version_minor: u16,
    sections: &[(u32, u32, &[u8])],
) -> Result<Vec<u8>, String> {
    let mut out = header.to_vec();
    out[6..8].copy_from_slice(&version_minor.to_le_bytes());
    out[16..20].copy_from_slice(&(sections.len() as u32).to_le_bytes());

    let mut offset = HEADER_LEN + ENTRY_LEN * sections.len();
    for &(kind, flags, data) in sections {
        let offset_u32 = u32::try_from(offset).map_err(|_| "offset does not fit a u32")?;
        let length_u32 = u32::try_from(data.len()).map_err(|_| "length does not fit a u32")?;
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&flags.to_le_bytes());
        out.extend_from_slice(&offset_u32.to_le_bytes());
        out.extend_from_slice(&length_u32.to_le_bytes());
        offset = align4(offset + data.len());
    }
    for &(_, _, data) in sections {
        out.extend_from_slice(data);
        out.resize(align4(out.len()), 0);
    }

    let file_length = u32::try_from(out.len()).map_err(|_| "the file does not fit a u32")?;
    out[12..16].copy_from_slice(&file_length.to_le_bytes());
    let crc = checksum(&out);
    out[20..24].copy_from_slice(&crc.to_le_bytes());
    Ok(out)
}

pub(crate) fn count_kind(sections: &[Section<'_>], kind: u32) -> usize {
    sections.iter().filter(|s| s.kind == kind).count()
}

/// The one section of `kind`, or an error if there is none or more than one.
pub(crate) fn only_section<'s, 'a>(
    sections: &'s [Section<'a>],
    kind: u32,
) -> Result<&'s Section<'a>, String> {
    let mut found = sections.iter().filter(|s| s.kind == kind);
    match (found.next(), found.next()) {
        (Some(s), None) => Ok(s),
        (None, _) => Err(format!("no section of kind {kind}: Malformed MissingSection")),
        (Some(_), Some(_)) => Err(format!("more than one section of kind {kind}")),
    }
}
