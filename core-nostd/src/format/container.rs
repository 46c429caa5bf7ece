//! The `.nmat` container: header, section table and the validation of every field
//! (docs/FORMAT.md §1–§5, limits in §7). `parse` runs once; what it returns is trusted.

use crate::bytes::{align4, f32_at, i16_at, i32_at, slice, u8_at, u16_at, u32_at};
use crate::error::{Error, Field, at_most, malformed, unsupported};
use crate::format::channel::{
    AddressMode, Channel, ColorSpace, Semantic, channel_codes, channel_name_bytes, channel_range,
    mip_size,
};
use crate::format::checksum::file_checksum;
use crate::jpeg::Jpeg;
use crate::limits::*;
use crate::material::{Body, FeatureLevel, Material, Mlp, Neural, Term, TermMode};
use crate::neural::latents::{LatentGrid, packed_len};
use crate::neural::mlp::{Activation, Layer, Requant};

pub use crate::format::version::{
    FLAG_LOD_SCALE, JPEG_VERSION_MINOR, KNOWN_FLAGS, LEGACY_VERSION_MAJOR, LOD_SCALE_VERSION_MINOR,
    MAGIC, PACKED_VERSION_MINOR, VERSION_MAJOR, VERSION_MINOR,
};
pub const HEADER_LEN: usize = 32;
pub const SECTION_ENTRY_LEN: usize = 16;
/// Section flag: a reader that does not know the section's kind must reject the file.
pub const SECTION_REQUIRED: u32 = 1;
pub const MATERIAL_HEADER_LEN: usize = 12;
pub const CHANNEL_RECORD_LEN: usize = 32;
pub const LEVELS_HEADER_LEN: usize = 20;
pub const GRID_RECORD_LEN: usize = 16;
pub const LEVEL_HEADER_LEN: usize = 4;
pub const TERM_RECORD_LEN: usize = 12;
pub const MLP_HEADER_LEN: usize = 8;
pub const LAYER_RECORD_LEN: usize = 8;
/// Entries of the mip → level table (one more than `MAX_MIPS`, so the record stays aligned).
pub const MIP_TABLE_LEN: usize = 16;
/// Largest |i8·i16| product: int8 weights are in [−127, 127], activations in [−32768, 32767].
const MAX_PRODUCT: i64 = 127 * 32768;

/// Kind of a section: an open code, unknown values are skipped or rejected by their flag.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SectionKind(pub u32);

impl SectionKind {
    pub const MATERIAL: SectionKind = SectionKind(1);
    pub const LEVELS: SectionKind = SectionKind(2);
    pub const MLP: SectionKind = SectionKind(3);
    pub const LATENTS: SectionKind = SectionKind(4);
    /// Indexed JPEG streams (FORMAT.md §11), in place of LEVELS, MLP and LATENTS.
    pub const JPEG: SectionKind = SectionKind(5);
    /// Entropy-coded latents (FORMAT.md §12), in place of LATENTS: `unpack` restores LATENTS.
    pub const PACKED_LATENTS: SectionKind = SectionKind(6);
    /// JPEG streams without their index (FORMAT.md §12.5), in place of JPEG: `unpack` rebuilds
    /// the index and restores JPEG.
    pub const PACKED_JPEG: SectionKind = SectionKind(7);
    pub(crate) const KNOWN: [SectionKind; 7] = [
        Self::MATERIAL,
        Self::LEVELS,
        Self::MLP,
        Self::LATENTS,
        Self::JPEG,
        Self::PACKED_LATENTS,
        Self::PACKED_JPEG,
    ];
}

/// The fixed 32-byte file header (§1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    pub magic: [u8; 4],
    pub version_major: u16,
    pub version_minor: u16,
    pub flags: u32,
    pub file_length: u32,
    pub section_count: u32,
    pub checksum: u32,
    pub reserved: [u32; 2],
}

impl Header {
    pub fn from_bytes(b: &[u8; HEADER_LEN]) -> Header {
        Header {
            magic: [b[0], b[1], b[2], b[3]],
            version_major: u16_at(b, 4),
            version_minor: u16_at(b, 6),
            flags: u32_at(b, 8),
            file_length: u32_at(b, 12),
            section_count: u32_at(b, 16),
            checksum: u32_at(b, 20),
            reserved: [u32_at(b, 24), u32_at(b, 28)],
        }
    }
}

/// Options of [`Container::parse_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParseOptions {
    /// Verify the CRC-32 of the whole file (one pass over it). Turn off only for bytes whose
    /// integrity is already established; validation of every field happens either way.
    pub verify_checksum: bool,
}

