//! A second, independent implementation of packed JPEG materials (docs/FORMAT.md §12.5,
//! PACKED_JPEG, kind 7), written from the specification text only — §1 (file layout, header,
//! section table, checksum), §3 (MATERIAL: mip sizes), §11.1–§11.3 (JPEG section, stream, Huffman
//! decoding of an MCU) and §12 (packed files) — without reading `nmat-core`'s `format/` or `jpeg/`
//! code. It exists so that the tests can check the two against each other byte for byte: where
//! they disagree, either the text or one of the implementations is wrong.
//!
//! Plain and slow on purpose: whole-section copies, one bit at a time, a linear Huffman search,
//! errors as strings. The only thing borrowed from `nmat-core` is the CRC-32 of §1.4.
//!
//! - [`unpack`]: a packed JPEG file → the fixed-rate file of §12.1 ("the unpacked file"), each
//!   stream's index and DC values rebuilt by walking it (§12.5 "Unpacking").
//! - [`pack`]: a fixed-rate JPEG file → a packed file (§12.5 "Packing"), each stream's
//!   `restart_interval` found as the text describes.
//!
//! Where the text leaves a choice open, the choice made here is marked `SPEC:` in a comment.

use crate::reference_container::*;

/// §12.5: "streams without index".
const CODER_WITHOUT_INDEX: u8 = 2;

/// §11.1: the JPEG section's header is 8 bytes, a map record 4, a quantization table 64, a
/// Huffman table 20 + its values (padded to 4), a stream record 20.
const JPEG_HEADER_LEN: usize = 8;
const MAP_RECORD_LEN: usize = 4;
const QUANT_TABLE_LEN: usize = 64;
const HUFFMAN_HEADER_LEN: usize = 20;
const STREAM_RECORD_LEN: usize = 20;
/// §11.2: an index group covers 9 MCUs in 20 bytes (u32 + 8 × u16).
const GROUP_MCUS: usize = 9;
const GROUP_LEN: usize = 20;
/// §11.2: DC values are 12-bit.
const DC_BITS: usize = 12;

