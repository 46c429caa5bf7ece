//! Packed files (docs/FORMAT.md §12): on disk a PACKED_LATENTS section stands in for LATENTS (the
//! latents entropy-coded) and a PACKED_JPEG section for JPEG (the streams without their index);
//! either is unpacked once, at load, into the fixed-rate file every decoder reads.
//!
//! The latents' coder is a binary adaptive range coder (12-bit probabilities, adaptation shift 5, 32-bit
//! range renormalized bytewise) over each latent's bits from the most significant, every bit
//! modelled by its position in the code's binary tree and by the codes of the latent's left and
//! upper neighbours in the same grid channel. Decoding is `no_std`, allocation-free and bounded:
//! a stream can stand for at most [`MAX_EXPANSION`] times its length.

use crate::bytes::{u8_at, u16_at, u32_at};
use crate::error::{Error, Field, malformed, unsupported};
use crate::format::channel::mip_size;
use crate::format::checksum::file_checksum;
use crate::format::container::{
    GRID_RECORD_LEN, HEADER_LEN, Header, LEVELS_HEADER_LEN, ParseOptions, SECTION_ENTRY_LEN,
    SECTION_REQUIRED, SectionEntry, SectionKind, check_checksum, grid_shape, levels_counts,
    parse_material, read_header, section_entries,
};
use crate::jpeg::{Jpeg, Streams};

/// Bytes before the payload of a packed section (the coded stream, or the bare JPEG body).
pub const PACKED_HEADER_LEN: usize = 8;
/// PACKED_LATENTS' coder: the binary range coder with neighbour contexts (§12.2).
pub const CODER_RANGE_NEIGHBOURS: u8 = 1;
/// PACKED_JPEG's "coder": streams without index, the index rebuilt by scanning them (§12.5).
pub const CODER_JPEG_SCAN: u8 = 2;
/// A payload of `n` bytes stands for at most `MAX_EXPANSION · (n + 64)` bytes: each binary
/// decision of the latents' coder costs at least 0.011 bits with 12-bit probabilities and shift 5
/// (§12.3), and a JPEG MCU at least 2 bits for its 3.7–6.7 bytes of index and DC values, so a
/// valid file is far below this bound, and a hostile one cannot ask for unbounded memory.
pub const MAX_EXPANSION: usize = 256;

const PROB_BITS: u32 = 12;
const PROB_ONE: u16 = 1 << PROB_BITS;
const ADAPT_SHIFT: u32 = 5;
const TOP: u32 = 1 << 24;
/// Neighbour classes: a code's two most significant bits (4 values) or "no neighbour".
const CLASSES: usize = 5;
/// Probabilities of one grid channel: neighbour class pair × binary-tree node (≤ 255 nodes).
const CONTEXTS: usize = CLASSES * CLASSES * 256;

/// The fields of a packed section's header (§12.1, §12.5).
#[derive(Clone, Copy, Debug)]
struct PackedHeader {
    /// Length of the section it stands for (LATENTS or JPEG).
    length: usize,
    unpacked_minor: u16,
}

/// The header of a packed section of `kind` and what follows it (the coded stream, or the bare
/// JPEG body).
fn packed_header(kind: SectionKind, section: &[u8]) -> Result<(PackedHeader, &[u8]), Error> {
    let Some(payload) = section.get(PACKED_HEADER_LEN..) else {
        return Err(Error::Truncated {
            field: Field::PackedLength,
            index: 0,
            needed: PACKED_HEADER_LEN as u64,
            available: section.len() as u64,
        });
    };
    let length = u32_at(section, 0) as usize;
    if !length.is_multiple_of(4) {
        return Err(malformed(Field::PackedLength, 0, length as i64));
    }
    let bound = MAX_EXPANSION.saturating_mul(payload.len().saturating_add(64));
    if length > bound {
        return Err(malformed(Field::PackedLength, 0, length as i64));
    }
    let coder =
        if kind == SectionKind::PACKED_JPEG { CODER_JPEG_SCAN } else { CODER_RANGE_NEIGHBOURS };
    if u8_at(section, 4) != coder {
        return Err(unsupported(Field::PackedCoder, 0, u8_at(section, 4)));
    }
    if u8_at(section, 5) != 0 {
        return Err(malformed(Field::PackedReserved, 0, u8_at(section, 5)));
    }
    Ok((PackedHeader { length, unpacked_minor: u16_at(section, 6) }, payload))
}

