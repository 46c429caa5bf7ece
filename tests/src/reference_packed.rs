//! A second, independent implementation of the entropy-coded latents of docs/FORMAT.md §12
//! (PACKED_LATENTS, kind 6), written from the specification text only — §1 (file layout, header,
//! section table, checksum), §4.1 (bit packing), §5.1 (grid records) and §12 — without reading
//! `nmat-core`'s `format/` code. It exists so that the tests can check the two against each other
//! byte for byte: where they disagree, either the text or one of the implementations is wrong.
//!
//! Plain and slow on purpose: whole-file copies, one bit at a time, errors as strings. The only
//! thing borrowed from `nmat-core` is the CRC-32 of §1.4.
//!
//! - [`unpack`]: a packed file → the fixed-rate file of §12.1 ("the unpacked file").
//! - [`pack`]: a fixed-rate neural file → a packed file, with a range *encoder* written from the
//!   description at the end of §12.3 (LZMA's carry-propagating encoder).

use crate::reference_container::*;

/// §12.1: the only coder defined.
const CODER_RANGE_NEIGHBOURS: u8 = 1;

/// §12.2: probabilities are 12-bit, start at one half, and adapt by a shift of 5.
const PROB_ONE: u32 = 4096;
const PROB_START: u32 = 2048;
const ADAPT_SHIFT: u32 = 5;
/// §12.3: renormalize while `range < 2^24`.
const RANGE_TOP: u32 = 1 << 24;

// ---------------------------------------------------------------------------------------------
// Grid records (§5.1) and bit packing (§4.1)
// ---------------------------------------------------------------------------------------------

/// The fields of a §5.1 grid record that packing needs.
#[derive(Clone, Copy, Debug)]
struct Grid {
    width: usize,
    height: usize,
    channels: usize,
    bits: u32,
    data_offset: usize,
    data_length: usize,
}

impl Grid {
    /// §4.1: codes are stored y, then x, then channel (channel fastest).
    fn code_index(&self, x: usize, y: usize, channel: usize) -> usize {
        (y * self.width + x) * self.channels + channel
    }

    fn code_count(&self) -> usize {
        self.width * self.height * self.channels
    }
}

/// The grid records of a LEVELS section, in record order (§5.1), checked so far as packing relies
/// on them: sizes in range and `data_length = 4·ceil(w·h·c·b / 32)`, `data_offset` a multiple of 4
/// and the data inside a LATENTS section of `latents_length` bytes.
fn grid_records(levels: &[u8], latents_length: usize) -> Result<Vec<Grid>, String> {
    let grid_count = *levels.get(1).ok_or("LEVELS is shorter than its header")? as usize;
    if !(1..=16).contains(&grid_count) {
        return Err(format!("grid_count {grid_count}"));
    }
    let mut grids = Vec::new();
    let mut at = 20; // level_count, grid_count, reserved, mip_to_level[16]
    for g in 0..grid_count {
        let width = u16_at(levels, at)? as usize;
        let height = u16_at(levels, at + 2)? as usize;
        let channels = *levels.get(at + 4).ok_or("grid record past the end")? as usize;
        let bits = u32::from(*levels.get(at + 5).ok_or("grid record past the end")?);
        let data_offset = u32_at(levels, at + 8)? as usize;
        let data_length = u32_at(levels, at + 12)? as usize;
        if !(1..=16384).contains(&width) || !(1..=16384).contains(&height) {
            return Err(format!("grid {g}: size {width}×{height}"));
        }
        if !(1..=16).contains(&channels) || !(1..=8).contains(&bits) {
            return Err(format!("grid {g}: {channels} channels of {bits} bits"));
        }
        let grid = Grid { width, height, channels, bits, data_offset, data_length };
        let total_bits = grid.code_count() * bits as usize;
        if data_length != 4 * total_bits.div_ceil(32) {
            return Err(format!("grid {g}: data_length {data_length}"));
        }
        if !data_offset.is_multiple_of(4) || data_offset + data_length > latents_length {
            return Err(format!(
                "grid {g}: data {data_offset}+{data_length} not in LATENTS of {latents_length}"
            ));
        }
        grids.push(grid);
        at += 16 + 4 * channels;
    }
    Ok(grids)
}

/// §4.1: bit `k` of a grid's stream is bit `k mod 32` of little-endian word `floor(k / 32)`,
/// which is bit `k mod 8` of byte `floor(k / 8)`.
fn read_bit(data: &[u8], k: usize) -> u32 {
    u32::from(data[k / 8] >> (k % 8)) & 1
}

fn set_bit(data: &mut [u8], k: usize) {
    data[k / 8] |= 1 << (k % 8);
}