impl Default for ParseOptions {
    fn default() -> Self {
        ParseOptions { verify_checksum: true }
    }
}

/// Entry point for reading `.nmat` bytes.
pub struct Container;

impl Container {
    /// Parses and validates a whole file, checksum included. Zero-copy: the material borrows
    /// `bytes`. Never panics and never allocates.
    pub fn parse(bytes: &[u8]) -> Result<Material<'_>, Error> {
        Self::parse_with(bytes, ParseOptions::default())
    }

    pub fn parse_with(bytes: &[u8], options: ParseOptions) -> Result<Material<'_>, Error> {
        let header = read_header(bytes)?;
        if options.verify_checksum {
            check_checksum(bytes, &header)?;
        }
        let sections = read_section_table(bytes, &header)?;
        let material = sections.material;
        let (width, height, mip_count, address_mode, channels) = parse_material(material)?;
        let (body, section_lens) = match sections.body {
            BodySections::Jpeg(jpeg) => {
                let sizes = core::array::from_fn(|m| mip_size(width, height, mip_count, m as u32));
                let body = Body::Jpeg(Jpeg::parse(jpeg, &channels, sizes, mip_count)?);
                (body, [material.len(), 0, 0, 0, jpeg.len()])
            }
            BodySections::Packed => {
                // Decoding needs the fixed-rate latents: `unpack` makes them (with memory).
                let unpacked =
                    crate::format::packed::unpacked_len(bytes).ok().flatten().unwrap_or(0);
                return Err(Error::Unsupported {
                    field: Field::Packed,
                    index: 0,
                    value: unpacked as u64,
                });
            }
            BodySections::Neural([levels_bytes, mlp_bytes, latents]) => {
                let levels = parse_levels(levels_bytes, latents, mip_count)?;
                let mlp = parse_mlp(mlp_bytes, channels.len(), &header)?;
                for (l, width_of_level) in levels.widths.iter().enumerate() {
                    let expected = width_of_level
                        + 4 * usize::from(mlp.pe_frequencies)
                        + usize::from(mlp.lod_input != 0);
                    if expected != mlp.input_width() {
                        return Err(malformed(Field::LevelFeatureWidth, l, expected as i64));
                    }
                }
                let body = Body::Neural(Neural {
                    mip_count,
                    mip_to_level: levels.mip_to_level,
                    grids: levels.grids,
                    levels: levels.levels,
                    mlp,
                });
                (body, [material, levels_bytes, mlp_bytes, latents, &[]].map(<[u8]>::len))
            }
        };
        Ok(Material {
            version_major: header.version_major,
            version_minor: header.version_minor,
            width,
            height,
            mip_count,
            address_mode,
            channels,
            body,
            file_len: bytes.len(),
            section_lens,
            optional_sections: sections.optional,
        })
    }
}

/// The file's CRC-32 against the one its header stores (§1.4).
pub(crate) fn check_checksum(bytes: &[u8], header: &Header) -> Result<(), Error> {
    let computed = file_checksum(bytes);
    if computed != header.checksum {
        return Err(Error::ChecksumMismatch { stored: header.checksum, computed });
    }
    Ok(())
}

pub(crate) fn read_header(bytes: &[u8]) -> Result<Header, Error> {
    let Some(head) = bytes.get(..HEADER_LEN).and_then(|h| <&[u8; HEADER_LEN]>::try_from(h).ok())
    else {
        let prefix = bytes.len().min(MAGIC.len());
        if bytes.get(..prefix) != MAGIC.get(..prefix) {
            return Err(malformed(Field::Magic, 0, 0));
        }
        return Err(Error::Truncated {
            field: Field::FileLength,
            index: 0,
            needed: HEADER_LEN as u64,
            available: bytes.len() as u64,
        });
    };
    let header = Header::from_bytes(head);
    if header.magic != MAGIC {
        return Err(malformed(Field::Magic, 0, u32::from_le_bytes(header.magic)));
    }
    if header.version_major != VERSION_MAJOR && header.version_major != LEGACY_VERSION_MAJOR {
        return Err(unsupported(Field::VersionMajor, 0, header.version_major));
    }
    if header.flags & !KNOWN_FLAGS != 0
        || (header.flags != 0 && header.version_major != VERSION_MAJOR)
    {
        // A set bit we do not know announces a feature we lack (§1.3); version 1 has no flags.
        return Err(unsupported(Field::Flags, 0, header.flags));
    }
    let len = bytes.len() as u64;
    let declared = u64::from(header.file_length);
    if declared > len {
        return Err(Error::Truncated {
            field: Field::FileLength,
            index: 0,
            needed: declared,
            available: len,
        });
    }
    if declared < len {
        return Err(malformed(Field::FileLength, 0, declared));
    }
    if let Some(i) = header.reserved.iter().position(|&r| r != 0) {
        return Err(malformed(
            Field::HeaderReserved,
            i,
            header.reserved.get(i).copied().unwrap_or(0),
        ));
    }
    Ok(header)
}

