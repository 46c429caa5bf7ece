//! A JPEG material built in code, with the codes every texel must decode to computed here from
//! docs/FORMAT.md §11 alone: several maps (4:2:0, luma 1 × 2, gray), several mips, streams of
//! several index groups, three quantization tables picked differently by every stream and
//! exactly two Huffman tables, one of 256 symbols. Every block holds its DC coefficient only
//! (an end-of-block right after it), so its 64 samples are one value, `clamp(floor((dc · q0 +
//! 4) / 8) + 128)`: in §11.4 with only `x0` non-zero, pass 1 gives `4 · dc · q0` down each
//! column and pass 2 shifts `that · 2^13 + 2^17` right by 18. A colour texel is §11.5 of its
//! block's Y and its MCU's Cb and Cr. What the committed, djpeg-checked fixture (one map, one
//! mip, 6 MCUs) cannot give: sums over stream records, index groups past the first, slots of
//! selected channels across maps.

use crate::generate::Rng;
use nmat_core::{
    AddressMode, ChannelSpec, ColorSpace, HuffmanTableSpec, JpegMap, JpegMaterialSpec,
    JpegStreamSpec, Semantic,
};

/// The DC Huffman table: sizes 0 ..= 11, all of length 4, so size `s` is the code `s`.
const DC_TABLE: u8 = 0;
/// The AC Huffman table: end-of-block is the code `0` (and 255 longer codes are never used).
const AC_TABLE: u8 = 1;

/// A DC-only JPEG material and the DC value of each of its blocks.
#[derive(Clone, Debug)]
pub struct DcJpegMaterial {
    pub spec: JpegMaterialSpec,
    /// Per stream (map-major, as `spec.streams`), per MCU: the DC of each luma block in MCU
    /// order, then (colour) of Cb and Cr.
    blocks: Vec<Vec<Vec<i32>>>,
}

/// Bits written most significant first, as JPEG's entropy-coded data holds them.
#[derive(Default)]
pub struct BitWriter {
    bytes: Vec<u8>,
    bits: u64,
}

impl BitWriter {
    /// The `count` low bits of `value`, its highest first.
    pub fn put(&mut self, value: u32, count: u32) {
        for k in (0..count).rev() {
            if self.bits.is_multiple_of(8) {
                self.bytes.push(0);
            }
            let bit = ((value >> k) & 1) as u8;
            self.bytes[(self.bits / 8) as usize] |= bit << (7 - self.bits % 8);
            self.bits += 1;
        }
    }

    /// Bits written so far.
    pub fn bits(&self) -> u64 {
        self.bits
    }

    /// A DC difference (T.81 F.1.2.1: its size as the DC symbol, then its bits, a negative
    /// difference as `d − 1` in those bits), then end-of-block, with this module's tables.
    fn block(&mut self, diff: i32) {
        let size = 32 - diff.unsigned_abs().leading_zeros();
        self.put(size, 4);
        let bits = if diff < 0 { diff - 1 } else { diff };
        self.put(bits as u32 & ((1u32 << size) - 1), size);
        self.put(0, 1);
    }

    /// The data, its last byte padded with 0 bits.
    pub fn into_bytes(self) -> Vec<u8> {
        self.bytes
    }

    /// The data, its last byte padded with 1 bits as JPEG writers do.
    pub fn finish(mut self) -> Vec<u8> {
        while !self.bits.is_multiple_of(8) {
            self.put(1, 1);
        }
        self.bytes
    }
}

/// The sample of a block whose only coefficient is `dc`, dequantized by `q0` (see the module).
fn dc_sample(dc: i32, q0: u8) -> u8 {
    ((dc * i32::from(q0) + 4).div_euclid(8) + 128).clamp(0, 255) as u8
}

/// FORMAT.md §11.5.
fn ycc_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    let (y, cb, cr) = (i32::from(y), i32::from(cb) - 128, i32::from(cr) - 128);
    [
        y + ((91881 * cr + 32768) >> 16),
        y + ((-22554 * cb - 46802 * cr + 32768) >> 16),
        y + ((116130 * cb + 32768) >> 16),
    ]
    .map(|v| v.clamp(0, 255) as u8)
}