/// The section kind a packed kind stands for.
fn unpacked_kind(kind: SectionKind) -> SectionKind {
    if kind == SectionKind::PACKED_JPEG { SectionKind::JPEG } else { SectionKind::LATENTS }
}

fn is_packed(kind: SectionKind) -> bool {
    kind == SectionKind::PACKED_LATENTS || kind == SectionKind::PACKED_JPEG
}

/// The unpacked file: its sections in the packed file's order, the packed section replaced by
/// the one it stands for, of `length` bytes, each section at the next 4-byte boundary.
fn unpacked_layout(entries: &[SectionEntry<'_>], length: usize) -> Option<usize> {
    let mut end = HEADER_LEN + SECTION_ENTRY_LEN * entries.len();
    for e in entries {
        let len = if is_packed(e.kind) { length } else { e.data.len() };
        end = end.checked_add(len)?.checked_add(3)? & !3;
    }
    u32::try_from(end).ok()?;
    Some(end)
}

/// The packed section (PACKED_LATENTS or PACKED_JPEG): its index in the table, kind and bytes,
/// if there is one (at most one, and not beside the section it stands for). It must be
/// `REQUIRED` (§12.1): a reader before 2.2 would skip it otherwise, and then miss the latents or
/// streams.
/// A packed section: its index in the table, its kind and its bytes.
type PackedEntry<'a> = (usize, SectionKind, &'a [u8]);

fn packed_entry<'a>(entries: &[SectionEntry<'a>]) -> Result<Option<PackedEntry<'a>>, Error> {
    let mut found = None;
    for (i, e) in entries.iter().enumerate().filter(|(_, e)| is_packed(e.kind)) {
        if e.flags & SECTION_REQUIRED == 0 {
            return Err(malformed(Field::SectionFlags, i, e.flags));
        }
        if found.is_some() {
            return Err(malformed(Field::SectionKind, i, e.kind.0));
        }
        found = Some((i, e.kind, e.data));
    }
    // A packed section stands in for LATENTS or JPEG: never beside it.
    if let Some((i, kind, _)) = found
        && entries.iter().any(|e| e.kind == unpacked_kind(kind))
    {
        return Err(malformed(Field::SectionKind, i, kind.0));
    }
    Ok(found)
}

/// The length of `bytes` once unpacked, or `None` for a file that is not packed (it parses as
/// it is). Reads the header and section table only; errors name what is wrong with them.
pub fn unpacked_len(bytes: &[u8]) -> Result<Option<usize>, Error> {
    let header = read_header(bytes)?;
    let entries = section_entries(bytes, &header)?;
    let Some((_, kind, section)) = packed_entry(&entries)? else { return Ok(None) };
    let (packed, _) = packed_header(kind, section)?;
    unpacked_layout(&entries, packed.length).map(Some).ok_or(malformed(
        Field::PackedLength,
        0,
        packed.length as i64,
    ))
}