struct Sections<'a> {
    optional: heapless::Vec<(SectionKind, &'a [u8]), MAX_SECTIONS>,
    material: &'a [u8],
    body: BodySections<'a>,
}

/// What a material stores besides MATERIAL: LEVELS, MLP and LATENTS, or a JPEG section, or
/// LEVELS, MLP and PACKED_LATENTS (§12).
enum BodySections<'a> {
    Neural([&'a [u8]; 3]),
    Jpeg(&'a [u8]),
    Packed,
}

/// One entry of the section table with the bytes it points at (§1.2).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SectionEntry<'a> {
    pub(crate) kind: SectionKind,
    pub(crate) flags: u32,
    pub(crate) data: &'a [u8],
}

/// The section table in file order, every entry's flags, offset and extent checked (§1.2) but
/// not its kind.
pub(crate) fn section_entries<'a>(
    bytes: &'a [u8],
    header: &Header,
) -> Result<heapless::Vec<SectionEntry<'a>, MAX_SECTIONS>, Error> {
    let count = header.section_count as usize;
    if count == 0 {
        return Err(malformed(Field::SectionCount, 0, 0));
    }
    at_most(Field::SectionCount, 0, u64::from(header.section_count), MAX_SECTIONS as u64)?;
    let table_end = HEADER_LEN + SECTION_ENTRY_LEN * count;
    need_bytes(bytes, 0, table_end, Field::SectionCount, 0)?;
    let mut ranges = [(0usize, 0usize); MAX_SECTIONS];
    let mut entries = heapless::Vec::new();
    for i in 0..count {
        let e = HEADER_LEN + SECTION_ENTRY_LEN * i;
        let kind = SectionKind(u32_at(bytes, e));
        let flags = u32_at(bytes, e + 4);
        let offset = u32_at(bytes, e + 8) as usize;
        let length = u32_at(bytes, e + 12) as usize;
        if flags & !SECTION_REQUIRED != 0 {
            return Err(unsupported(Field::SectionFlags, i, flags));
        }
        if !offset.is_multiple_of(4) || offset < table_end {
            return Err(malformed(Field::SectionOffset, i, offset as i64));
        }
        let data = take(bytes, offset, length, Field::SectionLength, i)?;
        let end = offset + length;
        for (j, &(o, e2)) in ranges.iter().enumerate().take(i) {
            if offset < e2 && o < end {
                return Err(malformed(Field::SectionOffset, i, j as i64));
            }
        }
        if let Some(r) = ranges.get_mut(i) {
            *r = (offset, end);
        }
        entries
            .push(SectionEntry { kind, flags, data })
            .map_err(|_| malformed(Field::SectionCount, i, 0))?;
    }
    Ok(entries)
}

fn read_section_table<'a>(bytes: &'a [u8], header: &Header) -> Result<Sections<'a>, Error> {
    let mut found: [Option<&'a [u8]>; SectionKind::KNOWN.len()] = [None; SectionKind::KNOWN.len()];
    let mut optional = heapless::Vec::new();
    for (i, entry) in section_entries(bytes, header)?.into_iter().enumerate() {
        let SectionEntry { kind, flags, data } = entry;
        match SectionKind::KNOWN.iter().position(|&k| k == kind) {
            Some(k) => match found.get_mut(k) {
                Some(slot @ None) => *slot = Some(data),
                _ => return Err(malformed(Field::SectionKind, i, kind.0)),
            },
            None if flags & SECTION_REQUIRED != 0 => {
                return Err(unsupported(Field::SectionKind, i, kind.0));
            }
            // An optional extension: not needed to decode (§1.3), kept for whoever knows it.
            None => {
                optional.push((kind, data)).map_err(|_| malformed(Field::SectionCount, i, 0))?
            }
        }
    }
    let has = |k: usize| found.get(k).is_some_and(Option::is_some);
    let need = |k: usize| {
        found.get(k).copied().flatten().ok_or(malformed(
            Field::MissingSection,
            k + 1,
            (k + 1) as i64,
        ))
    };
    let body = if has(6) {
        // JPEG streams without their index (§12.5): nothing of a network beside them, and no
        // JPEG section (the packed one stands for it).
        match [1, 2, 3, 4, 5].into_iter().find(|&k| has(k)) {
            Some(k) => return Err(malformed(Field::SectionKind, 6, (k + 1) as i64)),
            None => BodySections::Packed,
        }
    } else {
        match (found.get(4).copied().flatten(), found.get(5).copied().flatten()) {
            // A JPEG material has no network: LEVELS, MLP, LATENTS or PACKED_LATENTS beside it
            // contradict it.
            (Some(jpeg), _) => match [1, 2, 3, 5].into_iter().find(|&k| has(k)) {
                Some(k) => return Err(malformed(Field::SectionKind, k, (k + 1) as i64)),
                None => BodySections::Jpeg(jpeg),
            },
            // Entropy-coded latents stand in for LATENTS (§12): one or the other.
            (None, Some(_)) if has(3) => return Err(malformed(Field::SectionKind, 5, 6)),
            (None, Some(_)) => {
                need(1)?;
                need(2)?;
                BodySections::Packed
            }
            (None, None) => BodySections::Neural([need(1)?, need(2)?, need(3)?]),
        }
    };
    Ok(Sections { optional, material: need(0)?, body })
}