/// §1.2: a JPEG material (fixed-rate or packed) has none of the neural kinds, and §12: at most
/// one packed section.
fn refuse_neural_and_second_packed(sections: &[Section<'_>]) -> Result<(), String> {
    for kind in [KIND_LEVELS, KIND_MLP, KIND_LATENTS, KIND_PACKED_LATENTS] {
        if count_kind(sections, kind) != 0 {
            return Err(format!("a section of kind {kind} in a JPEG material"));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// MATERIAL (§3): what the streams' sizes depend on
// ---------------------------------------------------------------------------------------------

struct MaterialInfo {
    width: u32,
    height: u32,
    mip_count: usize,
    channel_count: usize,
}

impl MaterialInfo {
    /// §3: mip `m` is `max(1, width >> m) × max(1, height >> m)`.
    fn mip_size(&self, mip: usize) -> (u32, u32) {
        ((self.width >> mip).max(1), (self.height >> mip).max(1))
    }
}

fn read_material(material: &[u8]) -> Result<MaterialInfo, String> {
    let width = u32_at(material, 0)?;
    let height = u32_at(material, 4)?;
    let mip_count = usize::from(u8_at(material, 8)?);
    let channel_count = usize::from(u8_at(material, 9)?);
    if !(1..=16384).contains(&width) || !(1..=16384).contains(&height) {
        return Err(format!("material of {width}×{height}"));
    }
    let max_mips = (32 - width.max(height).leading_zeros()) as usize; // floor(log2) + 1
    if !(1..=max_mips).contains(&mip_count) {
        return Err(format!("mip_count {mip_count} (at most {max_mips})"));
    }
    if !(1..=16).contains(&channel_count) {
        return Err(format!("channel_count {channel_count}"));
    }
    if material.len() != 12 + 32 * channel_count {
        return Err(format!("MATERIAL of {} bytes for {channel_count} channels", material.len()));
    }
    Ok(MaterialInfo { width, height, mip_count, channel_count })
}

// ---------------------------------------------------------------------------------------------
// The JPEG section's tables and records (§11.1)
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug)]
struct MapRecord {
    channel_count: usize,
    luma_h: usize,
    luma_v: usize,
}

impl MapRecord {
    /// Luma blocks per MCU (raster order), then Cb and Cr for colour.
    fn luma_blocks(&self) -> usize {
        self.luma_h * self.luma_v
    }

    fn is_colour(&self) -> bool {
        self.channel_count == 3
    }

    /// §11.1: an MCU is `8·luma_h × 8·luma_v` texels; `N = ceil(w / mcu_w) · ceil(h / mcu_h)`.
    fn mcu_count(&self, (w, h): (u32, u32)) -> usize {
        let (mcu_w, mcu_h) = (8 * self.luma_h, 8 * self.luma_v);
        (w as usize).div_ceil(mcu_w) * (h as usize).div_ceil(mcu_h)
    }

    /// DC values per MCU (§11.2): one for gray, three (first luma, Cb, Cr) for colour.
    fn dc_per_mcu(&self) -> usize {
        if self.is_colour() { 3 } else { 1 }
    }
}

/// A canonical Huffman table (T.81 annex C) as §11.3's decoding procedure uses it.
#[derive(Clone, Debug)]
struct HuffmanTable {
    class: u8,
    values: Vec<u8>,
    /// For each length `l` (index `l − 1`): the number of codes, the first code, and the index
    /// in `values` of the first symbol of that length.
    counts: [usize; 16],
    first_code: [u32; 16],
    first_index: [usize; 16],
}

impl HuffmanTable {
    /// Reads the table at `at`; returns it and its padded length.
    fn read(section: &[u8], at: usize, index: usize) -> Result<(HuffmanTable, usize), String> {
        let class = u8_at(section, at)?;
        if class > 1 {
            return Err(format!("Huffman table {index}: class {class}"));
        }
        if u8_at(section, at + 1)? != 0 {
            return Err(format!("Huffman table {index}: reserved byte"));
        }
        let value_count = usize::from(u16_at(section, at + 2)?);
        let mut counts = [0usize; 16];
        for (l, count) in counts.iter_mut().enumerate() {
            *count = usize::from(u8_at(section, at + 4 + l)?);
        }
        if !(1..=256).contains(&value_count) || counts.iter().sum::<usize>() != value_count {
            return Err(format!("Huffman table {index}: value_count {value_count}"));
        }
        let start = at + HUFFMAN_HEADER_LEN;
        let values = section
            .get(start..start + value_count)
            .ok_or_else(|| format!("Huffman table {index} is past the end"))?
            .to_vec();
        for &v in &values {
            let ok = if class == 0 {
                v <= 11
            } else {
                (v & 15) <= 10 && ((v & 15) != 0 || v == 0x00 || v == 0xF0)
            };
            if !ok {
                return Err(format!("Huffman table {index}: symbol {v:#04x} (class {class})"));
            }
        }
        // Canonical codes: consecutive within a length, shifted left by one between lengths.
        let mut first_code = [0u32; 16];
        let mut first_index = [0usize; 16];
        let (mut code, mut k) = (0u32, 0usize);
        for l in 0..16 {
            first_code[l] = code;
            first_index[l] = k;
            code += counts[l] as u32;
            k += counts[l];
            // §11.1: after the codes of length `l + 1`, the next code must stay below 2^(l+1).
            if code >= 1 << (l + 1) {
                return Err(format!("Huffman table {index}: codes of length {} overflow", l + 1));
            }
            code <<= 1;
        }
        // SPEC: §11.1 says each table is "padded to a multiple of 4 bytes" but not what the
        // padding holds; it is copied as it is (both directions keep these bytes verbatim).
        let padded = align4(HUFFMAN_HEADER_LEN + value_count);
        if section.len() < at + padded {
            return Err(format!("the padding of Huffman table {index} is past the end"));
        }
        Ok((HuffmanTable { class, values, counts, first_code, first_index }, padded))
    }

    /// §11.3: for `l = 1 … 16`, the next `l` bits as `c`; the first `l` with `c` at most the
    /// largest code of length `l` gives the symbol. No match: symbol 0, 16 bits consumed.
    fn decode(&self, bits: &mut BitReader<'_>) -> u8 {
        let mut c = 0u32;
        for l in 0..16 {
            c = (c << 1) | bits.peek(l);
            if self.counts[l] > 0 {
                let largest = self.first_code[l] + self.counts[l] as u32 - 1;
                if c <= largest {
                    bits.skip(l + 1);
                    let i = c as usize - self.first_code[l] as usize + self.first_index[l];
                    return self.values[i];
                }
            }
        }
        bits.skip(16);
        0
    }
}

/// A stream record (§11.1): where the stream is, and its Huffman tables per component (Y, Cb, Cr).
#[derive(Clone, Copy, Debug)]
struct StreamRecord {
    offset: usize,
    entropy_length: usize,
    dc_table: [usize; 3],
    ac_table: [usize; 3],
    /// Bytes 18–19: the packed body's `restart_interval`; in a fixed-rate section, reserved.
    bytes_17_19: [u8; 3],
}

/// A JPEG section (or a packed body) read as far as packing and unpacking need it.
struct JpegLayout {
    maps: Vec<MapRecord>,
    huffman: Vec<HuffmanTable>,
    /// Where the stream records start (= where header, maps and tables end).
    records_at: usize,
    /// `map_count × mip_count`, map-major.
    streams: Vec<StreamRecord>,
}

impl JpegLayout {
    fn map_of_stream(&self, s: usize, mip_count: usize) -> (MapRecord, usize) {
        (self.maps[s / mip_count], s % mip_count)
    }
}

/// §11.1, for a section or a packed body: header, map records, quantization tables, Huffman
/// tables and stream records, checked as §11.1 says. The streams are not checked here.
fn read_jpeg_layout(section: &[u8], material: &MaterialInfo) -> Result<JpegLayout, String> {
    let version = u16_at(section, 0)?;
    if version != 1 {
        return Err(format!("JPEG version {version}: Unsupported JpegVersion"));
    }
    let map_count = usize::from(u8_at(section, 2)?);
    let quant_count = usize::from(u8_at(section, 3)?);
    let huffman_count = usize::from(u8_at(section, 4)?);
    if !(1..=material.channel_count).contains(&map_count) {
        return Err(format!("map_count {map_count}: Malformed JpegMapCount"));
    }
    if !(1..=16).contains(&quant_count) {
        return Err(format!("quant_table_count {quant_count}: Malformed JpegQuantCount"));
    }
    if !(2..=32).contains(&huffman_count) {
        return Err(format!("huffman_table_count {huffman_count}: Malformed JpegHuffmanCount"));
    }
    if section.get(5..8).ok_or("JPEG header past the end")?.iter().any(|&b| b != 0) {
        return Err("Malformed JpegReserved".into());
    }

    let mut at = JPEG_HEADER_LEN;
    let mut maps = Vec::new();
    let mut next_channel = 0usize;
    for m in 0..map_count {
        let first_channel = usize::from(u8_at(section, at)?);
        let channel_count = usize::from(u8_at(section, at + 1)?);
        let luma_h = usize::from(u8_at(section, at + 2)?);
        let luma_v = usize::from(u8_at(section, at + 3)?);
        if first_channel != next_channel {
            return Err(format!("map {m}: first_channel {first_channel}: Malformed JpegMap"));
        }
        let ok = match channel_count {
            1 => luma_h == 1 && luma_v == 1,
            3 => (1..=2).contains(&luma_h) && (1..=2).contains(&luma_v),
            _ => false,
        };
        if !ok {
            return Err(format!("map {m}: {channel_count} channels, {luma_h}×{luma_v}"));
        }
        next_channel += channel_count;
        if next_channel > material.channel_count {
            return Err(format!("map {m} is past the material's channels"));
        }
        maps.push(MapRecord { channel_count, luma_h, luma_v });
        at += MAP_RECORD_LEN;
    }
    if next_channel != material.channel_count {
        return Err("the maps do not cover every channel: Malformed JpegMapChannels".into());
    }

    for t in 0..quant_count {
        let table = section.get(at..at + QUANT_TABLE_LEN).ok_or("quant table past the end")?;
        if table.contains(&0) {
            return Err(format!("quantization table {t} has a 0: Malformed JpegQuantTable"));
        }
        at += QUANT_TABLE_LEN;
    }

    let mut huffman = Vec::new();
    for t in 0..huffman_count {
        let (table, len) = HuffmanTable::read(section, at, t)?;
        huffman.push(table);
        at += len;
    }

    let records_at = at;
    let stream_count = map_count * material.mip_count;
    let mut streams = Vec::new();
    for s in 0..stream_count {
        let r = records_at + STREAM_RECORD_LEN * s;
        let record = section.get(r..r + STREAM_RECORD_LEN).ok_or("stream record past the end")?;
        let map = maps[s / material.mip_count];
        let components = map.channel_count;
        let (quant, dc, ac) = (&record[8..11], &record[11..14], &record[14..17]);
        for c in 0..3 {
            if c < components {
                if usize::from(quant[c]) >= quant_count {
                    return Err(format!("stream {s}: quant table {}: JpegTableRef", quant[c]));
                }
                let dc_ok = huffman.get(usize::from(dc[c])).is_some_and(|t| t.class == 0);
                let ac_ok = huffman.get(usize::from(ac[c])).is_some_and(|t| t.class == 1);
                if !dc_ok || !ac_ok {
                    return Err(format!("stream {s} component {c}: Malformed JpegTableRef"));
                }
            } else if quant[c] != 0 || dc[c] != 0 || ac[c] != 0 {
                return Err(format!("stream {s}: unused table entry {c} is not 0"));
            }
        }
        streams.push(StreamRecord {
            offset: u32_at(record, 0)? as usize,
            entropy_length: u32_at(record, 4)? as usize,
            dc_table: [0, 1, 2].map(|c| usize::from(dc[c])),
            ac_table: [0, 1, 2].map(|c| usize::from(ac[c])),
            bytes_17_19: [record[17], record[18], record[19]],
        });
    }
    Ok(JpegLayout { maps, huffman, records_at, streams })
}

/// §11.1: each stream at a multiple of 4, at or after the end of the records and of the previous
/// stream, and the section ending with the last stream padded to a multiple of 4. `stream_len`
/// gives a stream's full length from its record (in a packed body: `entropy_length` alone).
fn check_stream_placement(
    section: &[u8],
    layout: &JpegLayout,
    stream_len: impl Fn(usize, &StreamRecord) -> usize,
) -> Result<(), String> {
    let mut end = layout.records_at + STREAM_RECORD_LEN * layout.streams.len();
    for (s, record) in layout.streams.iter().enumerate() {
        if !record.offset.is_multiple_of(4) || record.offset < end {
            return Err(format!(
                "stream {s}: offset {}: Malformed JpegStreamOffset",
                record.offset
            ));
        }
        end = record.offset + stream_len(s, record);
        if end > section.len() {
            return Err(format!(
                "stream {s} ends at {end}, past {}: JpegStreamLength",
                section.len()
            ));
        }
    }
    if section.len() != align4(end) {
        return Err(format!(
            "the section is {} bytes, its streams end at {end}: Malformed SectionContent",
            section.len()
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Walking a stream (§11.3 steps 1–2, §12.5 "Unpacking")
// ---------------------------------------------------------------------------------------------

/// Most significant bit first; bits past the end read as 0 (§11.2).
struct BitReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl BitReader<'_> {
    fn bit_at(&self, k: usize) -> u32 {
        match self.data.get(k / 8) {
            Some(&byte) => u32::from(byte >> (7 - k % 8)) & 1,
            None => 0,
        }
    }

    /// The bit `ahead` bits after the current position, without consuming it.
    fn peek(&self, ahead: usize) -> u32 {
        self.bit_at(self.pos + ahead)
    }

    fn skip(&mut self, n: usize) {
        self.pos += n;
    }

    fn read(&mut self, n: usize) -> u32 {
        let mut v = 0;
        for _ in 0..n {
            v = (v << 1) | self.bit_at(self.pos);
            self.pos += 1;
        }
        v
    }
}

/// §11.3: `extend(v, s)`.
fn extend(v: u32, s: usize) -> i32 {
    if s == 0 {
        0
    } else if v < 1 << (s - 1) {
        v as i32 - (1 << s) + 1
    } else {
        v as i32
    }
}

/// One stream's tables, per component.
struct StreamTables<'a> {
    dc: [&'a HuffmanTable; 3],
    ac: [&'a HuffmanTable; 3],
}

/// §11.3 step 2 for one block: returns the DC difference; the AC coefficients are decoded only to
/// be skipped.
fn walk_block(bits: &mut BitReader<'_>, dc: &HuffmanTable, ac: &HuffmanTable) -> i32 {
    let s = usize::from(dc.decode(bits));
    let v = bits.read(s);
    let difference = extend(v, s);
    let mut k = 1;
    while k < 64 {
        let rs = ac.decode(bits);
        let (r, s) = (usize::from(rs >> 4), usize::from(rs & 15));
        if s == 0 {
            if r == 15 {
                k += 16;
            } else {
                break; // end of block
            }
        } else {
            // SPEC: "k += r, read s bits v, coefficient k … k += 1 (a k past 63 ends the block)":
            // read here as: the s bits are read even when `k += r` went past 63, and the loop
            // condition ends the block (as libjpeg does). Not reading them moves every later MCU
            // of a corrupt stream.
            k += r;
            bits.read(s);
            k += 1;
        }
    }
    difference
}

/// What walking a stream gives: the bit offset of every MCU and its DC values (MCU-major, as
/// §11.2 stores them), before they are laid out.
#[derive(Debug, PartialEq, Eq)]
struct Walk {
    starts: Vec<usize>,
    dc: Vec<i32>,
}

/// §12.5: MCUs `0 … N − 1` in raster order with a bit position and a DC prediction per component;
/// at a restart (`restart_interval > 0`, `i > 0`, `i mod restart_interval = 0`) the position moves
/// up to the next multiple of 8 and every prediction becomes 0. Returns the walk and, if MCU `i`
/// would start past the data (`Malformed JpegIndex`), `Some(i)`: the walk then holds MCUs
/// `0 … i − 1`.
fn walk_stream(
    data: &[u8],
    map: MapRecord,
    tables: &StreamTables<'_>,
    mcu_count: usize,
    restart_interval: usize,
) -> (Walk, Option<usize>) {
    let mut bits = BitReader { data, pos: 0 };
    let mut prediction = [0i32; 3];
    let mut walk = Walk { starts: Vec::with_capacity(mcu_count), dc: Vec::new() };
    for i in 0..mcu_count {
        if restart_interval > 0 && i > 0 && i.is_multiple_of(restart_interval) {
            bits.pos = bits.pos.div_ceil(8) * 8;
            prediction = [0; 3];
        }
        if bits.pos > 8 * data.len() {
            return (walk, Some(i));
        }
        walk.starts.push(bits.pos);
        for b in 0..map.luma_blocks() {
            let d = walk_block(&mut bits, tables.dc[0], tables.ac[0]);
            prediction[0] = prediction[0].wrapping_add(d);
            if b == 0 {
                walk.dc.push(prediction[0]);
            }
        }
        if map.is_colour() {
            for (c, prediction) in prediction.iter_mut().enumerate().skip(1) {
                let d = walk_block(&mut bits, tables.dc[c], tables.ac[c]);
                *prediction = prediction.wrapping_add(d);
                walk.dc.push(*prediction);
            }
        }
    }
    (walk, None)
}

/// §11.2: the index's length for `N` MCUs.
fn index_len(mcu_count: usize) -> usize {
    GROUP_LEN * mcu_count.div_ceil(GROUP_MCUS)
}

/// §11.2: the DC values' length, padded to 4, for `count` 12-bit values.
fn dc_len(count: usize) -> usize {
    align4((DC_BITS * count).div_ceil(8))
}

/// §11.2: the index and the DC values of a walk, as the bytes that precede a stream's data.
fn lay_out_index_and_dc(walk: &Walk) -> Result<Vec<u8>, String> {
    let n = walk.starts.len();
    let mut out = vec![0u8; index_len(n) + dc_len(walk.dc.len())];
    for g in 0..n.div_ceil(GROUP_MCUS) {
        let group = &mut out[GROUP_LEN * g..GROUP_LEN * (g + 1)];
        let base = walk.starts[GROUP_MCUS * g];
        let base_u32 = u32::try_from(base).map_err(|_| "a bit offset does not fit a u32")?;
        group[0..4].copy_from_slice(&base_u32.to_le_bytes());
        for j in 1..GROUP_MCUS {
            let Some(&start) = walk.starts.get(GROUP_MCUS * g + j) else { break };
            let relative = u16::try_from(start - base).map_err(|_| {
                format!(
                    "MCU {} is {} bits after its group's first: LimitExceeded JpegIndex",
                    GROUP_MCUS * g + j,
                    start - base
                )
            })?;
            group[4 + 2 * (j - 1)..6 + 2 * (j - 1)].copy_from_slice(&relative.to_le_bytes());
        }
    }
    let dc = &mut out[index_len(n)..];
    for (k, &value) in walk.dc.iter().enumerate() {
        let twelve = (value as u32) & 0xFFF; // the low 12 bits of the two's complement
        for b in 0..DC_BITS {
            if (twelve >> b) & 1 == 1 {
                let j = DC_BITS * k + b;
                dc[j / 8] |= 1 << (j % 8);
            }
        }
    }
    Ok(out)
}

/// The tables stream record `record` refers to.
fn stream_tables<'a>(layout: &'a JpegLayout, record: &StreamRecord) -> StreamTables<'a> {
    StreamTables {
        dc: record.dc_table.map(|t| &layout.huffman[t]),
        ac: record.ac_table.map(|t| &layout.huffman[t]),
    }
}

// ---------------------------------------------------------------------------------------------
// unpack
// ---------------------------------------------------------------------------------------------

/// A packed JPEG file (MATERIAL and PACKED_JPEG, kind 7, and optional sections) → the fixed-rate
/// file it stands for (§12.1 "The unpacked file", §12.5 "Unpacking").
pub fn unpack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let (header, sections) = read_container(bytes)?;
    let packed_section = only_section(&sections, KIND_PACKED_JPEG)?;
    refuse_neural_and_second_packed(&sections)?;
    // SPEC: §1.2 refuses LATENTS beside PACKED_LATENTS but says nothing of JPEG beside
    // PACKED_JPEG; §12's "at most one packed section" does not cover it either. Refused here.
    if count_kind(&sections, KIND_JPEG) != 0 {
        return Err("a JPEG section beside PACKED_JPEG: Malformed SectionKind".into());
    }
    let material = read_material(only_section(&sections, KIND_MATERIAL)?.data)?;
    // SPEC: §12.5 does not say that PACKED_JPEG must carry REQUIRED; §12 says packed sections are
    // "written REQUIRED" and §12.1 refuses PACKED_LATENTS without it (Malformed SectionFlags). The
    // same rule is applied here.
    if packed_section.flags & REQUIRED == 0 {
        return Err("PACKED_JPEG without REQUIRED: Malformed SectionFlags".into());
    }
    let packed = packed_section.data;
    if packed.len() < PACKED_HEADER_LEN {
        return Err(format!("PACKED_JPEG of {} bytes", packed.len()));
    }
    let jpeg_length = u32_at(packed, 0)? as usize;
    let coder = packed[4];
    let reserved = packed[5];
    let unpacked_minor = u16_at(packed, 6)?;
    let body = &packed[PACKED_HEADER_LEN..];
    if !jpeg_length.is_multiple_of(4) || jpeg_length > 256 * (body.len() + 64) {
        return Err(format!("jpeg_length {jpeg_length}: Malformed PackedLength"));
    }
    if coder != CODER_WITHOUT_INDEX {
        return Err(format!("coder {coder}: Unsupported PackedCoder"));
    }
    if reserved != 0 {
        return Err("Malformed PackedReserved".into());
    }

    let layout = read_jpeg_layout(body, &material)?;
    check_stream_placement(body, &layout, |_, r| r.entropy_length)?;
    for (s, record) in layout.streams.iter().enumerate() {
        if record.bytes_17_19[0] != 0 {
            return Err(format!("stream {s}: reserved byte 17 is not 0"));
        }
    }

    // The length the body's streams give, checked before any stream is walked.
    let mcu_counts: Vec<usize> = (0..layout.streams.len())
        .map(|s| {
            let (map, mip) = layout.map_of_stream(s, material.mip_count);
            map.mcu_count(material.mip_size(mip))
        })
        .collect();
    let records_end = layout.records_at + STREAM_RECORD_LEN * layout.streams.len();
    let mut section_len = records_end;
    let mut offsets = Vec::new();
    for (s, record) in layout.streams.iter().enumerate() {
        let (map, _) = layout.map_of_stream(s, material.mip_count);
        let n = mcu_counts[s];
        section_len = align4(section_len);
        offsets.push(section_len);
        section_len += index_len(n) + dc_len(n * map.dc_per_mcu()) + record.entropy_length;
    }
    let section_len = align4(section_len);
    if section_len != jpeg_length {
        return Err(format!(
            "jpeg_length {jpeg_length}, the streams give {section_len}: Malformed PackedLength"
        ));
    }

    let mut jpeg = Vec::with_capacity(section_len);
    jpeg.extend_from_slice(&body[..layout.records_at]);
    // The records: `offset` recomputed, the same `entropy_length` and tables, bytes 17–19 zero.
    for (s, &offset) in offsets.iter().enumerate() {
        let r = layout.records_at + STREAM_RECORD_LEN * s;
        let mut bytes = body[r..r + STREAM_RECORD_LEN].to_vec();
        let offset = u32::try_from(offset).map_err(|_| "offset does not fit a u32")?;
        bytes[0..4].copy_from_slice(&offset.to_le_bytes());
        bytes[17..20].fill(0);
        jpeg.extend_from_slice(&bytes);
    }
    for (s, record) in layout.streams.iter().enumerate() {
        let (map, _) = layout.map_of_stream(s, material.mip_count);
        let data = &body[record.offset..record.offset + record.entropy_length];
        let restart_interval =
            usize::from(u16::from_le_bytes([record.bytes_17_19[1], record.bytes_17_19[2]]));
        let tables = stream_tables(&layout, record);
        let (walk, stopped) = walk_stream(data, map, &tables, mcu_counts[s], restart_interval);
        if let Some(i) = stopped {
            return Err(format!("stream {s}: MCU {i} starts past the data: Malformed JpegIndex"));
        }
        jpeg.resize(align4(jpeg.len()), 0);
        debug_assert_eq!(jpeg.len(), offsets[s]);
        jpeg.extend_from_slice(
            &lay_out_index_and_dc(&walk).map_err(|e| format!("stream {s}: {e}"))?,
        );
        jpeg.extend_from_slice(data);
    }
    jpeg.resize(align4(jpeg.len()), 0);
    debug_assert_eq!(jpeg.len(), jpeg_length);

    // SPEC: §12.1 gives the unpacked file's sections "the same flags", except that it names the
    // replacing LATENTS `REQUIRED`; the JPEG section that replaces PACKED_JPEG is written REQUIRED
    // likewise (§11: the JPEG section is written `REQUIRED`).
    let out_sections: Vec<(u32, u32, &[u8])> = sections
        .iter()
        .map(|s| {
            if s.kind == KIND_PACKED_JPEG {
                (KIND_JPEG, REQUIRED, jpeg.as_slice())
            } else {
                (s.kind, s.flags, s.data)
            }
        })
        .collect();
    write_container(&header, unpacked_minor, &out_sections)
}

// ---------------------------------------------------------------------------------------------
// pack
// ---------------------------------------------------------------------------------------------

/// The index entries (absolute bit offsets) and DC values a fixed-rate stream stores.
fn stored_walk(prefix: &[u8], mcu_count: usize, dc_count: usize) -> Walk {
    let mut starts = Vec::with_capacity(mcu_count);
    for i in 0..mcu_count {
        let group = &prefix[GROUP_LEN * (i / GROUP_MCUS)..];
        let base = u32::from_le_bytes([group[0], group[1], group[2], group[3]]) as usize;
        let j = i % GROUP_MCUS;
        let relative = if j == 0 {
            0
        } else {
            usize::from(u16::from_le_bytes([group[2 + 2 * j], group[3 + 2 * j]]))
        };
        starts.push(base + relative);
    }
    let dc_bytes = &prefix[index_len(mcu_count)..];
    let dc = (0..dc_count)
        .map(|k| {
            let mut v = 0u32;
            for b in 0..DC_BITS {
                let j = DC_BITS * k + b;
                v |= u32::from(dc_bytes[j / 8] >> (j % 8) & 1) << b;
            }
            v as i32 // compared by their low 12 bits
        })
        .collect();
    Walk { starts, dc }
}

/// A fixed-rate JPEG file → a packed file (§12.5 "Packing", §12.1 "The packed file"): the same
/// sections in the same order with the same flags, JPEG replaced by PACKED_JPEG (`REQUIRED`),
/// header `version_minor` 2. Refuses what would not unpack to the input's bytes.
pub fn pack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let (header, sections) = read_container(bytes)?;
    refuse_neural_and_second_packed(&sections)?;
    if count_kind(&sections, KIND_PACKED_JPEG) != 0 {
        return Err("the file is packed already".into());
    }
    let material = read_material(only_section(&sections, KIND_MATERIAL)?.data)?;
    let jpeg = only_section(&sections, KIND_JPEG)?.data;
    let layout = read_jpeg_layout(jpeg, &material)?;
    let mcu_counts: Vec<usize> = (0..layout.streams.len())
        .map(|s| {
            let (map, mip) = layout.map_of_stream(s, material.mip_count);
            map.mcu_count(material.mip_size(mip))
        })
        .collect();
    let prefix_len = |s: usize| {
        let (map, _) = layout.map_of_stream(s, material.mip_count);
        index_len(mcu_counts[s]) + dc_len(mcu_counts[s] * map.dc_per_mcu())
    };
    check_stream_placement(jpeg, &layout, |s, r| prefix_len(s) + r.entropy_length)?;

    // The body: the section up to the records, the records, then each stream's data alone at the
    // next multiple of 4 (offsets counted from the body's start).
    let mut body = jpeg[..layout.records_at].to_vec();
    let records_end = layout.records_at + STREAM_RECORD_LEN * layout.streams.len();
    let mut data_offsets = Vec::new();
    let mut at = records_end;
    for record in &layout.streams {
        data_offsets.push(at);
        at = align4(at + record.entropy_length);
    }
    let mut datas = Vec::new();
    for (s, record) in layout.streams.iter().enumerate() {
        let (map, _) = layout.map_of_stream(s, material.mip_count);
        let n = mcu_counts[s];
        let prefix = &jpeg[record.offset..record.offset + prefix_len(s)];
        let data_at = record.offset + prefix_len(s);
        let data = &jpeg[data_at..data_at + record.entropy_length];
        let restart_interval = find_restart_interval(&layout, record, map, data, prefix, n)
            .map_err(|e| format!("stream {s}: {e}"))?;
        let r = layout.records_at + STREAM_RECORD_LEN * s;
        let mut bytes = jpeg[r..r + STREAM_RECORD_LEN].to_vec();
        let offset = u32::try_from(data_offsets[s]).map_err(|_| "offset does not fit a u32")?;
        bytes[0..4].copy_from_slice(&offset.to_le_bytes());
        bytes[17] = 0;
        bytes[18..20].copy_from_slice(&restart_interval.to_le_bytes());
        body.extend_from_slice(&bytes);
        datas.push(data);
    }
    for data in datas {
        body.extend_from_slice(data);
        body.resize(align4(body.len()), 0);
    }

    let jpeg_length = u32::try_from(jpeg.len()).map_err(|_| "JPEG section too long")?;
    let unpacked_minor = u16_at(&header, 6)?;
    let mut packed_section = Vec::with_capacity(PACKED_HEADER_LEN + body.len());
    packed_section.extend_from_slice(&jpeg_length.to_le_bytes());
    packed_section.push(CODER_WITHOUT_INDEX);
    packed_section.push(0);
    packed_section.extend_from_slice(&unpacked_minor.to_le_bytes());
    packed_section.extend_from_slice(&body);

    let out_sections: Vec<(u32, u32, &[u8])> = sections
        .iter()
        .map(|s| {
            if s.kind == KIND_JPEG {
                (KIND_PACKED_JPEG, REQUIRED, packed_section.as_slice())
            } else {
                (s.kind, s.flags, s.data)
            }
        })
        .collect();
    let packed = write_container(&header, PACKED_VERSION_MINOR, &out_sections)?;

    // §12.5: "nor can any file that does not unpack to its own bytes".
    if unpack(&packed)? != bytes {
        return Err("the input does not unpack to its own bytes: BadArgument Layout".into());
    }
    Ok(packed)
}

/// §12.5 "Packing": 0 if walking without restarts reproduces the stored index and DC values; else
/// the first MCU `k` the walk gets wrong follows a restart marker, and the interval is the
/// smallest divisor of `k` under which the walk reproduces them all.
fn find_restart_interval(
    layout: &JpegLayout,
    record: &StreamRecord,
    map: MapRecord,
    data: &[u8],
    prefix: &[u8],
    mcu_count: usize,
) -> Result<u16, String> {
    let tables = stream_tables(layout, record);
    let per_mcu = map.dc_per_mcu();
    let stored = stored_walk(prefix, mcu_count, mcu_count * per_mcu);
    let reproduces = |interval: usize| match walk_stream(data, map, &tables, mcu_count, interval) {
        (walk, None) => lay_out_index_and_dc(&walk).is_ok_and(|laid| laid == prefix),
        (_, Some(_)) => false,
    };
    if reproduces(0) {
        return Ok(0);
    }
    let k = first_wrong_mcu(data, map, &tables, &stored, per_mcu)
        .ok_or("the walk without restarts differs only in padding: BadArgument Layout")?;
    for d in 1..=k {
        if k.is_multiple_of(d) && reproduces(d) {
            return u16::try_from(d)
                .map_err(|_| format!("restart interval {d} does not fit a u16"));
        }
    }
    Err(format!(
        "no restart interval reproduces the index (first wrong MCU {k}): BadArgument Layout"
    ))
}

/// The first MCU whose start or DC values, walked without restarts, differ from the stored ones
/// (`None`: they all agree, only unused bits or entries can differ).
fn first_wrong_mcu(
    data: &[u8],
    map: MapRecord,
    tables: &StreamTables<'_>,
    stored: &Walk,
    per_mcu: usize,
) -> Option<usize> {
    let (walk, _) = walk_stream(data, map, tables, stored.starts.len(), 0);
    let twelve_bits = |v: i32| v & 0xFFF;
    (0..stored.starts.len()).find(|&i| {
        // A walk that stopped before MCU `i` gets it wrong.
        i >= walk.starts.len()
            || walk.starts[i] != stored.starts[i]
            || (per_mcu * i..per_mcu * (i + 1))
                .any(|k| twelve_bits(walk.dc[k]) != twelve_bits(stored.dc[k]))
    })
}