/// Decodes a packed file into the fixed-rate file it stands for, in `out` (at least
/// [`unpacked_len`] bytes), and returns that length; `out[..len]` then parses with
/// `Container::parse`. Checks the packed file's checksum when `options` say so (the
/// unpacked file gets its own). Never allocates; work is bounded by the packed section's length.
pub fn unpack_into(bytes: &[u8], options: ParseOptions, out: &mut [u8]) -> Result<usize, Error> {
    let header = read_header(bytes)?;
    if options.verify_checksum {
        check_checksum(bytes, &header)?;
    }
    let entries = section_entries(bytes, &header)?;
    let Some((packed_index, kind, section)) = packed_entry(&entries)? else {
        return Err(malformed(Field::MissingSection, 6, 6));
    };
    let (packed, payload) = packed_header(kind, section)?;
    let total = unpacked_layout(&entries, packed.length).ok_or(malformed(
        Field::PackedLength,
        0,
        packed.length as i64,
    ))?;
    let available = out.len();
    let out = out.get_mut(..total).ok_or(Error::BadArgument {
        argument: crate::Argument::Output,
        value: available as u64,
        limit: total as u64,
    })?;
    out.fill(0);
    // Header and table; every section copied but the packed one, which is decoded in place.
    write_header(out, &header, packed.unpacked_minor, total, entries.len());
    let mut offset = HEADER_LEN + SECTION_ENTRY_LEN * entries.len();
    let (mut unpacked_at, mut levels, mut material) = (0, None, None);
    for (i, e) in entries.iter().enumerate() {
        let (kind, len) = if i == packed_index {
            unpacked_at = offset;
            (unpacked_kind(kind), packed.length)
        } else {
            copy(out, offset, e.data);
            (e.kind, e.data.len())
        };
        let t = HEADER_LEN + SECTION_ENTRY_LEN * i;
        put_u32(out, t, kind.0);
        put_u32(out, t + 4, e.flags);
        put_u32(out, t + 8, offset as u32);
        put_u32(out, t + 12, len as u32);
        if e.kind == SectionKind::LEVELS {
            levels = Some(e.data);
        } else if e.kind == SectionKind::MATERIAL {
            material = Some(e.data);
        }
        offset = (offset + len + 3) & !3;
    }
    let material = material.ok_or(malformed(Field::MissingSection, 1, 1))?;
    let target = out.get_mut(unpacked_at..unpacked_at + packed.length).ok_or(malformed(
        Field::PackedLength,
        0,
        packed.length as i64,
    ))?;
    if kind == SectionKind::PACKED_JPEG {
        let (width, height, mip_count, _, channels) = parse_material(material)?;
        let sizes = core::array::from_fn(|m| mip_size(width, height, mip_count, m as u32));
        let body = Jpeg::parse_streams(payload, &channels, sizes, mip_count, Streams::Bare)?;
        if body.indexed_len() != packed.length {
            return Err(malformed(Field::PackedLength, 0, packed.length as i64));
        }
        body.write_indexed(target)?;
    } else {
        let levels = levels.ok_or(malformed(Field::MissingSection, 2, 2))?;
        let mut decoder = RangeDecoder::new(payload)?;
        for grid in grid_records(levels)? {
            let grid = grid?;
            let data = grid_data(target, &grid)?;
            code_grid(&grid, |p, _| decoder.bit(p), data)?;
        }
        decoder.finish()?;
    }
    let crc = file_checksum(out);
    put_u32(out, 20, crc);
    Ok(total)
}

/// Where a grid's codes lie and how they are shaped, read from its LEVELS record.
#[derive(Clone, Copy, Debug)]
struct GridRecord {
    index: usize,
    width: u32,
    height: u32,
    channels: u32,
    bits: u32,
    offset: usize,
    length: usize,
}

/// The grid records of a LEVELS section, each checked as the parser checks it (§5.1), but for its
/// quantization and its data's place in LATENTS: the whole section is validated again when the
/// unpacked file is parsed.
fn grid_records(
    levels: &[u8],
) -> Result<impl Iterator<Item = Result<GridRecord, Error>> + '_, Error> {
    let (_, grid_count) = levels_counts(levels)?;
    let mut pos = LEVELS_HEADER_LEN;
    Ok((0..grid_count).map(move |index| {
        let shape = grid_shape(levels, pos, index)?;
        pos += GRID_RECORD_LEN + 4 * usize::from(shape.channels);
        Ok(GridRecord {
            index,
            width: u32::from(shape.width),
            height: u32::from(shape.height),
            channels: u32::from(shape.channels),
            bits: u32::from(shape.bits),
            offset: shape.offset,
            length: shape.length,
        })
    }))
}

fn grid_data<'a>(latents: &'a mut [u8], grid: &GridRecord) -> Result<&'a mut [u8], Error> {
    let available = latents.len();
    grid.offset.checked_add(grid.length).and_then(|end| latents.get_mut(grid.offset..end)).ok_or(
        Error::Truncated {
            field: Field::GridDataOffset,
            index: grid.index as u32,
            needed: grid.offset as u64 + grid.length as u64,
            available: available as u64,
        },
    )
}