fn exact_length(
    section: &[u8],
    needed: usize,
    field: Field,
    kind: SectionKind,
) -> Result<(), Error> {
    if section.len() < needed {
        return Err(Error::Truncated {
            field,
            index: 0,
            needed: needed as u64,
            available: section.len() as u64,
        });
    }
    if section.len() > needed {
        return Err(malformed(Field::SectionContent, kind.0 as usize, section.len() as i64));
    }
    Ok(())
}

fn dimension(field: Field, value: u32, limit: u32) -> Result<u32, Error> {
    if value == 0 {
        return Err(malformed(field, 0, 0));
    }
    at_most(field, 0, u64::from(value), u64::from(limit))?;
    Ok(value)
}

pub(crate) type MaterialParts<'a> =
    (u32, u32, u8, AddressMode, heapless::Vec<Channel<'a>, MAX_CHANNELS>);

pub(crate) fn parse_material(s: &[u8]) -> Result<MaterialParts<'_>, Error> {
    need_bytes(s, 0, MATERIAL_HEADER_LEN, Field::Width, 0)?;
    let width = dimension(Field::Width, u32_at(s, 0), MAX_DIMENSION)?;
    let height = dimension(Field::Height, u32_at(s, 4), MAX_DIMENSION)?;
    let mip_count = u8_at(s, 8);
    let full_chain = 32 - width.max(height).leading_zeros();
    if mip_count == 0 || u32::from(mip_count) > full_chain {
        return Err(malformed(Field::MipCount, 0, mip_count));
    }
    let channel_count = usize::from(u8_at(s, 9));
    if channel_count == 0 {
        return Err(malformed(Field::ChannelCount, 0, 0));
    }
    at_most(Field::ChannelCount, 0, channel_count as u64, MAX_CHANNELS as u64)?;
    let address_mode = match u8_at(s, 10) {
        0 => AddressMode::Wrap,
        1 => AddressMode::Clamp,
        other => return Err(unsupported(Field::AddressMode, 0, other)),
    };
    if u8_at(s, 11) != 0 {
        return Err(malformed(Field::MaterialReserved, 0, u8_at(s, 11)));
    }
    let len = MATERIAL_HEADER_LEN + CHANNEL_RECORD_LEN * channel_count;
    exact_length(s, len, Field::ChannelCount, SectionKind::MATERIAL)?;
    let mut channels = heapless::Vec::new();
    for c in 0..channel_count {
        let rec = slice(s, MATERIAL_HEADER_LEN + CHANNEL_RECORD_LEN * c, CHANNEL_RECORD_LEN)
            .unwrap_or(&[]);
        channels
            .push(parse_channel(rec, c)?)
            .map_err(|_| malformed(Field::ChannelCount, c, c as i64))?;
    }
    Ok((width, height, mip_count, address_mode, channels))
}

fn parse_channel(rec: &[u8], c: usize) -> Result<Channel<'_>, Error> {
    let name_bytes = channel_name_bytes(rec);
    let padding = rec.get(name_bytes.len()..16).unwrap_or(&[]);
    if name_bytes.is_empty() || padding.iter().any(|&b| b != 0) {
        return Err(malformed(Field::ChannelName, c, name_bytes.len() as i64));
    }
    let name = core::str::from_utf8(name_bytes)
        .map_err(|e| malformed(Field::ChannelName, c, e.valid_up_to() as i64))?;
    let (semantic, component, color_space, reserved) = channel_codes(rec);
    let color_space = match color_space {
        0 => ColorSpace::Linear,
        1 => ColorSpace::Srgb,
        other => return Err(unsupported(Field::ChannelColorSpace, c, other)),
    };
    if reserved != 0 || u32_at(rec, 28) != 0 {
        return Err(malformed(Field::ChannelReserved, c, i64::from(reserved)));
    }
    let (range_min, range_max) = channel_range(rec);
    if !range_min.is_finite() || !range_max.is_finite() || range_min > range_max {
        return Err(malformed(Field::ChannelRange, c, i64::from(range_min.to_bits())));
    }
    Ok(Channel { name, semantic: Semantic(semantic), component, color_space, range_min, range_max })
}