impl DcJpegMaterial {
    /// 70 × 37 texels, 4 mips, 8 channels in 4 maps: RGB 4:2:0 (16 × 16 MCUs), gray, RGB with
    /// luma 1 × 2 (8 × 16 MCUs; a normal map: x, y in −1 … 1, z in 0 … 1), gray (a height, range 0 … 0.25).
    /// Mip 0's gray maps have 45 MCUs (5 index groups). DC values are random (seeded), `|dc ·
    /// q0| ≤ 950`, so no sample clamps in the IDCT.
    pub fn new(seed: u64) -> DcJpegMaterial {
        let mut rng = Rng::new(seed);
        let (width, height, mip_count) = (70u32, 37u32, 4u8);
        let maps = vec![
            JpegMap { first_channel: 0, channel_count: 3, luma_h: 2, luma_v: 2 },
            JpegMap { first_channel: 3, channel_count: 1, luma_h: 1, luma_v: 1 },
            JpegMap { first_channel: 4, channel_count: 3, luma_h: 1, luma_v: 2 },
            JpegMap { first_channel: 7, channel_count: 1, luma_h: 1, luma_v: 1 },
        ];
        // Tables 0, 1, 2 with first values 2, 3, 5; the AC values are never used.
        let quant_tables: Vec<[u8; 64]> = [2u8, 3, 5]
            .iter()
            .map(|&q0| core::array::from_fn(|k| if k == 0 { q0 } else { (1 + k * 7 % 200) as u8 }))
            .collect();
        let mut dc_counts = [0u8; 16];
        dc_counts[3] = 12;
        // End-of-block as the code `0`, then 255 codes of 9 bits that the data never uses: a
        // table of 256 symbols, the most a table may hold.
        let mut ac_counts = [0u8; 16];
        (ac_counts[0], ac_counts[8]) = (1, 255);
        let ac_values = [0x00].into_iter().chain([0x01; 255]).collect();
        let huffman_tables = vec![
            HuffmanTableSpec { class: 0, counts: dc_counts, values: (0..12).collect() },
            HuffmanTableSpec { class: 1, counts: ac_counts, values: ac_values },
        ];
        let mut streams = Vec::new();
        let mut blocks = Vec::new();
        for (m, map) in maps.iter().enumerate() {
            let colour = map.channel_count == 3;
            for mip in 0..u32::from(mip_count) {
                let (w, h) = ((width >> mip).max(1), (height >> mip).max(1));
                let (mw, mh) = map.mcu_size();
                let mcus = (w.div_ceil(mw) * h.div_ceil(mh)) as usize;
                let pick = |c: usize| ((m + mip as usize + c) % 3) as u8;
                let quant = if colour { [pick(0), pick(1), pick(2)] } else { [pick(0), 0, 0] };
                let tables = |t: u8| if colour { [t; 3] } else { [t, 0, 0] };
                let q0 = |c: usize| quant_tables[usize::from(quant[c])][0];
                let luma_blocks = map.blocks_per_mcu() - if colour { 2 } else { 0 };
                let mut bw = BitWriter::default();
                let (mut mcu_bits, mut dcs, mut stream_blocks) = (vec![], vec![], vec![]);
                let mut previous = [0i32; 3];
                for _ in 0..mcus {
                    mcu_bits.push(bw.bits());
                    let components =
                        (0..luma_blocks).map(|_| 0).chain(if colour { vec![1, 2] } else { vec![] });
                    let mut mcu = vec![];
                    for c in components {
                        let limit = 950 / i64::from(q0(c));
                        let dc = rng.range(-limit, limit) as i32;
                        bw.block(dc - previous[c]);
                        previous[c] = dc;
                        mcu.push(dc);
                    }
                    dcs.push(mcu[0] as i16);
                    if colour {
                        dcs.extend([mcu[luma_blocks] as i16, mcu[luma_blocks + 1] as i16]);
                    }
                    stream_blocks.push(mcu);
                }
                streams.push(JpegStreamSpec {
                    quant,
                    dc: tables(DC_TABLE),
                    ac: tables(AC_TABLE),
                    mcu_bits,
                    dcs,
                    data: bw.finish(),
                });
                blocks.push(stream_blocks);
            }
        }
        let names = ["R", "G", "B", "gloss", "nx", "ny", "nz", "height"];
        let channels = names
            .iter()
            .enumerate()
            .map(|(c, name)| {
                let (semantic, component) = match c {
                    0..=2 => (Semantic::ALBEDO, c as u8),
                    3 => (Semantic::GLOSS, 0),
                    4..=6 => (Semantic::NORMAL, c as u8 - 4),
                    _ => (Semantic::HEIGHT, 0),
                };
                let (range_min, range_max) = match c {
                    4 | 5 => (-1.0, 1.0),
                    7 => (0.0, 0.25),
                    _ => (0.0, 1.0),
                };
                ChannelSpec {
                    name: name.to_string(),
                    semantic,
                    component,
                    color_space: if c < 3 { ColorSpace::Srgb } else { ColorSpace::Linear },
                    range_min,
                    range_max,
                }
            })
            .collect();
        let spec = JpegMaterialSpec {
            width,
            height,
            mip_count,
            address_mode: AddressMode::Wrap,
            channels,
            maps,
            quant_tables,
            huffman_tables,
            streams,
            optional_sections: vec![],
        };
        DcJpegMaterial { spec, blocks }
    }

    /// The 8-bit code of `channel` at texel (x, y) of `mip` (inside the mip).
    pub fn code(&self, channel: usize, x: u32, y: u32, mip: u32) -> u8 {
        let spec = &self.spec;
        let (m, map) = spec
            .maps
            .iter()
            .enumerate()
            .find(|(_, map)| channel < usize::from(map.first_channel + map.channel_count))
            .expect("a channel of the material");
        let stream = m * usize::from(spec.mip_count) + mip as usize;
        let w = (spec.width >> mip).max(1);
        let (mw, mh) = map.mcu_size();
        let mcu = &self.blocks[stream][((y / mh) * w.div_ceil(mw) + x / mw) as usize];
        let block = ((y % mh) / 8 * u32::from(map.luma_h) + (x % mw) / 8) as usize;
        let quant = spec.streams[stream].quant;
        let q0 = |c: usize| spec.quant_tables[usize::from(quant[c])][0];
        let luma = dc_sample(mcu[block], q0(0));
        if map.channel_count == 1 {
            return luma;
        }
        let n = mcu.len();
        let rgb = ycc_to_rgb(luma, dc_sample(mcu[n - 2], q0(1)), dc_sample(mcu[n - 1], q0(2)));
        rgb[channel - usize::from(map.first_channel)]
    }

    /// Every channel's code of every texel of `mip`, row-major, channels fastest.
    pub fn mip_codes(&self, mip: u32) -> Vec<u8> {
        let (w, h) = ((self.spec.width >> mip).max(1), (self.spec.height >> mip).max(1));
        let n = self.spec.channels.len();
        (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| (0..n).map(move |c| (c, x, y))))
            .map(|(c, x, y)| self.code(c, x, y, mip))
            .collect()
    }
}
