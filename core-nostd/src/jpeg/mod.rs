//! Indexed baseline JPEG, the second codec of a material (docs/FORMAT.md §11): each map of a
//! material is one JPEG stream per mip, with an index of where every MCU starts and the absolute
//! DC values that make each MCU decodable on its own ("Variable-Rate Texture Compression:
//! Real-Time Rendering with JPEG", Kristmann, Wimmer and Schütz). Parsing validates the section
//! once; decoding an MCU never fails.

pub(crate) mod entropy;
pub use entropy::huffman_decoding;
pub(crate) mod idct;
pub(crate) mod packing;
#[cfg(feature = "alloc")]
pub mod writer;

use crate::bytes::{align4, slice, u8_at, u16_at, u32_at};
use crate::error::{Error, Field, at_most, malformed, unsupported};
use crate::format::channel::Channel;
use crate::limits::{MAX_CHANNELS, MAX_MIPS};
use entropy::{Bits, Huffman, block};

/// Version of the JPEG section this crate reads and writes.
pub const JPEG_SECTION_VERSION: u16 = 1;
pub const JPEG_HEADER_LEN: usize = 8;
pub const JPEG_MAP_RECORD_LEN: usize = 4;
pub const QUANT_TABLE_LEN: usize = 64;
pub const HUFFMAN_HEADER_LEN: usize = 20;
pub const STREAM_RECORD_LEN: usize = 20;
/// MCUs per index group: one absolute 32-bit bit offset, then eight 16-bit ones relative to it.
pub const GROUP_MCUS: usize = 9;
pub const GROUP_LEN: usize = 20;
/// Bits of one stored absolute DC value (two's complement).
pub const DC_BITS: usize = 12;
/// Quantization tables of a section.
pub const MAX_QUANT_TABLES: usize = 16;
/// Huffman tables of a section.
pub const MAX_HUFFMAN_TABLES: usize = 32;
/// Samples of the largest MCU: 16 × 16 texels of 3 channels.
pub const MAX_MCU_SAMPLES: usize = 16 * 16 * 3;

/// One map of a JPEG material: `channel_count` consecutive channels from `first_channel`, stored
/// as one component (gray) or three (YCbCr, decoded to RGB). Colour maps store luma at `luma_h ×
/// luma_v` (1 or 2 each) per chroma sample: 1×1 is 4:4:4, 2×2 is 4:2:0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JpegMap {
    pub first_channel: u8,
    pub channel_count: u8,
    pub luma_h: u8,
    pub luma_v: u8,
}

/// Where one stream (a map at a mip) lies in a JPEG section, in bytes from the section's start,
/// and which tables it uses ([`Jpeg::stream_parts`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StreamParts {
    /// The MCU index (FORMAT.md §11.2).
    pub index_at: usize,
    /// The 12-bit DC values.
    pub dc_at: usize,
    /// The entropy-coded data and its length in bytes.
    pub data_at: usize,
    pub data_len: usize,
    /// MCU columns and rows.
    pub mcus: (u32, u32),
    /// The quantization table of Y, Cb, Cr (64 bytes, zigzag order; gray: Y only).
    pub quant_at: [usize; 3],
    /// The DC and AC Huffman table of Y, Cb, Cr ([`Jpeg::huffman_table`]).
    pub dc_table: [u8; 3],
    pub ac_table: [u8; 3],
}

/// Why a Huffman table cannot be stored in a JPEG material (docs/FORMAT.md §11.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HuffmanProblem {
    /// No codes, more than 256, or a number of symbols other than the counts add up to.
    Count(usize),
    /// The codes up to this length overflow it, or the all-ones code is used.
    Length(u32),
    /// A symbol a table of its class cannot hold.
    Symbol(u8),
}