/// Runs the context model over one grid: channel by channel, rows top to bottom, cells left to
/// right, each code's bits from the most significant. `coder(p, bit)` codes `bit` (the encoder)
/// or decodes one (the decoder, whose `data` is zero and so offers 0) with the adaptive
/// probability `p`, and returns the bit; the codes come from or go to `data`, bit-packed as §4.1
/// lays them out.
fn code_grid(
    grid: &GridRecord,
    mut coder: impl FnMut(&mut u16, u32) -> Result<u32, Error>,
    data: &mut [u8],
) -> Result<(), Error> {
    let (w, h, c, b) =
        (grid.width as usize, grid.height as usize, grid.channels as usize, grid.bits);
    let top = 1u32 << b;
    for j in 0..c {
        // Every channel starts from even odds.
        let mut probs = [PROB_ONE / 2; CONTEXTS];
        for y in 0..h {
            let mut left = 4; // no neighbour at x = 0
            for x in 0..w {
                let index = (y * w + x) * c + j;
                let up = if y > 0 { class(get_code(data, index - w * c, b), b) } else { 4 };
                let base = (left * CLASSES + up) * 256;
                let known = get_code(data, index, b);
                let mut node = 1u32;
                for k in (0..b).rev() {
                    let Some(p) = probs.get_mut(base + node as usize) else { break };
                    node = 2 * node + coder(p, (known >> k) & 1)?;
                }
                let code = node - top;
                set_code(data, index, b, code);
                left = class(code, b);
            }
        }
    }
    Ok(())
}

/// The neighbour class of a code: its two most significant bits.
fn class(code: u32, bits: u32) -> usize {
    (code >> bits.saturating_sub(2)) as usize
}

/// Code `index` of a bit-packed grid (§4.1); bits past the end read as 0.
fn get_code(data: &[u8], index: usize, bits: u32) -> u32 {
    let bit = index * bits as usize;
    let word =
        u64::from(u32_at(data, bit / 32 * 4)) | (u64::from(u32_at(data, bit / 32 * 4 + 4)) << 32);
    ((word >> (bit % 32)) & ((1 << bits) - 1)) as u32
}

/// Writes code `index` of a bit-packed grid, clearing what was there (bits past the end of
/// `data` are dropped).
fn set_code(data: &mut [u8], index: usize, bits: u32, code: u32) {
    let bit = index * bits as usize;
    let at = bit / 32 * 4;
    let shift = bit % 32;
    let mask = ((1u64 << bits) - 1) << shift;
    let old = u64::from(u32_at(data, at)) | (u64::from(u32_at(data, at + 4)) << 32);
    let new = (old & !mask) | (u64::from(code) << shift);
    // The high word is written back unchanged where the code does not reach it.
    copy(data, at, &(new as u32).to_le_bytes());
    copy(data, at + 4, &((new >> 32) as u32).to_le_bytes());
}

fn put_u32(out: &mut [u8], at: usize, v: u32) {
    copy(out, at, &v.to_le_bytes());
}

fn copy(out: &mut [u8], at: usize, src: &[u8]) {
    if let Some(dst) = at.checked_add(src.len()).and_then(|end| out.get_mut(at..end)) {
        dst.copy_from_slice(src);
    }
}

fn write_header(out: &mut [u8], header: &Header, minor: u16, total: usize, sections: usize) {
    copy(out, 0, &header.magic);
    copy(out, 4, &header.version_major.to_le_bytes());
    copy(out, 6, &minor.to_le_bytes());
    put_u32(out, 8, header.flags);
    put_u32(out, 12, total as u32);
    put_u32(out, 16, sections as u32);
}

/// Adapts a probability (of a 0) towards the bit just coded.
fn adapt(p: &mut u16, bit: u32) {
    if bit == 0 {
        *p += (PROB_ONE - *p) >> ADAPT_SHIFT;
    } else {
        *p -= *p >> ADAPT_SHIFT;
    }
}

/// The decoding half of the range coder (§12.3).
struct RangeDecoder<'a> {
    range: u32,
    code: u32,
    stream: &'a [u8],
    pos: usize,
}

impl<'a> RangeDecoder<'a> {
    fn new(stream: &'a [u8]) -> Result<Self, Error> {
        let mut d = RangeDecoder { range: u32::MAX, code: 0, stream, pos: 0 };
        for _ in 0..4 {
            d.code = (d.code << 8) | d.next()?;
        }
        Ok(d)
    }

    fn next(&mut self) -> Result<u32, Error> {
        let byte = self.stream.get(self.pos).ok_or(Error::Truncated {
            field: Field::PackedStream,
            index: 0,
            needed: self.pos as u64 + 1,
            available: self.stream.len() as u64,
        })?;
        self.pos += 1;
        Ok(u32::from(*byte))
    }