/// Code number `i` occupies bits `i·b … i·b + b − 1`, least significant first.
fn read_code(data: &[u8], i: usize, bits: u32) -> u32 {
    let first = i * bits as usize;
    (0..bits as usize).map(|k| read_bit(data, first + k) << k).sum()
}

fn write_code(data: &mut [u8], i: usize, bits: u32, value: u32) {
    let first = i * bits as usize;
    for k in 0..bits as usize {
        if (value >> k) & 1 == 1 {
            set_bit(data, first + k);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The model (§12.2)
// ---------------------------------------------------------------------------------------------

/// `class(u)`: the two most significant bits of a `bits`-bit code (the code itself when
/// `bits ≤ 2`), or 4 for a missing neighbour.
fn class(neighbour: Option<u32>, bits: u32) -> usize {
    match neighbour {
        None => 4,
        Some(u) if bits > 2 => (u >> (bits - 2)) as usize,
        Some(u) => u as usize,
    }
}

/// The `5 · 5 · 2^b` probabilities of one grid channel, each that the next bit is 0.
struct ChannelContexts {
    bits: u32,
    probability: Vec<u32>,
}

impl ChannelContexts {
    fn new(bits: u32) -> ChannelContexts {
        ChannelContexts { bits, probability: vec![PROB_START; 25 << bits] }
    }

    /// Context `(class(left), class(up), node)`; `node` is in `1 .. 2^b`.
    fn index(&self, left: Option<u32>, up: Option<u32>, node: u32) -> usize {
        let (l, u) = (class(left, self.bits), class(up, self.bits));
        ((l * 5 + u) << self.bits) + node as usize
    }
}

/// The left and up neighbours of cell `(x, y)`, channel `j`: no wrapping.
fn neighbours(grid: &Grid, codes: &[u32], x: usize, y: usize, j: usize) -> [Option<u32>; 2] {
    let left = if x > 0 { Some(codes[grid.code_index(x - 1, y, j)]) } else { None };
    let up = if y > 0 { Some(codes[grid.code_index(x, y - 1, j)]) } else { None };
    [left, up]
}

/// §12.2's adaptation, after coding `bit` with probability `p`.
fn adapt(p: &mut u32, bit: u32) {
    if bit == 0 {
        *p += (PROB_ONE - *p) >> ADAPT_SHIFT;
    } else {
        *p -= *p >> ADAPT_SHIFT;
    }
}

// ---------------------------------------------------------------------------------------------
// The range decoder (§12.3)
// ---------------------------------------------------------------------------------------------

struct RangeDecoder<'a> {
    stream: &'a [u8],
    next: usize,
    range: u32,
    code: u32,
}

impl<'a> RangeDecoder<'a> {
    fn new(stream: &'a [u8]) -> Result<RangeDecoder<'a>, String> {
        let Some(first) = stream.get(..4) else {
            return Err(format!("a stream of {} bytes: Truncated PackedStream", stream.len()));
        };
        let code = u32::from_be_bytes([first[0], first[1], first[2], first[3]]);
        Ok(RangeDecoder { stream, next: 4, range: 0xFFFF_FFFF, code })
    }

    fn decode_bit(&mut self, p: &mut u32) -> Result<u32, String> {
        let bound = (self.range >> 12) * *p;
        let bit = if self.code < bound {
            self.range = bound;
            0
        } else {
            self.code -= bound;
            self.range -= bound;
            1
        };
        adapt(p, bit);
        while self.range < RANGE_TOP {
            let Some(&byte) = self.stream.get(self.next) else {
                return Err("read past the end of the stream: Truncated PackedStream".into());
            };
            self.next += 1;
            self.range <<= 8;
            self.code = (self.code << 8) | u32::from(byte);
        }
        Ok(bit)
    }

    fn finish(self) -> Result<(), String> {
        if self.next == self.stream.len() {
            Ok(())
        } else {
            Err(format!(
                "{} of {} stream bytes used: Malformed PackedStream",
                self.next,
                self.stream.len()
            ))
        }
    }
}

/// §12.2: one grid's codes, in storage order (§4.1), decoded channel by channel.
fn decode_grid(decoder: &mut RangeDecoder<'_>, grid: &Grid) -> Result<Vec<u32>, String> {
    let mut codes = vec![0u32; grid.code_count()];
    for j in 0..grid.channels {
        let mut contexts = ChannelContexts::new(grid.bits);
        for y in 0..grid.height {
            for x in 0..grid.width {
                let [left, up] = neighbours(grid, &codes, x, y, j);
                let mut node = 1u32;
                for _ in 0..grid.bits {
                    let ctx = contexts.index(left, up, node);
                    let bit = decoder.decode_bit(&mut contexts.probability[ctx])?;
                    node = 2 * node + bit;
                }
                codes[grid.code_index(x, y, j)] = node - (1 << grid.bits);
            }
        }
    }
    Ok(codes)
}

// ---------------------------------------------------------------------------------------------
// The range encoder (end of §12.3)
// ---------------------------------------------------------------------------------------------

/// LZMA's range encoder: `low` is kept in 64 bits so that a carry out of bit 31 is seen; a byte
/// leaving `low` is held back (`cache`, followed by `pending_ff` bytes of 0xFF) until it is known
/// that no later carry can change it.
struct RangeEncoder {
    low: u64,
    range: u32,
    cache: u8,
    pending_ff: u64,
    out: Vec<u8>,
    /// How many times a carry rippled into held-back bytes (for the tests: proof that the carry
    /// path was exercised).
    carries: u64,
}

impl RangeEncoder {
    fn new() -> RangeEncoder {
        RangeEncoder {
            low: 0,
            range: 0xFFFF_FFFF,
            cache: 0,
            pending_ff: 0,
            out: Vec::new(),
            carries: 0,
        }
    }

    fn encode_bit(&mut self, p: &mut u32, bit: u32) {
        let bound = (self.range >> 12) * *p;
        if bit == 0 {
            self.range = bound;
        } else {
            self.low += u64::from(bound);
            self.range -= bound;
        }
        adapt(p, bit);
        while self.range < RANGE_TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Shifts byte 3 of `low` out. If it is 0xFF and no carry has happened, a later carry could
    /// still turn it into 0x00 (and add one to the byte before it), so it is only counted; once a
    /// byte below 0xFF leaves, or a carry arrives, everything held back is settled and written.
    fn shift_low(&mut self) {
        let carry = self.low >> 32; // 0 or 1
        let byte3 = ((self.low >> 24) & 0xFF) as u8;
        if carry == 1 || byte3 != 0xFF {
            if carry == 1 {
                self.carries += 1;
            }
            // The cache is never 0xFF, so adding a carry to it cannot overflow.
            self.out.push(self.cache + carry as u8);
            for _ in 0..self.pending_ff {
                self.out.push(0xFFu8.wrapping_add(carry as u8));
            }
            self.pending_ff = 0;
            self.cache = byte3;
        } else {
            self.pending_ff += 1;
        }
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// Five more shifts flush `low` (and the held-back bytes); the first byte produced — the
    /// initial cache, 0 — is not written.
    fn finish(mut self) -> Result<(Vec<u8>, u64), String> {
        for _ in 0..5 {
            self.shift_low();
        }
        match self.out.first() {
            Some(0) => Ok((self.out.split_off(1), self.carries)),
            other => Err(format!("the encoder's first byte is {other:?}, not 0")),
        }
    }
}

/// §12.2: one grid's codes (storage order), encoded channel by channel.
fn encode_grid(encoder: &mut RangeEncoder, grid: &Grid, codes: &[u32]) {
    for j in 0..grid.channels {
        let mut contexts = ChannelContexts::new(grid.bits);
        for y in 0..grid.height {
            for x in 0..grid.width {
                let [left, up] = neighbours(grid, codes, x, y, j);
                let value = codes[grid.code_index(x, y, j)];
                let mut node = 1u32;
                for k in (0..grid.bits).rev() {
                    let bit = (value >> k) & 1;
                    let ctx = contexts.index(left, up, node);
                    encoder.encode_bit(&mut contexts.probability[ctx], bit);
                    node = 2 * node + bit;
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// unpack and pack
// ---------------------------------------------------------------------------------------------

/// A packed file (one PACKED_LATENTS section, §12.1) → the fixed-rate file it stands for.
pub fn unpack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let (header, sections) = read_container(bytes)?;
    if count_kind(&sections, KIND_LATENTS) != 0 || count_kind(&sections, KIND_JPEG) != 0 {
        return Err("a packed file has neither LATENTS nor JPEG".into());
    }
    only_section(&sections, KIND_MATERIAL)?;
    only_section(&sections, KIND_MLP)?;
    let levels = only_section(&sections, KIND_LEVELS)?.data;
    let packed = only_section(&sections, KIND_PACKED_LATENTS)?.data;
    if sections.iter().any(|s| s.kind == KIND_PACKED_LATENTS && s.flags & REQUIRED == 0) {
        return Err("PACKED_LATENTS without REQUIRED: Malformed SectionFlags".into());
    }

    if packed.len() < PACKED_HEADER_LEN {
        return Err(format!("PACKED_LATENTS of {} bytes", packed.len()));
    }
    let latents_length = u32_at(packed, 0)? as usize;
    let coder = packed[4];
    let reserved = packed[5];
    let unpacked_minor = u16_at(packed, 6)?;
    let stream = &packed[PACKED_HEADER_LEN..];
    if !latents_length.is_multiple_of(4) || latents_length > 256 * (stream.len() + 64) {
        return Err(format!("latents_length {latents_length}: Malformed PackedLength"));
    }
    if coder != CODER_RANGE_NEIGHBOURS {
        return Err(format!("coder {coder}: Unsupported PackedCoder"));
    }
    if reserved != 0 {
        return Err("Malformed PackedReserved".into());
    }

    let grids = grid_records(levels, latents_length)?;
    let mut latents = vec![0u8; latents_length];
    let mut decoder = RangeDecoder::new(stream)?;
    for grid in &grids {
        let codes = decode_grid(&mut decoder, grid)?;
        let data = &mut latents[grid.data_offset..grid.data_offset + grid.data_length];
        for (i, &code) in codes.iter().enumerate() {
            write_code(data, i, grid.bits, code);
        }
    }
    decoder.finish()?;

    let out_sections: Vec<(u32, u32, &[u8])> = sections
        .iter()
        .map(|s| {
            if s.kind == KIND_PACKED_LATENTS {
                (KIND_LATENTS, s.flags, latents.as_slice())
            } else {
                (s.kind, s.flags, s.data)
            }
        })
        .collect();
    write_container(&header, unpacked_minor, &out_sections)
}

/// A fixed-rate neural file (kinds 1–4 present) → a packed file: the same sections in the same
/// order with the same flags, LATENTS replaced by PACKED_LATENTS (flag `REQUIRED`) (`latents_length` = the LATENTS
/// length, coder 1, `unpacked_minor` = the input's `version_minor`), header `version_minor` 2
/// or the input's if that is higher, the header flags kept, laid out like an unpacked file (see [`write_container`]).
pub fn pack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    pack_counting_carries(bytes).map(|(packed, _)| packed)
}

/// [`pack`], also returning how many carries the range encoder propagated.
pub fn pack_counting_carries(bytes: &[u8]) -> Result<(Vec<u8>, u64), String> {
    let (header, sections) = read_container(bytes)?;
    if count_kind(&sections, KIND_PACKED_LATENTS) != 0 || count_kind(&sections, KIND_JPEG) != 0 {
        return Err("only fixed-rate neural files are packed".into());
    }
    only_section(&sections, KIND_MATERIAL)?;
    only_section(&sections, KIND_MLP)?;
    let levels = only_section(&sections, KIND_LEVELS)?.data;
    let latents = only_section(&sections, KIND_LATENTS)?.data;
    let latents_length = u32::try_from(latents.len()).map_err(|_| "LATENTS too long")?;

    let mut encoder = RangeEncoder::new();
    for grid in &grid_records(levels, latents.len())? {
        let data = &latents[grid.data_offset..grid.data_offset + grid.data_length];
        let codes: Vec<u32> =
            (0..grid.code_count()).map(|i| read_code(data, i, grid.bits)).collect();
        encode_grid(&mut encoder, grid, &codes);
    }
    let (stream, carries) = encoder.finish()?;

    let unpacked_minor = u16_at(&header, 6)?;
    let mut packed_section = Vec::with_capacity(PACKED_HEADER_LEN + stream.len());
    packed_section.extend_from_slice(&latents_length.to_le_bytes());
    packed_section.push(CODER_RANGE_NEIGHBOURS);
    packed_section.push(0);
    packed_section.extend_from_slice(&unpacked_minor.to_le_bytes());
    packed_section.extend_from_slice(&stream);

    let out_sections: Vec<(u32, u32, &[u8])> = sections
        .iter()
        .map(|s| {
            if s.kind == KIND_LATENTS {
                // §12.1: PACKED_LATENTS is always REQUIRED.
                (KIND_PACKED_LATENTS, REQUIRED, packed_section.as_slice())
            } else {
                (s.kind, s.flags, s.data)
            }
        })
        .collect();
    let packed = write_container(&header, PACKED_VERSION_MINOR.max(unpacked_minor), &out_sections)?;

    // Packing must lose nothing (§12): the input must be laid out exactly as an unpacked file is,
    // with zero padding and zero bits outside the grids' codes.
    if unpack(&packed)? != bytes {
        return Err(
            "the input is not laid out as §12.1's unpacked file: packing would lose bytes".into()
        );
    }
    Ok((packed, carries))
}