/// Checks a Huffman table of `class` (0 DC, 1 AC) as a JPEG material stores it: canonical codes
/// that fit their lengths without the all-ones code (ITU T.81 annex C) and baseline symbols (DC:
/// 0 ..= 11; AC: run/size with size ≤ 10, size 0 only in end-of-block and 16 zeros).
pub fn check_huffman_table(
    class: u8,
    counts: &[u8; 16],
    values: &[u8],
) -> Result<(), HuffmanProblem> {
    let total: usize = counts.iter().map(|&n| usize::from(n)).sum();
    if total != values.len() || total == 0 || total > 256 {
        return Err(HuffmanProblem::Count(values.len()));
    }
    let mut code = 0u32;
    for (l, &n) in (1..=16u32).zip(counts) {
        code += u32::from(n);
        if code >= 1 << l {
            return Err(HuffmanProblem::Length(l));
        }
        code <<= 1;
    }
    let symbol_ok = |&v: &u8| match class {
        0 => v <= 11,
        _ => v & 15 <= 10 && (v & 15 != 0 || v == 0 || v == 0xF0),
    };
    match values.iter().find(|v| !symbol_ok(v)) {
        Some(&bad) => Err(HuffmanProblem::Symbol(bad)),
        None => Ok(()),
    }
}

impl JpegMap {
    /// Width and height of one MCU in texels.
    pub fn mcu_size(&self) -> (u32, u32) {
        (8 * u32::from(self.luma_h), 8 * u32::from(self.luma_v))
    }
    /// Blocks of one MCU (luma blocks, plus one Cb and one Cr for colour).
    pub fn blocks_per_mcu(&self) -> usize {
        let luma = usize::from(self.luma_h) * usize::from(self.luma_v);
        if self.channel_count == 3 { luma + 2 } else { luma }
    }
}

/// What a section's streams hold: their index, DC values and entropy-coded data (the JPEG
/// section, FORMAT.md §11), or the entropy-coded data alone, the index to be rebuilt (the body of
/// a PACKED_JPEG section, §12.5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Streams {
    Indexed,
    Bare,
}

/// The JPEG section of a material, validated.
#[derive(Clone, Debug)]
pub struct Jpeg<'a> {
    section: &'a [u8],
    streams: Streams,
    maps: heapless::Vec<JpegMap, MAX_CHANNELS>,
    quant_at: usize,
    huffman_at: heapless::Vec<u32, MAX_HUFFMAN_TABLES>,
    streams_at: usize,
    mip_count: u8,
    /// Mip sizes, for the MCU grid of every stream.
    mip_sizes: [(u32, u32); MAX_MIPS],
}