struct Levels<'a> {
    mip_to_level: [u8; MAX_MIPS],
    grids: heapless::Vec<LatentGrid<'a>, MAX_GRIDS>,
    levels: heapless::Vec<FeatureLevel, MAX_LEVELS>,
    /// Features each level's terms produce (before positional encoding and LOD).
    widths: heapless::Vec<usize, MAX_LEVELS>,
}

/// `len` bytes of `s` from `pos`, or `Truncated` naming the structure that needed them.
fn take(s: &[u8], pos: usize, len: usize, field: Field, index: usize) -> Result<&[u8], Error> {
    slice(s, pos, len).ok_or(Error::Truncated {
        field,
        index: index as u32,
        needed: pos as u64 + len as u64,
        available: s.len() as u64,
    })
}

fn need_bytes(s: &[u8], pos: usize, len: usize, field: Field, index: usize) -> Result<(), Error> {
    take(s, pos, len, field, index).map(|_| ())
}

fn count(field: Field, value: u8, limit: usize) -> Result<usize, Error> {
    if value == 0 {
        return Err(malformed(field, 0, 0));
    }
    at_most(field, 0, u64::from(value), limit as u64)?;
    Ok(usize::from(value))
}

/// The level and grid counts of a LEVELS section (§5), checked. Shared with the unpacker
/// (`format/packed.rs`), so that both report the same field for the same fault.
pub(crate) fn levels_counts(s: &[u8]) -> Result<(usize, usize), Error> {
    need_bytes(s, 0, LEVELS_HEADER_LEN, Field::LevelCount, 0)?;
    let level_count = count(Field::LevelCount, u8_at(s, 0), MAX_LEVELS)?;
    let grid_count = count(Field::GridCount, u8_at(s, 1), MAX_GRIDS)?;
    Ok((level_count, grid_count))
}

fn parse_levels<'a>(s: &'a [u8], latents: &'a [u8], mip_count: u8) -> Result<Levels<'a>, Error> {
    let (level_count, grid_count) = levels_counts(s)?;
    if u16_at(s, 2) != 0 {
        return Err(malformed(Field::LevelsReserved, 0, u16_at(s, 2)));
    }
    let mut mip_to_level = [0u8; MAX_MIPS];
    for m in 0..MIP_TABLE_LEN {
        let level = u8_at(s, 4 + m);
        let valid =
            if m < usize::from(mip_count) { usize::from(level) < level_count } else { level == 0 };
        if !valid {
            return Err(malformed(Field::MipToLevel, m, level));
        }
        if let Some(slot) = mip_to_level.get_mut(m) {
            *slot = level;
        }
    }
    let mut pos = LEVELS_HEADER_LEN;
    let mut grids = heapless::Vec::new();
    for g in 0..grid_count {
        let grid = parse_grid(s, pos, g, latents)?;
        pos += GRID_RECORD_LEN + 4 * grid.channels();
        grids.push(grid).map_err(|_| malformed(Field::GridCount, g, g as i64))?;
    }
    let mut levels = heapless::Vec::new();
    let mut widths = heapless::Vec::new();
    for l in 0..level_count {
        need_bytes(s, pos, LEVEL_HEADER_LEN, Field::TermCount, l)?;
        let term_count = usize::from(u8_at(s, pos));
        if term_count == 0 {
            return Err(malformed(Field::TermCount, l, 0));
        }
        at_most(Field::TermCount, l, term_count as u64, MAX_TERMS as u64)?;
        if s.get(pos + 1..pos + 4).is_some_and(|r| r.iter().any(|&b| b != 0)) {
            return Err(malformed(Field::LevelReserved, l, 0));
        }
        pos += LEVEL_HEADER_LEN;
        need_bytes(s, pos, TERM_RECORD_LEN * term_count, Field::TermCount, l)?;
        let mut terms = heapless::Vec::new();
        let mut width = 0usize;
        for t in 0..term_count {
            let rec = slice(s, pos, TERM_RECORD_LEN).unwrap_or(&[]);
            let (term, term_width) = parse_term(rec, l * MAX_TERMS + t, &grids)?;
            width += term_width;
            terms.push(term).map_err(|_| malformed(Field::TermCount, l, t as i64))?;
            pos += TERM_RECORD_LEN;
        }
        levels
            .push(FeatureLevel { terms })
            .map_err(|_| malformed(Field::LevelCount, l, l as i64))?;
        widths.push(width).map_err(|_| malformed(Field::LevelCount, l, l as i64))?;
    }
    exact_length(s, pos, Field::LevelCount, SectionKind::LEVELS)?;
    Ok(Levels { mip_to_level, grids, levels, widths })
}