    fn bit(&mut self, p: &mut u16) -> Result<u32, Error> {
        let bound = (self.range >> PROB_BITS) * u32::from(*p);
        let bit = if self.code < bound {
            self.range = bound;
            0
        } else {
            self.code -= bound;
            self.range -= bound;
            1
        };
        adapt(p, bit);
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next()?;
        }
        Ok(bit)
    }

    /// A valid stream ends exactly where its last decision's bytes end.
    fn finish(self) -> Result<(), Error> {
        if self.pos != self.stream.len() {
            return Err(malformed(Field::PackedStream, 0, self.pos as i64));
        }
        Ok(())
    }
}

#[cfg(feature = "alloc")]
mod write {
    extern crate alloc;

    use super::*;
    use alloc::borrow::Cow;
    use alloc::vec::Vec;

    /// The encoding half of the range coder: carries propagate through a run of pending 0xFF
    /// bytes; the first byte, always 0, is not written.
    struct RangeEncoder {
        low: u64,
        range: u32,
        cache: u8,
        pending: u64,
        started: bool,
        out: Vec<u8>,
    }

    impl RangeEncoder {
        fn new() -> Self {
            RangeEncoder {
                low: 0,
                range: u32::MAX,
                cache: 0,
                pending: 0,
                started: false,
                out: Vec::new(),
            }
        }

        fn bit(&mut self, p: &mut u16, bit: u32) -> u32 {
            let bound = (self.range >> PROB_BITS) * u32::from(*p);
            if bit == 0 {
                self.range = bound;
            } else {
                self.low += u64::from(bound);
                self.range -= bound;
            }
            adapt(p, bit);
            while self.range < TOP {
                self.range <<= 8;
                self.shift_low();
            }
            bit
        }

        fn shift_low(&mut self) {
            if self.low < 0xFF00_0000 || self.low >= 1 << 32 {
                let carry = (self.low >> 32) as u8;
                if self.started {
                    self.out.push(self.cache.wrapping_add(carry));
                }
                self.started = true;
                for _ in 0..self.pending {
                    self.out.push(0xFFu8.wrapping_add(carry));
                }
                self.pending = 0;
                self.cache = (self.low >> 24) as u8;
            } else {
                self.pending += 1;
            }
            self.low = (self.low & 0x00FF_FFFF) << 8;
        }

        fn finish(mut self) -> Vec<u8> {
            for _ in 0..5 {
                self.shift_low();
            }
            self.out
        }
    }