/// One stream (a map at a mip), located.
pub(crate) struct Stream<'a> {
    index: &'a [u8],
    dc: &'a [u8],
    data: &'a [u8],
    mcus_x: u32,
    map: JpegMap,
    /// Quantization table, DC and AC Huffman tables of each component.
    tables: [(&'a [u8], Huffman<'a>, Huffman<'a>); 3],
}

/// Where each part of a stream lies: index bytes, DC bytes (padded), MCU count (a bare stream
/// has neither index nor DC values).
fn stream_layout(map: &JpegMap, (w, h): (u32, u32), streams: Streams) -> (usize, usize, usize) {
    let (mw, mh) = map.mcu_size();
    let mcus = w.div_ceil(mw) as usize * h.div_ceil(mh) as usize;
    if streams == Streams::Bare {
        return (0, 0, mcus);
    }
    let values = if map.channel_count == 3 { 3 } else { 1 };
    let index = mcus.div_ceil(GROUP_MCUS) * GROUP_LEN;
    let dc = align4((mcus * values * DC_BITS).div_ceil(8));
    (index, dc, mcus)
}

impl<'a> Jpeg<'a> {
    /// Validates a JPEG section for a material of `channels` and the given mip chain.
    pub(crate) fn parse(
        s: &'a [u8],
        channels: &[Channel<'_>],
        mip_sizes: [(u32, u32); MAX_MIPS],
        mip_count: u8,
    ) -> Result<Jpeg<'a>, Error> {
        Self::parse_streams(s, channels, mip_sizes, mip_count, Streams::Indexed)
    }

    /// [`Jpeg::parse`] of a section whose streams are `streams`: a bare stream's record may hold
    /// its restart interval in bytes 18..20 (§12.5).
    pub(crate) fn parse_streams(
        s: &'a [u8],
        channels: &[Channel<'_>],
        mip_sizes: [(u32, u32); MAX_MIPS],
        mip_count: u8,
        streams: Streams,
    ) -> Result<Jpeg<'a>, Error> {
        need(s, 0, JPEG_HEADER_LEN, Field::JpegVersion, 0)?;
        let version = u16_at(s, 0);
        if version != JPEG_SECTION_VERSION {
            return Err(unsupported(Field::JpegVersion, 0, version));
        }
        let (map_count, quant_count, huffman_count) =
            (usize::from(u8_at(s, 2)), usize::from(u8_at(s, 3)), usize::from(u8_at(s, 4)));
        if map_count == 0 {
            return Err(malformed(Field::JpegMapCount, 0, 0));
        }
        at_most(Field::JpegMapCount, 0, map_count as u64, channels.len() as u64)?;
        if quant_count == 0 {
            return Err(malformed(Field::JpegQuantCount, 0, 0));
        }
        at_most(Field::JpegQuantCount, 0, quant_count as u64, MAX_QUANT_TABLES as u64)?;
        if huffman_count < 2 {
            return Err(malformed(Field::JpegHuffmanCount, 0, huffman_count as i64));
        }
        at_most(Field::JpegHuffmanCount, 0, huffman_count as u64, MAX_HUFFMAN_TABLES as u64)?;
        if let Some(i) = (5..8).find(|&i| u8_at(s, i) != 0) {
            return Err(malformed(Field::JpegReserved, 0, u8_at(s, i)));
        }
        // Maps: consecutive, covering every channel once.
        let mut maps = heapless::Vec::new();
        let mut pos = JPEG_HEADER_LEN;
        let mut next_channel = 0usize;
        for m in 0..map_count {
            let r = take(s, pos, JPEG_MAP_RECORD_LEN, Field::JpegMap, m)?;
            let map = JpegMap {
                first_channel: u8_at(r, 0),
                channel_count: u8_at(r, 1),
                luma_h: u8_at(r, 2),
                luma_v: u8_at(r, 3),
            };
            if usize::from(map.first_channel) != next_channel {
                return Err(malformed(Field::JpegMap, m, map.first_channel));
            }
            if !matches!(map.channel_count, 1 | 3) {
                return Err(unsupported(Field::JpegMapChannels, m, map.channel_count));
            }
            let sampling_ok = match map.channel_count {
                1 => (map.luma_h, map.luma_v) == (1, 1),
                _ => matches!(map.luma_h, 1 | 2) && matches!(map.luma_v, 1 | 2),
            };
            if !sampling_ok {
                let code = u16::from(map.luma_h) << 8 | u16::from(map.luma_v);
                return Err(unsupported(Field::JpegSubsampling, m, code));
            }
            next_channel += usize::from(map.channel_count);
            maps.push(map).map_err(|_| malformed(Field::JpegMapCount, m, map_count as i64))?;
            pos += JPEG_MAP_RECORD_LEN;
        }
        if next_channel != channels.len() {
            return Err(malformed(Field::JpegMap, map_count, next_channel as i64));
        }
        // Quantization tables: 64 values 1..=255 in zigzag order.
        let quant_at = pos;
        for t in 0..quant_count {
            let q = take(s, pos, QUANT_TABLE_LEN, Field::JpegQuantTable, t)?;
            if q.contains(&0) {
                return Err(malformed(Field::JpegQuantTable, t, 0));
            }
            pos += QUANT_TABLE_LEN;
        }
        // Huffman tables.
        let mut huffman_at = heapless::Vec::new();
        for t in 0..huffman_count {
            let head = take(s, pos, HUFFMAN_HEADER_LEN, Field::JpegHuffmanTable, t)?;
            let (class, count) = (u8_at(head, 0), usize::from(u16_at(head, 2)));
            if class > 1 || u8_at(head, 1) != 0 {
                return Err(malformed(Field::JpegHuffmanTable, t, class));
            }
            let counts: [u8; 16] = core::array::from_fn(|i| u8_at(head, 4 + i));
            if count == 0 || count > 256 {
                return Err(malformed(Field::JpegHuffmanTable, t, count as i64));
            }
            let values = take(s, pos + HUFFMAN_HEADER_LEN, count, Field::JpegHuffmanTable, t)?;
            check_huffman_table(class, &counts, values).map_err(|problem| match problem {
                HuffmanProblem::Count(n) => malformed(Field::JpegHuffmanTable, t, n as i64),
                HuffmanProblem::Length(l) => malformed(Field::JpegHuffmanTable, t, l),
                HuffmanProblem::Symbol(v) => malformed(Field::JpegHuffmanSymbol, t, v),
            })?;
            let _ = huffman_at.push(pos as u32);
            pos = align4(pos + HUFFMAN_HEADER_LEN + count);
        }
        // Stream records, map-major, and the streams they point at (in order, not overlapping).
        let streams_at = pos;
        let records = map_count * usize::from(mip_count);
        let mut data_start = streams_at + records * STREAM_RECORD_LEN;
        need(s, streams_at, records * STREAM_RECORD_LEN, Field::JpegStream, 0)?;
        for (m, map) in maps.iter().enumerate() {
            for (mip, &size) in mip_sizes.iter().enumerate().take(usize::from(mip_count)) {
                let i = m * usize::from(mip_count) + mip;
                let r = take(
                    s,
                    streams_at + i * STREAM_RECORD_LEN,
                    STREAM_RECORD_LEN,
                    Field::JpegStream,
                    i,
                )?;
                let offset = u32_at(r, 0) as usize;
                let entropy = u32_at(r, 4) as usize;
                if offset < data_start || !offset.is_multiple_of(4) {
                    return Err(malformed(Field::JpegStreamOffset, i, offset as i64));
                }
                let components = usize::from(map.channel_count);
                for (c, kind) in (0..3).flat_map(|c| (0..3).map(move |k| (c, k))) {
                    let t = usize::from(u8_at(r, 8 + 3 * kind + c));
                    let limit = if kind == 0 { quant_count } else { huffman_count };
                    let used = c < components;
                    let class_ok = kind == 0
                        || !used
                        || huffman_at
                            .get(t)
                            .is_some_and(|&at| usize::from(u8_at(s, at as usize)) == kind - 1);
                    if (used && (t >= limit || !class_ok)) || (!used && t != 0) {
                        return Err(malformed(Field::JpegTableRef, i, t));
                    }
                }
                let reserved = if streams == Streams::Bare { 17..18 } else { 17..20 };
                if let Some(k) = reserved.into_iter().find(|&k| u8_at(r, k) != 0) {
                    return Err(malformed(Field::JpegReserved, i, u8_at(r, k)));
                }
                let (index_len, dc_len, mcus) = stream_layout(map, size, streams);
                let total = index_len + dc_len + entropy;
                let body = take(s, offset, total, Field::JpegStreamLength, i)?;
                if streams == Streams::Indexed {
                    check_index(body.get(..index_len).unwrap_or(&[]), mcus, entropy, i)?;
                }
                data_start = align4(offset + total);
            }
        }
        if align4(data_start) < s.len() {
            return Err(malformed(Field::SectionContent, 5, s.len() as i64));
        }
        Ok(Jpeg {
            section: s,
            streams,
            maps,
            quant_at,
            huffman_at,
            streams_at,
            mip_count,
            mip_sizes,
        })
    }

    /// The maps, in channel order.
    pub fn maps(&self) -> &[JpegMap] {
        &self.maps
    }

    /// The section's bytes (FORMAT.md §11.1), which [`Jpeg::stream_parts`] and
    /// [`Jpeg::huffman_table`] point into.
    pub fn section(&self) -> &'a [u8] {
        self.section
    }

    /// Where the stream of `map` at `mip` lies in [`Jpeg::section`] and which tables it uses:
    /// for decoders that read the section themselves (the GPU runtime). `None` for a map or mip
    /// the material lacks.
    pub fn stream_parts(&self, map: usize, mip: u32) -> Option<StreamParts> {
        if mip >= u32::from(self.mip_count) {
            return None;
        }
        let m = *self.maps.get(map)?;
        let size = *self.mip_sizes.get(mip as usize)?;
        let r = self.streams_at
            + (map * usize::from(self.mip_count) + mip as usize) * STREAM_RECORD_LEN;
        let rec = slice(self.section, r, STREAM_RECORD_LEN)?;
        let (offset, entropy) = (u32_at(rec, 0) as usize, u32_at(rec, 4) as usize);
        let (index_len, dc_len, _) = stream_layout(&m, size, self.streams);
        let (mw, mh) = m.mcu_size();
        Some(StreamParts {
            index_at: offset,
            dc_at: offset + index_len,
            data_at: offset + index_len + dc_len,
            data_len: entropy,
            mcus: (size.0.div_ceil(mw), size.1.div_ceil(mh)),
            quant_at: core::array::from_fn(|c| {
                self.quant_at + usize::from(u8_at(rec, 8 + c)) * QUANT_TABLE_LEN
            }),
            dc_table: core::array::from_fn(|c| u8_at(rec, 11 + c)),
            ac_table: core::array::from_fn(|c| u8_at(rec, 14 + c)),
        })
    }

    /// Huffman table `t`: its class (0 DC, 1 AC), its code counts per length 1 ..= 16 and where
    /// its symbols start in [`Jpeg::section`].
    pub fn huffman_table(&self, t: u8) -> Option<(u8, [u8; 16], usize)> {
        let at = *self.huffman_at.get(usize::from(t))? as usize;
        let counts = core::array::from_fn(|i| u8_at(self.section, at + 4 + i));
        Some((u8_at(self.section, at), counts, at + HUFFMAN_HEADER_LEN))
    }

    /// Number of MCUs of map `map` at `mip` and the columns of its MCU grid.
    pub fn mcu_grid(&self, map: usize, mip: u32) -> (u32, u32) {
        let (Some(m), Some(&(w, h))) = (self.maps.get(map), self.mip_sizes.get(mip as usize))
        else {
            return (0, 0);
        };
        if mip >= u32::from(self.mip_count) {
            return (0, 0);
        }
        let (mw, mh) = m.mcu_size();
        (w.div_ceil(mw), h.div_ceil(mh))
    }

    /// Bits spent on index and DC values (the random-access overhead) and on entropy-coded
    /// data, over every stream.
    pub fn overhead_bits(&self) -> (u64, u64) {
        (0..self.maps.len())
            .flat_map(|m| (0..u32::from(self.mip_count)).map(move |mip| (m, mip)))
            .map(|(m, mip)| self.stream_overhead_bits(m, mip))
            .fold((0, 0), |(a, b), (x, y)| (a + x, b + y))
    }

    /// [`Jpeg::overhead_bits`] of the stream of `map` at `mip` ((0, 0) for one the material
    /// lacks).
    pub fn stream_overhead_bits(&self, map: usize, mip: u32) -> (u64, u64) {
        let (Some(m), Some(&size)) = (self.maps.get(map), self.mip_sizes.get(mip as usize)) else {
            return (0, 0);
        };
        if mip >= u32::from(self.mip_count) {
            return (0, 0);
        }
        let (index, _, mcus) = stream_layout(m, size, self.streams);
        let values = if m.channel_count == 3 { 3 } else { 1 };
        let dc = if self.streams == Streams::Bare { 0 } else { mcus * values * DC_BITS };
        let r = self.streams_at
            + (map * usize::from(self.mip_count) + mip as usize) * STREAM_RECORD_LEN;
        (8 * index as u64 + dc as u64, 8 * u64::from(u32_at(self.section, r + 4)))
    }

    fn huffman(&self, t: u8) -> Huffman<'a> {
        let at = self.huffman_at.get(usize::from(t)).map_or(0, |&a| a as usize);
        let counts: [u8; 16] = core::array::from_fn(|i| u8_at(self.section, at + 4 + i));
        let count = usize::from(u16_at(self.section, at + 2));
        Huffman::new(&counts, slice(self.section, at + HUFFMAN_HEADER_LEN, count).unwrap_or(&[]))
    }

    pub(crate) fn stream(&self, map: usize, mip: u32) -> Option<Stream<'a>> {
        let p = self.stream_parts(map, mip)?;
        let part = |from: usize, to: usize| self.section.get(from..to);
        let tables = core::array::from_fn(|c| {
            let table = |t: &[u8; 3]| self.huffman(t.get(c).copied().unwrap_or(0));
            let quant = p.quant_at.get(c).and_then(|&q| slice(self.section, q, QUANT_TABLE_LEN));
            (quant.unwrap_or(&[]), table(&p.dc_table), table(&p.ac_table))
        });
        Some(Stream {
            index: part(p.index_at, p.dc_at)?,
            dc: part(p.dc_at, p.data_at)?,
            data: part(p.data_at, p.data_at.checked_add(p.data_len)?)?,
            mcus_x: p.mcus.0,
            map: *self.maps.get(map)?,
            tables,
        })
    }
}