/// A grid record's shape and where its codes lie (§5.1).
#[derive(Clone, Copy, Debug)]
pub(crate) struct GridShape {
    pub(crate) width: u16,
    pub(crate) height: u16,
    pub(crate) channels: u8,
    pub(crate) bits: u8,
    /// The codes' offset and length in LATENTS.
    pub(crate) offset: usize,
    pub(crate) length: usize,
}

/// Grid record `g`, at `pos` in the LEVELS section `s`, checked but for its quantization and
/// its data's place in LATENTS. Shared with the unpacker (`format/packed.rs`), so that both
/// report the same field for the same fault.
pub(crate) fn grid_shape(s: &[u8], pos: usize, g: usize) -> Result<GridShape, Error> {
    need_bytes(s, pos, GRID_RECORD_LEN, Field::GridWidth, g)?;
    let grid_dim = |field, v: u16| {
        if v == 0 {
            return Err(malformed(field, g, 0));
        }
        at_most(field, g, u64::from(v), u64::from(MAX_GRID_DIMENSION)).map(|_| v)
    };
    let width = grid_dim(Field::GridWidth, u16_at(s, pos))?;
    let height = grid_dim(Field::GridHeight, u16_at(s, pos + 2))?;
    let channels = u8_at(s, pos + 4);
    if channels == 0 {
        return Err(malformed(Field::GridChannels, g, 0));
    }
    at_most(Field::GridChannels, g, u64::from(channels), MAX_GRID_CHANNELS as u64)?;
    let bits = u8_at(s, pos + 5);
    if bits == 0 || bits > MAX_LATENT_BITS {
        return Err(malformed(Field::GridBits, g, bits));
    }
    if u16_at(s, pos + 6) != 0 {
        return Err(malformed(Field::GridReserved, g, u16_at(s, pos + 6)));
    }
    let offset = u32_at(s, pos + 8) as usize;
    let length = u32_at(s, pos + 12) as usize;
    let expected =
        packed_len(u32::from(width), u32::from(height), u32::from(channels), u32::from(bits));
    if expected != Some(length) {
        return Err(malformed(Field::GridDataLength, g, length as i64));
    }
    if !offset.is_multiple_of(4) {
        return Err(malformed(Field::GridDataOffset, g, offset as i64));
    }
    Ok(GridShape { width, height, channels, bits, offset, length })
}

fn parse_grid<'a>(
    s: &'a [u8],
    pos: usize,
    g: usize,
    latents: &'a [u8],
) -> Result<LatentGrid<'a>, Error> {
    let GridShape { width, height, channels, bits, offset, length } = grid_shape(s, pos, g)?;
    let data = take(latents, offset, length, Field::GridDataOffset, g)?;
    let quant_len = 4 * usize::from(channels);
    let quant = take(s, pos + GRID_RECORD_LEN, quant_len, Field::LatentQuantization, g)?;
    let max_code = (1i32 << bits) - 1;
    for c in 0..usize::from(channels) {
        let offset = i32::from(i16_at(quant, 4 * c));
        let step = i32::from(i16_at(quant, 4 * c + 2));
        // Every dequantized value offset + code·step must be an i16 (§4.2).
        let far = offset + max_code * step;
        if !(i32::from(i16::MIN)..=i32::from(i16::MAX)).contains(&far) {
            return Err(malformed(Field::LatentQuantization, g, far));
        }
    }
    Ok(LatentGrid { width, height, channels, bits, quant, data })
}