    /// Decodes a packed file into the fixed-rate file it stands for; a file that is not packed
    /// is returned as it is, borrowed (zero-copy). Then `Container::parse` the result.
    pub fn unpack(bytes: &[u8], options: ParseOptions) -> Result<Cow<'_, [u8]>, Error> {
        let Some(len) = unpacked_len(bytes)? else { return Ok(Cow::Borrowed(bytes)) };
        let mut out = Vec::new();
        out.try_reserve_exact(len).map_err(|_| Error::OutOfMemory { bytes: len as u64 })?;
        out.resize(len, 0);
        unpack_into(bytes, options, &mut out)?;
        Ok(Cow::Owned(out))
    }

    /// Packs a fixed-rate file (§12): a neural material's latents entropy-coded, a JPEG
    /// material's streams without their index. The result unpacks to exactly `bytes` (checked
    /// before it is returned). A file that is already packed is returned as it is; a file whose
    /// layout is not the one this crate writes (sections in table order at 4-byte boundaries,
    /// grids back to back, unused bits zero), or a JPEG material whose index a scan of its
    /// streams does not rebuild, is refused (`BadArgument Layout`).
    pub fn pack(bytes: &[u8]) -> Result<Vec<u8>, Error> {
        if unpacked_len(bytes)?.is_some() {
            let mut out = Vec::new();
            out.extend_from_slice(bytes);
            return Ok(out);
        }
        let material = crate::Container::parse(bytes)?;
        let refuse =
            |value: u64| Error::BadArgument { argument: crate::Argument::Layout, value, limit: 0 };
        let header = read_header(bytes)?;
        let entries = section_entries(bytes, &header)?;
        let find = |kind| entries.iter().position(|e: &SectionEntry<'_>| e.kind == kind);
        let (replaced, kind, coder, payload) = match material.jpeg() {
            Some(jpeg) => {
                let bare = jpeg.bare_section().ok_or(refuse(2))?;
                (find(SectionKind::JPEG), SectionKind::PACKED_JPEG, CODER_JPEG_SCAN, bare)
            }
            None => {
                let at = find(SectionKind::LATENTS);
                let levels = find(SectionKind::LEVELS).and_then(|i| entries.get(i));
                let latents = at.and_then(|i| entries.get(i));
                let (Some(levels), Some(latents)) = (levels, latents) else {
                    return Err(refuse(1));
                };
                let stream = encode_latents(levels.data, latents.data)?;
                (at, SectionKind::PACKED_LATENTS, CODER_RANGE_NEIGHBOURS, stream)
            }
        };
        let replaced = replaced.ok_or(refuse(1))?;
        let original = entries.get(replaced).ok_or(refuse(1))?.data;
        let mut section = Vec::with_capacity(PACKED_HEADER_LEN + payload.len());
        section.extend_from_slice(&(original.len() as u32).to_le_bytes());
        section.extend_from_slice(&[coder, 0]);
        section.extend_from_slice(&header.version_minor.to_le_bytes());
        section.extend_from_slice(&payload);
        let table_end = HEADER_LEN + SECTION_ENTRY_LEN * entries.len();
        let mut out = alloc::vec![0u8; table_end];
        write_header(
            &mut out,
            &header,
            crate::format::version::PACKED_VERSION_MINOR.max(header.version_minor),
            0,
            entries.len(),
        );
        for (i, e) in entries.iter().enumerate() {
            let (kind, data) =
                if i == replaced { (kind, section.as_slice()) } else { (e.kind, e.data) };
            let t = HEADER_LEN + SECTION_ENTRY_LEN * i;
            let offset = out.len();
            put_u32(&mut out, t, kind.0);
            // A packed section is always REQUIRED; unpacking gives the section it stands for
            // that flag, so a file whose LATENTS or JPEG lacks it does not round-trip and is
            // refused below.
            let flags = if i == replaced { SECTION_REQUIRED } else { e.flags };
            put_u32(&mut out, t + 4, flags);
            put_u32(&mut out, t + 8, offset as u32);
            put_u32(&mut out, t + 12, data.len() as u32);
            out.extend_from_slice(data);
            out.resize((out.len() + 3) & !3, 0);
        }
        let total = u32::try_from(out.len()).map_err(|_| refuse(out.len() as u64))?;
        put_u32(&mut out, 12, total);
        let crc = file_checksum(&out);
        put_u32(&mut out, 20, crc);
        // Nothing is lost: the packed file must unpack to the very bytes it came from.
        if unpack(&out, ParseOptions::default())?.as_ref() != bytes {
            return Err(refuse(1));
        }
        Ok(out)
    }

    /// The length in bytes of the coded stream (§12.3) of latent grids given as one code per
    /// latent — `(width, height, channels, bits, codes)`, codes in §4.1's order (cell by cell,
    /// channels innermost) — without writing a file: what packing such a LATENTS section
    /// makes of it, for an encoder that steers its rate while it trains.
    pub fn coded_latents_len(grids: &[(u32, u32, u32, u32, &[u8])]) -> usize {
        let mut encoder = RangeEncoder::new();
        for (index, &(width, height, channels, bits, codes)) in grids.iter().enumerate() {
            let bits = bits.clamp(1, 8);
            let mut data = crate::writer::pack_codes(codes, bits as u8);
            let grid =
                GridRecord { index, width, height, channels, bits, offset: 0, length: data.len() };
            // Codes that do not fill the grid code as zeros (the encoder's coder never fails).
            let _ = code_grid(&grid, |p, bit| Ok(encoder.bit(p, bit)), &mut data);
        }
        encoder.finish().len()
    }

    /// The coded stream of a LATENTS section whose grids LEVELS describes (§12.2–12.3).
    fn encode_latents(levels: &[u8], latents: &[u8]) -> Result<Vec<u8>, Error> {
        let mut scratch = Vec::new();
        scratch.extend_from_slice(latents);
        let mut encoder = RangeEncoder::new();
        for grid in grid_records(levels)? {
            let grid = grid?;
            let data = grid_data(&mut scratch, &grid)?;
            code_grid(&grid, |p, bit| Ok(encoder.bit(p, bit)), data)?;
        }
        Ok(encoder.finish())
    }
}
#[cfg(feature = "alloc")]
pub use write::{coded_latents_len, pack, unpack};