fn need(s: &[u8], pos: usize, len: usize, field: Field, index: usize) -> Result<(), Error> {
    take(s, pos, len, field, index).map(|_| ())
}

fn take(s: &[u8], pos: usize, len: usize, field: Field, index: usize) -> Result<&[u8], Error> {
    slice(s, pos, len).ok_or(Error::Truncated {
        field,
        index: index as u32,
        needed: pos.saturating_add(len) as u64,
        available: s.len() as u64,
    })
}

/// Every MCU's bit offset (index group `g`: absolute, then relative) lies in the entropy data and
/// does not go backwards; entries past the last MCU are 0.
fn check_index(
    index: &[u8],
    mcus: usize,
    entropy_bytes: usize,
    stream: usize,
) -> Result<(), Error> {
    let end = 8 * entropy_bytes as u64;
    let mut last = 0u64;
    for (g, group) in index.chunks_exact(GROUP_LEN).enumerate() {
        let base = u64::from(u32_at(group, 0));
        for j in 0..GROUP_MCUS {
            let rel = if j == 0 { 0 } else { u64::from(u16_at(group, 4 + 2 * (j - 1))) };
            let mcu = g * GROUP_MCUS + j;
            if mcu >= mcus {
                if rel != 0 {
                    return Err(malformed(Field::JpegIndex, stream, rel));
                }
                continue;
            }
            let at = base + rel;
            if at < last || at > end {
                return Err(malformed(Field::JpegIndex, stream, at as i64));
            }
            last = at;
        }
    }
    Ok(())
}