fn parse_term(rec: &[u8], index: usize, grids: &[LatentGrid<'_>]) -> Result<(Term, usize), Error> {
    let mode = match u8_at(rec, 0) {
        0 => TermMode::Nearest4,
        1 => TermMode::Bilinear,
        other => return Err(unsupported(Field::TermMode, index, other)),
    };
    let chain_len = usize::from(u8_at(rec, 1));
    if chain_len == 0 || chain_len > MAX_CHAIN || (mode == TermMode::Nearest4 && chain_len != 1) {
        return Err(malformed(Field::TermChainLength, index, chain_len as i64));
    }
    if u16_at(rec, 2) != 0 {
        return Err(malformed(Field::TermReserved, index, u16_at(rec, 2)));
    }
    let slots = rec.get(4..4 + MAX_CHAIN).unwrap_or(&[]);
    let mut chain = heapless::Vec::new();
    let mut channels = None;
    for (k, &g) in slots.iter().enumerate() {
        if k >= chain_len {
            if g != 0 {
                return Err(malformed(Field::TermReserved, index, g));
            }
            continue;
        }
        let Some(grid) = grids.get(usize::from(g)) else {
            return Err(malformed(Field::TermGrid, index, g));
        };
        // A fusion chain sums its grids channel by channel: they must agree.
        if *channels.get_or_insert(grid.channels()) != grid.channels() {
            return Err(malformed(Field::TermGrid, index, g));
        }
        chain.push(g).map_err(|_| malformed(Field::TermChainLength, index, chain_len as i64))?;
    }
    let c = channels.unwrap_or(0);
    let width = if mode == TermMode::Nearest4 { 4 * c } else { c };
    Ok((Term { mode, grids: chain }, width))
}

/// Byte length of one layer's parameter block (§5.3): int8 weights (padded to 4 bytes), then an f32
/// scale and an i32 bias per output row.
pub fn layer_data_len(inputs: usize, outputs: usize) -> usize {
    align4(inputs * outputs) + 8 * outputs
}

/// Byte length of a layer block of a version-1 file, which adds f16 weights (padded) and an f32
/// bias per row after the integer parameters (§10).
fn legacy_layer_data_len(inputs: usize, outputs: usize) -> usize {
    layer_data_len(inputs, outputs) + align4(2 * inputs * outputs) + 4 * outputs
}

fn parse_mlp<'a>(s: &'a [u8], channel_count: usize, header: &Header) -> Result<Mlp<'a>, Error> {
    let version_major = header.version_major;
    need_bytes(s, 0, MLP_HEADER_LEN, Field::LayerCount, 0)?;
    let layer_count = count(Field::LayerCount, u8_at(s, 0), MAX_LAYERS)?;
    let input_frac_bits = u8_at(s, 1);
    if input_frac_bits < MIN_INPUT_FRAC_BITS {
        return Err(malformed(Field::InputFracBits, 0, input_frac_bits));
    }
    at_most(Field::InputFracBits, 0, u64::from(input_frac_bits), u64::from(MAX_FRAC_BITS))?;
    let pe_frequencies = u8_at(s, 2);
    at_most(Field::PeFrequencies, 0, u64::from(pe_frequencies), u64::from(MAX_PE_FREQUENCIES))?;
    if pe_frequencies + 2 > input_frac_bits {
        // The triangle wave of frequency k has denominator 2^(k+3) and must be exact (§6.4).
        return Err(malformed(Field::PeFrequencies, 0, pe_frequencies));
    }
    // 0: none; 1: mip / 16; 2–5 (with FLAG_LOD_SCALE): mip · 2^(lod_input − 5), whose value at
    // the last possible mip (MAX_MIPS − 1 = 14) must fit the i16 input: f + lod_input ≤ 16 (§5.3, §6.5).
    let lod_input = u8_at(s, 3);
    let scaled = header.flags & FLAG_LOD_SCALE != 0;
    let fits = lod_input < 2 || u16::from(input_frac_bits) + u16::from(lod_input) <= 16;
    if lod_input > 5 || (lod_input > 1 && !scaled) || !fits {
        return Err(malformed(Field::LodInput, 0, lod_input));
    }
    let input_width = u16_at(s, 4);
    if u16_at(s, 6) != 0 {
        return Err(malformed(Field::MlpReserved, 0, u16_at(s, 6)));
    }
    need_bytes(s, MLP_HEADER_LEN, LAYER_RECORD_LEN * layer_count, Field::LayerCount, 0)?;
    let mut pos = MLP_HEADER_LEN + LAYER_RECORD_LEN * layer_count;
    let mut layers = heapless::Vec::new();
    let mut prev_outputs = usize::from(input_width);
    let mut prev_frac = input_frac_bits;
    for l in 0..layer_count {
        let r = MLP_HEADER_LEN + LAYER_RECORD_LEN * l;
        let inputs = usize::from(u16_at(s, r));
        let outputs = usize::from(u16_at(s, r + 2));
        if inputs == 0 || inputs != prev_outputs {
            return Err(malformed(Field::LayerInputs, l, inputs as i64));
        }
        at_most(Field::LayerInputs, l, inputs as u64, MAX_WIDTH as u64)?;
        let last = l + 1 == layer_count;
        if outputs == 0 || (last && outputs != channel_count) {
            return Err(malformed(Field::LayerOutputs, l, outputs as i64));
        }
        at_most(Field::LayerOutputs, l, outputs as u64, MAX_WIDTH as u64)?;
        let out_frac_bits = u8_at(s, r + 4);
        if out_frac_bits == 0 {
            return Err(malformed(Field::LayerOutFracBits, l, 0));
        }
        at_most(Field::LayerOutFracBits, l, u64::from(out_frac_bits), u64::from(MAX_FRAC_BITS))?;
        let activation = match u8_at(s, r + 5) {
            0 => Activation::None,
            1 => Activation::HardGelu,
            other => return Err(unsupported(Field::LayerActivation, l, other)),
        };
        if u16_at(s, r + 6) != 0 {
            return Err(malformed(Field::LayerReserved, l, u16_at(s, r + 6)));
        }
        let legacy = version_major == LEGACY_VERSION_MAJOR;
        let len = if legacy {
            legacy_layer_data_len(inputs, outputs)
        } else {
            layer_data_len(inputs, outputs)
        };
        let block = take(s, pos, len, Field::LayerOutputs, l)?;
        if legacy {
            check_legacy_float_copy(block, l, inputs, outputs)?;
        }
        let layer = parse_layer(block, l, inputs, outputs, prev_frac, out_frac_bits, activation)?;
        layers.push(layer).map_err(|_| malformed(Field::LayerCount, l, l as i64))?;
        pos += len;
        prev_outputs = outputs;
        prev_frac = out_frac_bits;
    }
    exact_length(s, pos, Field::LayerCount, SectionKind::MLP)?;
    Ok(Mlp { input_frac_bits, pe_frequencies, lod_input, input_width, layers })
}