impl Stream<'_> {
    /// Bit offset of MCU `i` in the entropy data.
    fn mcu_bit(&self, i: usize) -> u64 {
        let (g, j) = (i / GROUP_MCUS, i % GROUP_MCUS);
        let base = u64::from(u32_at(self.index, g * GROUP_LEN));
        let rel =
            if j == 0 { 0 } else { u64::from(u16_at(self.index, g * GROUP_LEN + 4 + 2 * (j - 1))) };
        base + rel
    }

    /// Stored DC value `k` (of MCU-major order), sign-extended from 12 bits.
    fn dc(&self, k: usize) -> i32 {
        let bit = k * DC_BITS;
        let word = u32::from(u8_at(self.dc, bit / 8)) | u32::from(u8_at(self.dc, bit / 8 + 1)) << 8;
        let v = (word >> (bit % 8)) & 0xFFF;
        ((v << 20) as i32) >> 20
    }

    /// Decodes MCU `i` into `out`: texels row-major over the MCU (`mcu_size`), each with the
    /// map's channels (1, or R, G, B).
    pub(crate) fn decode_mcu(&self, i: usize, out: &mut [u8; MAX_MCU_SAMPLES]) {
        let mut bits = Bits { data: self.data, pos: self.mcu_bit(i) };
        let map = self.map;
        let colour = map.channel_count == 3;
        let (lh, lv) = (usize::from(map.luma_h), usize::from(map.luma_v));
        let values = if colour { 3 } else { 1 };
        let mut coefs = [0i32; 64];
        let mut luma = [[0u8; 64]; 4];
        let (quant, dc_table, ac_table) = &self.tables[0];
        let mut dc = self.dc(i * values);
        for (b, samples) in luma.iter_mut().enumerate().take(lh * lv) {
            let diff = block(&mut bits, dc_table, ac_table, quant, &mut coefs);
            if b > 0 {
                dc = dc.wrapping_add(diff);
            }
            coefs[0] = dc.wrapping_mul(i32::from(u8_at(quant, 0)));
            idct::idct(&coefs, samples);
        }
        if !colour {
            if let Some(o) = out.get_mut(..64) {
                o.copy_from_slice(&luma[0]);
            }
            return;
        }
        let mut chroma = [[0u8; 64]; 2];
        for (c, (samples, (quant, dc_table, ac_table))) in
            chroma.iter_mut().zip(self.tables.iter().skip(1)).enumerate()
        {
            block(&mut bits, dc_table, ac_table, quant, &mut coefs);
            coefs[0] = self.dc(i * values + 1 + c).wrapping_mul(i32::from(u8_at(quant, 0)));
            idct::idct(&coefs, samples);
        }
        let [cb, cr] = &chroma;
        let mw = 8 * lh;
        for (y, row) in out.chunks_exact_mut(3 * mw).take(8 * lv).enumerate() {
            for (x, texel) in row.chunks_exact_mut(3).enumerate() {
                let luma_block = luma.get((y / 8) * lh + x / 8).map_or(&[][..], |b| &b[..]);
                let yv = u8_at(luma_block, (y % 8) * 8 + x % 8);
                let at = (y / lv) * 8 + x / lh;
                texel.copy_from_slice(&ycc_to_rgb(yv, u8_at(cb, at), u8_at(cr, at)));
            }
        }
    }
}

/// A map's stream at one mip and where its selected channels go ([`Jpeg::selected_maps`]).
struct Selected<'a> {
    stream: Stream<'a>,
    first: usize,
    /// The selected channels (material channel bits) of this map.
    selected: u16,
    /// Slot of the map's first selected channel among all selected channels.
    before: usize,
}

impl Selected<'_> {
    /// `put(slot, channel, code)` for each selected channel of texel `at` (row-major over the
    /// MCU) of a decoded MCU.
    #[cfg_attr(not(feature = "alloc"), allow(dead_code))]
    fn put_texel(&self, pixels: &[u8], at: usize, mut put: impl FnMut(usize, usize, u8)) {
        let n = usize::from(self.stream.map.channel_count);
        let mut slot = self.before;
        for c in 0..n {
            if self.selected & (1 << (self.first + c)) != 0 {
                put(slot, self.first + c, u8_at(pixels, at * n + c));
                slot += 1;
            }
        }
    }
}

/// YCbCr to RGB in 16-bit fixed point, as the IJG decoder (FORMAT.md §11.5).
#[inline(always)]
pub(crate) fn ycc_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    let (y, cb, cr) = (i32::from(y), i32::from(cb) - 128, i32::from(cr) - 128);
    let half = 1 << 15;
    let r = y + ((91881 * cr + half) >> 16);
    let g = y + ((-22554 * cb - 46802 * cr + half) >> 16);
    let b = y + ((116130 * cb + half) >> 16);
    [r, g, b].map(|v| v.clamp(0, 255) as u8)
}