fn parse_layer(
    block: &[u8],
    l: usize,
    inputs: usize,
    outputs: usize,
    in_frac_bits: u8,
    out_frac_bits: u8,
    activation: Activation,
) -> Result<Layer<'_>, Error> {
    let n = inputs * outputs;
    let mut at = 0usize;
    let mut take = |len: usize, padded: usize| {
        let part = slice(block, at, len).unwrap_or(&[]);
        at += padded;
        part
    };
    let weights_i8 = take(n, align4(n));
    let scales = take(4 * outputs, 4 * outputs);
    let bias = take(4 * outputs, 4 * outputs);
    if let Some(i) = weights_i8.iter().position(|&w| w as i8 == i8::MIN) {
        // −128 would break the symmetric range the accumulator bound assumes (docs/FORMAT.md §5.3).
        return Err(malformed(Field::WeightInt8, l, i as i64));
    }
    // |acc| ≤ inputs·127·32768 + |bias| must stay below 2^31 (docs/FORMAT.md §5.3, the bias bound).
    let bias_limit = i64::from(i32::MAX) - inputs as i64 * MAX_PRODUCT;
    for o in 0..outputs {
        let scale_bits = f32_at(scales, 4 * o).to_bits();
        if Requant::from_scale_bits(scale_bits, in_frac_bits, out_frac_bits).is_none() {
            return Err(malformed(Field::WeightScale, l, scale_bits));
        }
        let b = i64::from(i32_at(bias, 4 * o));
        at_most(Field::Bias, l, b.unsigned_abs(), bias_limit.unsigned_abs())?;
    }
    Ok(Layer {
        inputs: inputs as u16,
        outputs: outputs as u16,
        in_frac_bits,
        out_frac_bits,
        activation,
        weights_i8,
        scales,
        bias,
    })
}

/// Version 1 stored the float network a second time after the integer one: f16 weights and f32
/// biases, each finite (§10). A 2.x reader checks that rule and then ignores the copy: both of its
/// decoders run the int8 network.
fn check_legacy_float_copy(
    block: &[u8],
    l: usize,
    inputs: usize,
    outputs: usize,
) -> Result<(), Error> {
    let n = inputs * outputs;
    let at = layer_data_len(inputs, outputs);
    let weights_f16 = slice(block, at, 2 * n).unwrap_or(&[]);
    let float_bias = slice(block, at + align4(2 * n), 4 * outputs).unwrap_or(&[]);
    if let Some(i) =
        weights_f16.chunks_exact(2).position(|w| !half::f16::from_bits(u16_at(w, 0)).is_finite())
    {
        return Err(malformed(Field::FloatWeight, l, i as i64));
    }
    if let Some(o) = float_bias.chunks_exact(4).position(|b| !f32_at(b, 0).is_finite()) {
        return Err(malformed(Field::FloatBias, l, o as i64));
    }
    Ok(())
}