/// The channels of `map` selected by `rows`, as a mask.
fn map_rows(map: &JpegMap) -> u16 {
    (((1u32 << map.channel_count) - 1) << map.first_channel) as u16
}

impl Jpeg<'_> {
    /// 8-bit codes of texel (x, y) of `mip` (addressed) for the channels in `rows`, indexed by
    /// channel: one MCU decoded per map that holds a selected channel.
    pub(crate) fn texel_codes(&self, x: u32, y: u32, mip: u32, rows: u16) -> [u8; MAX_CHANNELS] {
        let mut codes = [0u8; MAX_CHANNELS];
        let mut pixels = [0u8; MAX_MCU_SAMPLES];
        for (m, map) in self.maps.iter().enumerate() {
            if rows & map_rows(map) == 0 {
                continue;
            }
            let Some(stream) = self.stream(m, mip) else { continue };
            let (mw, mh) = map.mcu_size();
            stream.decode_mcu(((y / mh) * stream.mcus_x + x / mw) as usize, &mut pixels);
            let n = usize::from(map.channel_count);
            let at = ((y % mh) * mw + x % mw) as usize * n;
            let first = usize::from(map.first_channel);
            if let (Some(dst), Some(src)) =
                (codes.get_mut(first..first + n), pixels.get(at..at + n))
            {
                dst.copy_from_slice(src);
            }
        }
        codes
    }

    /// The codes of the rectangle (x0, y0, width, height) of `mip` (inside the mip) for the
    /// channels in `rows`: `put(x, y, slot, code)` with (x, y) from the rectangle's corner and
    /// `slot` counting the selected channels from 0. Each MCU the rectangle touches is decoded
    /// once per map (a row span decodes it once per row).
    #[cfg_attr(not(feature = "alloc"), allow(dead_code))]
    pub(crate) fn region_codes(
        &self,
        mip: u32,
        (x0, y0, width, height): (u32, u32, u32, u32),
        rows: u16,
        mut put: impl FnMut(u32, u32, usize, u8),
    ) {
        if width == 0 || height == 0 {
            return;
        }
        let mut pixels = [0u8; MAX_MCU_SAMPLES];
        let (x1, y1) = (x0.saturating_add(width), y0.saturating_add(height));
        for sel in self.selected_maps(mip, rows) {
            let (mw, mh) = sel.stream.map.mcu_size();
            for my in y0 / mh..=(y1 - 1) / mh {
                for mx in x0 / mw..=(x1 - 1) / mw {
                    sel.stream.decode_mcu((my * sel.stream.mcus_x + mx) as usize, &mut pixels);
                    for y in (my * mh).max(y0)..((my + 1) * mh).min(y1) {
                        for x in (mx * mw).max(x0)..((mx + 1) * mw).min(x1) {
                            let at = ((y - my * mh) * mw + (x - mx * mw)) as usize;
                            sel.put_texel(&pixels, at, |slot, _, code| {
                                put(x - x0, y - y0, slot, code)
                            });
                        }
                    }
                }
            }
        }
    }

    /// The codes of `count` texels of one row: `texel(i)` is the addressed (x, y) of texel i of
    /// `mip`; `put(i, slot, channel, code)` receives each selected channel's code (`slot` counts
    /// the selected channels from 0). An MCU is decoded once per run of texels inside it.
    #[cfg_attr(not(feature = "alloc"), allow(dead_code))]
    pub(crate) fn span_codes(
        &self,
        mip: u32,
        count: usize,
        rows: u16,
        texel: impl Fn(usize) -> (u32, u32),
        mut put: impl FnMut(usize, usize, usize, u8),
    ) {
        let mut pixels = [0u8; MAX_MCU_SAMPLES];
        for sel in self.selected_maps(mip, rows) {
            let (mw, mh) = sel.stream.map.mcu_size();
            let mut decoded = None;
            for i in 0..count {
                let (x, y) = texel(i);
                let mcu = ((y / mh) * sel.stream.mcus_x + x / mw) as usize;
                if decoded != Some(mcu) {
                    sel.stream.decode_mcu(mcu, &mut pixels);
                    decoded = Some(mcu);
                }
                let at = ((y % mh) * mw + x % mw) as usize;
                sel.put_texel(&pixels, at, |slot, channel, code| put(i, slot, channel, code));
            }
        }
    }

    /// The streams at `mip` of the maps that hold a channel of `rows`, with where their selected
    /// channels go.
    fn selected_maps(&self, mip: u32, rows: u16) -> impl Iterator<Item = Selected<'_>> {
        self.maps.iter().enumerate().filter_map(move |(m, map)| {
            let selected = rows & map_rows(map);
            let first = usize::from(map.first_channel);
            (selected != 0).then_some(())?;
            Some(Selected {
                stream: self.stream(m, mip)?,
                first,
                selected,
                // Slot of this map's first selected channel among all selected channels.
                before: (rows & ((1u16 << first) - 1)).count_ones() as usize,
            })
        })
    }
}
