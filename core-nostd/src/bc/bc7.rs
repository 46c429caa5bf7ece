//! BC7 (RGB or RGBA, 16 bytes per block): eight modes that trade subsets (1–3 groups of pixels
//! from a table of partitions, each with its own endpoints), endpoint precision (4–8 bits, some
//! with a "p-bit" as their lowest bit) and index precision (2–4 bits). The layout of every mode
//! and the partition and anchor tables are those of the format's definition (Khronos
//! `ARB_texture_compression_bptc`, Table.M, P2, P3, A2, A3a, A3b; Direct3D 11 calls it BC7).
//!
//! The decoder reads every mode. The encoder writes, for blocks whose alpha is 255 everywhere
//! (and for every block of an RGB texture): mode 6 (one subset, 4-bit indices), mode 1 (two
//! subsets, 3-bit indices) and mode 3 (two subsets, 2-bit indices, finer endpoints), mode 2
//! (three subsets, 2-bit indices) and mode 0 (three subsets of the first 16 partitions, 3-bit
//! indices, coarse endpoints), and modes 5 and 4, where one colour channel, rotated into the
//! alpha slot, has indices of its own (mode 5 for each channel, 2-bit indices both; mode 4, with
//! one 2-bit and one 3-bit index a pixel either way round, for the channel mode 5 did best
//! with); for blocks with alpha: mode 6 (colour and alpha together) and mode 5 (alpha with its
//! own indices). Partitions are ranked by the squared error of one colour per subset, and the
//! best few are encoded in full. Each subset's endpoints start at the pixels at both ends of its
//! principal axis, every p-bit choice is tried, and least squares refines them for the chosen
//! indices (twice). The candidate with the least squared error over the texture's
//! channels wins. Integer arithmetic only.

use super::{BLOCK_PIXELS, counts, principal_ends};

/// The fields of a mode (Table.M of the format's definition).
#[derive(Clone, Copy, Default)]
struct Mode {
    subsets: usize,
    partition_bits: u32,
    rotation_bits: u32,
    selector_bits: u32,
    color_bits: u32,
    alpha_bits: u32,
    endpoint_pbits: bool,
    shared_pbits: bool,
    index_bits: u32,
    index2_bits: u32,
}

/// A row of Table.M: subsets, partition, rotation, selector, colour and alpha bits, endpoint and
/// shared p-bits (1 = present), index and secondary index bits.
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time only (MODES): an index out of bounds fails the build"
)]
const fn mode(r: [u32; 10]) -> Mode {
    Mode {
        subsets: r[0] as usize,
        partition_bits: r[1],
        rotation_bits: r[2],
        selector_bits: r[3],
        color_bits: r[4],
        alpha_bits: r[5],
        endpoint_pbits: r[6] == 1,
        shared_pbits: r[7] == 1,
        index_bits: r[8],
        index2_bits: r[9],
    }
}

const MODES: [Mode; 8] = [
    mode([3, 4, 0, 0, 4, 0, 1, 0, 3, 0]),
    mode([2, 6, 0, 0, 6, 0, 0, 1, 3, 0]),
    mode([3, 6, 0, 0, 5, 0, 0, 0, 2, 0]),
    mode([2, 6, 0, 0, 7, 0, 1, 0, 2, 0]),
    mode([1, 0, 2, 1, 5, 6, 0, 0, 2, 3]),
    mode([1, 0, 2, 0, 7, 8, 0, 0, 2, 2]),
    mode([1, 0, 0, 0, 7, 7, 1, 0, 4, 0]),
    mode([2, 6, 0, 0, 5, 5, 1, 0, 2, 0]),
];

/// Two-subset partitions (Table.P2): bit `i` set when pixel `i` is in subset 1.
static P2: [u16; 64] = [
    0xCCCC, 0x8888, 0xEEEE, 0xECC8, 0xC880, 0xFEEC, 0xFEC8, 0xEC80, //
    0xC800, 0xFFEC, 0xFE80, 0xE800, 0xFFE8, 0xFF00, 0xFFF0, 0xF000, //
    0xF710, 0x008E, 0x7100, 0x08CE, 0x008C, 0x7310, 0x3100, 0x8CCE, //
    0x088C, 0x3110, 0x6666, 0x366C, 0x17E8, 0x0FF0, 0x718E, 0x399C, //
    0xAAAA, 0xF0F0, 0x5A5A, 0x33CC, 0x3C3C, 0x55AA, 0x9696, 0xA55A, //
    0x73CE, 0x13C8, 0x324C, 0x3BDC, 0x6996, 0xC33C, 0x9966, 0x0660, //
    0x0272, 0x04E4, 0x4E40, 0x2720, 0xC936, 0x936C, 0x39C6, 0x639C, //
    0x9336, 0x9CC6, 0x817E, 0xE718, 0xCCF0, 0x0FCC, 0x7744, 0xEE22,
];

/// Three-subset partitions (Table.P3): bits `2i`, `2i + 1` hold pixel `i`'s subset.
static P3: [u32; 64] = [
    0xAA685050, 0x6A5A5040, 0x5A5A4200, 0x5450A0A8, 0xA5A50000, 0xA0A05050, //
    0x5555A0A0, 0x5A5A5050, 0xAA550000, 0xAA555500, 0xAAAA5500, 0x90909090, //
    0x94949494, 0xA4A4A4A4, 0xA9A59450, 0x2A0A4250, 0xA5945040, 0x0A425054, //
    0xA5A5A500, 0x55A0A0A0, 0xA8A85454, 0x6A6A4040, 0xA4A45000, 0x1A1A0500, //
    0x0050A4A4, 0xAAA59090, 0x14696914, 0x69691400, 0xA08585A0, 0xAA821414, //
    0x50A4A450, 0x6A5A0200, 0xA9A58000, 0x5090A0A8, 0xA8A09050, 0x24242424, //
    0x00AA5500, 0x24924924, 0x24499224, 0x50A50A50, 0x500AA550, 0xAAAA4444, //
    0x66660000, 0xA5A0A5A0, 0x50A050A0, 0x69286928, 0x44AAAA44, 0x66666600, //
    0xAA444444, 0x54A854A8, 0x95809580, 0x96969600, 0xA85454A8, 0x80959580, //
    0xAA141414, 0x96960000, 0xAAAA1414, 0xA05050A0, 0xA0A5A5A0, 0x96000000, //
    0x40804080, 0xA9A8A9A8, 0xAAAAAA44, 0x2A4A5254,
];

/// Anchor pixel of subset 1 of the two-subset partitions (Table.A2).
static A2: [u8; 64] = [
    15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, //
    15, 2, 8, 2, 2, 8, 8, 15, 2, 8, 2, 2, 8, 8, 2, 2, //
    15, 15, 6, 8, 2, 8, 15, 15, 2, 8, 2, 2, 2, 15, 15, 6, //
    6, 2, 6, 8, 15, 15, 2, 2, 15, 15, 15, 15, 15, 2, 2, 15,
];

/// Anchor pixel of subset 1 of the three-subset partitions (Table.A3a).
static A3A: [u8; 64] = [
    3, 3, 15, 15, 8, 3, 15, 15, 8, 8, 6, 6, 6, 5, 3, 3, //
    3, 3, 8, 15, 3, 3, 6, 10, 5, 8, 8, 6, 8, 5, 15, 15, //
    8, 15, 3, 5, 6, 10, 8, 15, 15, 3, 15, 5, 15, 15, 15, 15, //
    3, 15, 5, 5, 5, 8, 5, 10, 5, 10, 8, 13, 15, 12, 3, 3,
];

/// Anchor pixel of subset 2 of the three-subset partitions (Table.A3b).
static A3B: [u8; 64] = [
    15, 8, 8, 3, 15, 15, 3, 8, 15, 15, 15, 15, 15, 15, 15, 8, //
    15, 8, 15, 3, 15, 8, 15, 8, 3, 15, 6, 10, 15, 15, 10, 8, //
    15, 3, 15, 10, 10, 8, 9, 10, 6, 15, 8, 15, 3, 6, 6, 8, //
    15, 3, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 3, 15, 15, 8,
];

/// Interpolation weights (out of 64) of 2-, 3- and 4-bit indices.
static W2: [u32; 4] = [0, 21, 43, 64];
static W3: [u32; 8] = [0, 9, 18, 27, 37, 46, 55, 64];
static W4: [u32; 16] = [0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64];

fn weights(bits: u32) -> &'static [u32] {
    match bits {
        2 => &W2,
        3 => &W3,
        _ => &W4,
    }
}

fn at<T: Copy + Default>(table: &[T], i: usize) -> T {
    table.get(i).copied().unwrap_or_default()
}

/// The subset of pixel `i` in `partition` of a mode with `subsets` subsets.
fn subset_of(subsets: usize, partition: usize, i: usize) -> usize {
    match subsets {
        2 => usize::from((at(&P2, partition) >> i) & 1),
        3 => ((at(&P3, partition) >> (2 * i)) & 3) as usize,
        _ => 0,
    }
}

/// The anchor pixel of each subset (whose index is stored without its top bit); 16 for none.
fn anchors(subsets: usize, partition: usize) -> [usize; 3] {
    match subsets {
        2 => [0, usize::from(at(&A2, partition)), 16],
        3 => [0, usize::from(at(&A3A, partition)), usize::from(at(&A3B, partition))],
        _ => [0, 16, 16],
    }
}

/// An endpoint component of `bits` bits (p-bit included) widened to 8 bits by repeating its top
/// bits.
fn expand(v: u32, bits: u32) -> u32 {
    if bits >= 8 { v } else { (v << (8 - bits)) | (v >> (2 * bits).saturating_sub(8)) }
}

fn interpolate(a: u32, b: u32, w: u32) -> u32 {
    ((64 - w) * a + w * b + 32) >> 6
}

/// Reads fields from the low bits of a block.
struct Reader {
    word: u128,
}

impl Reader {
    fn read(&mut self, bits: u32) -> u32 {
        let v = (self.word & ((1u128 << bits) - 1)) as u32;
        self.word >>= bits;
        v
    }
}

/// Decodes one BC7 block into RGBA; a block of the reserved mode (first byte 0) is transparent
/// black, as the format's definition requires.
pub fn decode_bc7(block: &[u8; 16]) -> [[u8; 4]; BLOCK_PIXELS] {
    let word = u128::from_le_bytes(*block);
    let first = *block.first().unwrap_or(&0);
    let Some(m) = MODES.get(first.trailing_zeros() as usize).copied() else {
        return [[0; 4]; BLOCK_PIXELS];
    };
    let mut r = Reader { word: word >> (first.trailing_zeros() + 1) };
    let partition = r.read(m.partition_bits) as usize;
    let rotation = r.read(m.rotation_bits);
    let selector = r.read(m.selector_bits);
    let mut ends = [[[0u32; 4]; 2]; 3];
    let comps = if m.alpha_bits > 0 { 4 } else { 3 };
    for c in 0..comps {
        let bits = if c == 3 { m.alpha_bits } else { m.color_bits };
        for subset in ends.iter_mut().take(m.subsets) {
            for end in subset.iter_mut() {
                if let Some(v) = end.get_mut(c) {
                    *v = r.read(bits);
                }
            }
        }
    }
    let with_pbit = m.endpoint_pbits || m.shared_pbits;
    for subset in ends.iter_mut().take(m.subsets) {
        let shared = if m.shared_pbits { r.read(1) } else { 0 };
        for end in subset.iter_mut() {
            let p = if m.endpoint_pbits { r.read(1) } else { shared };
            if with_pbit {
                end.iter_mut().for_each(|v| *v = (*v << 1) | p);
            }
        }
    }
    let pbit = u32::from(with_pbit);
    for subset in ends.iter_mut().take(m.subsets) {
        for end in subset.iter_mut() {
            for (c, v) in end.iter_mut().enumerate() {
                *v = match (c, m.alpha_bits) {
                    (3, 0) => 255,
                    (3, a) => expand(*v, a + pbit),
                    _ => expand(*v, m.color_bits + pbit),
                };
            }
        }
    }
    let anchor = anchors(m.subsets, partition);
    let mut index = [0u32; BLOCK_PIXELS];
    for (i, k) in index.iter_mut().enumerate() {
        let s = subset_of(m.subsets, partition, i);
        *k = r.read(m.index_bits - u32::from(at(&anchor, s) == i));
    }
    let mut index2 = [0u32; BLOCK_PIXELS];
    if m.index2_bits > 0 {
        for (i, k) in index2.iter_mut().enumerate() {
            *k = r.read(m.index2_bits - u32::from(i == 0));
        }
    }
    core::array::from_fn(|i| {
        let [e0, e1] = at(&ends, subset_of(m.subsets, partition, i));
        let (k, k2) = (at(&index, i) as usize, at(&index2, i) as usize);
        // Colour and alpha weights: one index for both, or colour from one and alpha from the
        // other, swapped by the selector bit.
        let (wc, wa) = match (m.index2_bits, selector) {
            (0, _) => (at(weights(m.index_bits), k), at(weights(m.index_bits), k)),
            (_, 0) => (at(weights(m.index_bits), k), at(weights(m.index2_bits), k2)),
            _ => (at(weights(m.index2_bits), k2), at(weights(m.index_bits), k)),
        };
        let mut px: [u8; 4] = core::array::from_fn(|c| {
            interpolate(at(&e0, c), at(&e1, c), if c == 3 { wa } else { wc }) as u8
        });
        if rotation > 0 {
            px.swap(3, rotation as usize - 1);
        }
        px
    })
}

/// How one fit stores its endpoints: the bits of each component without the p-bit, and the
/// p-bit choices to try (`[p0, p1]`), or `None` when the mode has no p-bits.
#[derive(Clone, Copy)]
struct Precision {
    bits: [u32; 4],
    pbits: Option<&'static [[u32; 2]]>,
}

/// The one "choice" of a fit without p-bits.
static NO_PBITS: [[u32; 2]; 1] = [[0, 0]];
static ENDPOINT_PBITS: [[u32; 2]; 4] = [[0, 0], [0, 1], [1, 0], [1, 1]];
static SHARED_PBITS: [[u32; 2]; 2] = [[0, 0], [1, 1]];
/// Mode 6 for opaque blocks: alpha 127 with p-bit 1 is 255 on both endpoints.
static OPAQUE_PBITS: [[u32; 2]; 1] = [[1, 1]];

impl Precision {
    fn has_pbit(&self) -> bool {
        self.pbits.is_some()
    }

    /// The stored value of `bits` bits (and p-bit `p`) whose expansion is nearest `target`.
    fn quantize(&self, c: usize, target: i32, p: u32) -> u32 {
        let bits = at(&self.bits, c);
        let pbit = u32::from(self.has_pbit());
        let total = bits + pbit;
        let max = (1u32 << bits) - 1;
        let t = target.clamp(0, 255) as u32;
        let guess = ((t * ((1 << total) - 1) + 127) / 255) >> pbit;
        let value = |q: u32| expand((q << pbit) | (p & pbit), total);
        let mut best = guess.min(max);
        for q in [guess.saturating_sub(1), guess + 1] {
            let q = q.min(max);
            if value(q).abs_diff(t) < value(best).abs_diff(t) {
                best = q;
            }
        }
        best
    }

    /// The 8-bit value of stored component `q` with p-bit `p`.
    fn value(&self, c: usize, q: u32, p: u32) -> u32 {
        let pbit = u32::from(self.has_pbit());
        expand((q << pbit) | (p & pbit), at(&self.bits, c) + pbit)
    }
}

/// One subset's endpoints as stored, its p-bits, the index of each of its pixels, and the
/// squared error over the fitted components.
#[derive(Clone, Copy, Default)]
struct Fit {
    ends: [[u32; 4]; 2],
    pbits: [u32; 2],
    index: [u8; BLOCK_PIXELS],
    error: u64,
}

/// The pixels of a fit: the fitted components of each member (the pixels of a mask), gathered
/// once for the fit's rounds.
struct Subset {
    /// The members' fitted components, 0 past the fitted ones, in pixel order.
    points: [[i64; 4]; BLOCK_PIXELS],
    /// Each member's pixel.
    pixel: [usize; BLOCK_PIXELS],
    members: usize,
    dims: usize,
}

impl Subset {
    /// Components `comps` (of R, G, B, A) of the pixels in `mask`.
    fn new(pixels: &[[u8; 4]; BLOCK_PIXELS], mask: u16, comps: &[usize]) -> Subset {
        let mut s = Subset {
            points: [[0; 4]; BLOCK_PIXELS],
            pixel: [0; BLOCK_PIXELS],
            members: 0,
            dims: comps.len(),
        };
        for (i, p) in pixels.iter().enumerate().filter(|&(i, _)| counts(mask, i)) {
            if let (Some(q), Some(at_pixel)) =
                (s.points.get_mut(s.members), s.pixel.get_mut(s.members))
            {
                *q = core::array::from_fn(|k| comps.get(k).map_or(0, |&c| i64::from(at(p, c))));
                *at_pixel = i;
                s.members += 1;
            }
        }
        s
    }

    /// Each member's pixel and fitted components.
    fn members(&self) -> impl Iterator<Item = (usize, &[i64; 4])> + '_ {
        let n = self.members;
        self.pixel.iter().copied().zip(&self.points).take(n)
    }

    /// The pixels at both ends of the principal axis of the fitted components, as 8-bit targets;
    /// the first pixel twice when they do not spread.
    fn axis_ends(&self) -> [[i32; 4]; 2] {
        let target = |k: usize| -> [i32; 4] { at(&self.points, k).map(|v| v as i32) };
        let points = self.points.get(..self.members).unwrap_or(&[]);
        let (lo, hi) = principal_ends(points, self.dims).unwrap_or((0, 0));
        [target(lo), target(hi)]
    }

    /// The nearest palette entry of every member (the lowest index on a tie) and the squared
    /// error, for stored endpoints `ends` with p-bits `pbits`.
    fn assign(&self, q: &Precision, index_bits: u32, ends: &[[u32; 4]; 2], pbits: [u32; 2]) -> Fit {
        let dims = self.dims;
        let e: [[i64; 4]; 2] = core::array::from_fn(|k| {
            core::array::from_fn(|c| {
                if c < dims { i64::from(q.value(c, at(&at(ends, k), c), at(&pbits, k))) } else { 0 }
            })
        });
        let [e0, e1] = e;
        let w = weights(index_bits);
        let mut palette = [[0i64; 4]; 16];
        for (entry, &wk) in palette.iter_mut().zip(w) {
            for ((v, &a), &b) in entry.iter_mut().zip(&e0).zip(&e1) {
                *v = i64::from(interpolate(a as u32, b as u32, wk));
            }
        }
        let entries = w.len();
        let d: [i64; 4] = core::array::from_fn(|c| at(&e1, c) - at(&e0, c));
        let dd: i64 = d.iter().map(|x| x * x).sum();
        let mut fit = Fit { ends: *ends, pbits, ..Fit::default() };
        for (i, p) in self.members() {
            let err = |k: usize| -> i64 {
                let entry = at(&palette, k);
                p.iter().zip(&entry).map(|(v, e)| (v - e).pow(2)).sum()
            };
            // The entry nearest the pixel's projection on the endpoint line, then its
            // neighbours (the rounded palette is not exactly on the line).
            let guess = if dd == 0 {
                0
            } else {
                let t: i64 = p.iter().zip(&e0).zip(&d).map(|((v, e), d)| (v - e) * d).sum();
                let wt = (t * 64 + dd / 2).div_euclid(dd).clamp(0, 64) as u32;
                w.iter().position(|&x| x >= wt).map_or(entries - 1, |k| {
                    let below = k.saturating_sub(1);
                    if wt - at(w, below) <= at(w, k) - wt { below } else { k }
                })
            };
            let mut best = (guess, err(guess));
            for k in [guess.wrapping_sub(1), guess + 1] {
                if k < entries {
                    let e = err(k);
                    if e < best.1 || (e == best.1 && k < best.0) {
                        best = (k, e);
                    }
                }
            }
            if let Some(slot) = fit.index.get_mut(i) {
                *slot = best.0 as u8;
            }
            fit.error += best.1 as u64;
        }
        fit
    }

    /// Least-squares 8-bit endpoints for the weights of `fit`'s indices, or `None` if every
    /// member has the same weight.
    fn refine(&self, fit: &Fit, index_bits: u32) -> Option<[[i32; 4]; 2]> {
        let w = weights(index_bits);
        let (mut aa, mut bb, mut ab) = (0i64, 0i64, 0i64);
        let (mut x, mut y) = ([0i64; 4], [0i64; 4]);
        for (i, p) in self.members() {
            let beta = i64::from(at(w, usize::from(at(&fit.index, i))));
            let alpha = 64 - beta;
            aa += alpha * alpha;
            bb += beta * beta;
            ab += alpha * beta;
            for ((xc, yc), v) in x.iter_mut().zip(&mut y).zip(p) {
                *xc += alpha * v;
                *yc += beta * v;
            }
        }
        let det = aa * bb - ab * ab;
        if det == 0 {
            return None;
        }
        let solve = |num: i64| -> i32 { (2 * num + det).div_euclid(2 * det).clamp(0, 255) as i32 };
        let e0 = core::array::from_fn(|c| solve(64 * (bb * at(&x, c) - ab * at(&y, c))));
        let e1 = core::array::from_fn(|c| solve(64 * (aa * at(&y, c) - ab * at(&x, c))));
        Some([e0, e1])
    }

    /// The best endpoints for these pixels: from the principal axis, every p-bit choice, then
    /// least squares twice.
    fn fit(&self, q: &Precision, index_bits: u32) -> Fit {
        if self.members == 0 {
            return Fit::default();
        }
        let mut targets = self.axis_ends();
        let mut best: Option<Fit> = None;
        for round in 0..3 {
            for &pbits in q.pbits.unwrap_or(&NO_PBITS) {
                let ends: [[u32; 4]; 2] = core::array::from_fn(|k| {
                    core::array::from_fn(|c| {
                        if c < self.dims {
                            q.quantize(c, at(&at(&targets, k), c), at(&pbits, k))
                        } else {
                            0
                        }
                    })
                });
                let fit = self.assign(q, index_bits, &ends, pbits);
                if best.is_none_or(|b| fit.error < b.error) {
                    best = Some(fit);
                }
            }
            let Some(b) = best.filter(|b| round < 2 && b.error > 0) else { break };
            let Some(next) = self.refine(&b, index_bits) else { break };
            targets = next;
        }
        best.unwrap_or_default()
    }
}

/// A whole encoded block before packing.
#[derive(Clone, Copy)]
struct Candidate {
    mode: usize,
    partition: usize,
    /// Modes 4 and 5: the colour channel (1–3: R, G, B) stored in the alpha slot, 0 for none.
    rotation: u32,
    /// Mode 4: 1 when colour takes the 3-bit indices (`index2`) and alpha the 2-bit ones.
    selector: u32,
    /// Stored endpoints per subset (RGBA; alpha as the mode stores it) and p-bits.
    ends: [[[u32; 4]; 2]; 3],
    pbits: [[u32; 2]; 3],
    index: [u8; BLOCK_PIXELS],
    index2: [u8; BLOCK_PIXELS],
    error: u64,
}

impl Candidate {
    /// Swaps endpoints where an anchor's index has its top bit set (the format stores anchors
    /// without it), inverting that subset's indices.
    fn fix_anchors(&mut self) {
        let m = at(&MODES, self.mode);
        let anchor = anchors(m.subsets, self.partition);
        let top = 1u8 << (m.index_bits - 1);
        // The components each index array interpolates: with two arrays, `index` holds colour's
        // and `index2` alpha's, or the other way round when the selector is set.
        let (first, second) = match (m.index2_bits, self.selector) {
            (0, _) => (0..4, 0..0),
            (_, 0) => (0..3, 3..4),
            _ => (3..4, 0..3),
        };
        for s in 0..m.subsets {
            let a = at(&anchor, s);
            if at(&self.index, a) & top == 0 {
                continue;
            }
            let max = (top << 1) - 1;
            for i in 0..BLOCK_PIXELS {
                if subset_of(m.subsets, self.partition, i) == s
                    && let Some(k) = self.index.get_mut(i)
                {
                    *k = max - *k;
                }
            }
            if let Some([e0, e1]) = self.ends.get_mut(s) {
                for c in first.clone() {
                    if let (Some(a), Some(b)) = (e0.get_mut(c), e1.get_mut(c)) {
                        core::mem::swap(a, b);
                    }
                }
            }
            if let Some(p) = self.pbits.get_mut(s) {
                p.swap(0, 1);
            }
        }
        if m.index2_bits > 0 && at(&self.index2, 0) & (1 << (m.index2_bits - 1)) != 0 {
            let max = (1u8 << m.index2_bits) - 1;
            self.index2.iter_mut().for_each(|k| *k = max - *k);
            if let Some([e0, e1]) = self.ends.get_mut(0) {
                for c in second {
                    if let (Some(a), Some(b)) = (e0.get_mut(c), e1.get_mut(c)) {
                        core::mem::swap(a, b);
                    }
                }
            }
        }
    }

    fn pack(mut self) -> [u8; 16] {
        self.fix_anchors();
        let m = at(&MODES, self.mode);
        let mut word = 0u128;
        let mut pos = 0u32;
        let mut put = |v: u32, bits: u32| {
            word |= (u128::from(v) & ((1u128 << bits) - 1)) << pos;
            pos += bits;
        };
        put(1 << self.mode, self.mode as u32 + 1);
        put(self.partition as u32, m.partition_bits);
        put(self.rotation, m.rotation_bits);
        put(self.selector, m.selector_bits);
        let comps = if m.alpha_bits > 0 { 4 } else { 3 };
        for c in 0..comps {
            let bits = if c == 3 { m.alpha_bits } else { m.color_bits };
            for subset in self.ends.iter().take(m.subsets) {
                for end in subset {
                    put(at(end, c), bits);
                }
            }
        }
        for pbits in self.pbits.iter().take(m.subsets) {
            if m.shared_pbits {
                put(at(pbits, 0), 1);
            } else if m.endpoint_pbits {
                put(at(pbits, 0), 1);
                put(at(pbits, 1), 1);
            }
        }
        let anchor = anchors(m.subsets, self.partition);
        for (i, &k) in self.index.iter().enumerate() {
            let s = subset_of(m.subsets, self.partition, i);
            put(u32::from(k), m.index_bits - u32::from(at(&anchor, s) == i));
        }
        if m.index2_bits > 0 {
            for (i, &k) in self.index2.iter().enumerate() {
                put(u32::from(k), m.index2_bits - u32::from(i == 0));
            }
        }
        word.to_le_bytes()
    }
}

const RGB: [usize; 3] = [0, 1, 2];
const RGBA: [usize; 4] = [0, 1, 2, 3];
const ALPHA: [usize; 1] = [3];

/// Partitions of a mode's table tried in full, best first by the one-colour-per-subset error.
const TRIED_PARTITIONS: usize = 4;

/// The `TRIED_PARTITIONS` partitions of the 64 with the least squared error when each subset is
/// its mean colour, best first (the lower partition on a tie); and the same of the first 16 (mode
/// 0's), from the same pass.
fn rank_partitions(
    pixels: &[[u8; 4]; BLOCK_PIXELS],
    valid: u16,
    subsets: usize,
) -> [[usize; TRIED_PARTITIONS]; 2] {
    let mut best = [[(i64::MAX, 0usize); TRIED_PARTITIONS]; 2];
    for partition in 0..64 {
        let mut stats = [(0i64, [0i64; 3], 0i64); 3];
        for (i, p) in pixels.iter().enumerate().filter(|&(i, _)| counts(valid, i)) {
            if let Some((n, sum, sq)) = stats.get_mut(subset_of(subsets, partition, i)) {
                *n += 1;
                for (s, &v) in sum.iter_mut().zip(p.iter()) {
                    *s += i64::from(v);
                    *sq += i64::from(v) * i64::from(v);
                }
            }
        }
        let cost: i64 = stats
            .iter()
            .filter(|(n, _, _)| *n > 0)
            .map(|(n, sum, sq)| sq - sum.iter().map(|s| s * s / n).sum::<i64>())
            .sum();
        for best in best.iter_mut().take(if partition < 16 { 2 } else { 1 }) {
            if let Some(slot) = best.iter().position(|&(c, _)| cost < c) {
                best.copy_within(slot..TRIED_PARTITIONS - 1, slot + 1);
                if let Some(b) = best.get_mut(slot) {
                    *b = (cost, partition);
                }
            }
        }
    }
    best.map(|ranked| ranked.map(|(_, p)| p))
}

/// Encodes `pixels` in a mode of subsets (mode 0–3, 7), for each partition given, into `best`
/// where a partition does better than it.
fn encode_subsets(
    pixels: &[[u8; 4]; BLOCK_PIXELS],
    valid: u16,
    mode: usize,
    partitions: &[usize],
    best: &mut Candidate,
) {
    let m = at(&MODES, mode);
    let pbits: Option<&'static [[u32; 2]]> = if m.endpoint_pbits {
        Some(&ENDPOINT_PBITS)
    } else if m.shared_pbits {
        Some(&SHARED_PBITS)
    } else {
        None
    };
    let q = Precision { bits: [m.color_bits; 4], pbits };
    for &partition in partitions {
        let mut c = Candidate {
            mode,
            partition,
            rotation: 0,
            selector: 0,
            ends: [[[0; 4]; 2]; 3],
            pbits: [[0; 2]; 3],
            index: [0; BLOCK_PIXELS],
            index2: [0; BLOCK_PIXELS],
            error: 0,
        };
        for s in 0..m.subsets {
            let mask = (0..BLOCK_PIXELS)
                .filter(|&i| subset_of(m.subsets, partition, i) == s)
                .fold(0u16, |mask, i| mask | (1 << i))
                & valid;
            let fit = Subset::new(pixels, mask, &RGB).fit(&q, m.index_bits);
            if let (Some(e), Some(p)) = (c.ends.get_mut(s), c.pbits.get_mut(s)) {
                *e = fit.ends;
                *p = fit.pbits;
            }
            for i in (0..BLOCK_PIXELS).filter(|&i| counts(mask, i)) {
                if let Some(k) = c.index.get_mut(i) {
                    *k = at(&fit.index, i);
                }
            }
            c.error += fit.error;
            if c.error >= best.error {
                break;
            }
        }
        if c.error < best.error {
            *best = c;
        }
    }
}

/// Mode 6: one subset, 7-bit endpoints with a p-bit each, 4-bit indices; RGB with alpha 255,
/// or RGBA together.
fn encode_mode6(pixels: &[[u8; 4]; BLOCK_PIXELS], valid: u16, alpha: bool) -> Candidate {
    let (comps, pbits): (&[usize], &'static [[u32; 2]]) =
        if alpha { (&RGBA, &ENDPOINT_PBITS) } else { (&RGB, &OPAQUE_PBITS) };
    let q = Precision { bits: [7; 4], pbits: Some(pbits) };
    let fit = Subset::new(pixels, valid, comps).fit(&q, 4);
    let mut ends = fit.ends;
    if !alpha {
        ends.iter_mut().for_each(|e| e[3] = 127);
    }
    Candidate {
        mode: 6,
        partition: 0,
        rotation: 0,
        selector: 0,
        ends: [ends, [[0; 4]; 2], [[0; 4]; 2]],
        pbits: [fit.pbits, [0; 2], [0; 2]],
        index: fit.index,
        index2: [0; BLOCK_PIXELS],
        error: fit.error,
    }
}

/// Modes 4 and 5: one subset, colour and alpha each with indices of their own; mode 5: 7-bit
/// colour and 8-bit alpha endpoints, 2-bit indices for both; mode 4: 5-bit colour and 6-bit
/// alpha, 2-bit indices for one and 3-bit for the other (colour's 3-bit with `selector` 1).
/// With `rotation` r (1–3) the block stores colour channel r − 1 in the alpha slot and alpha (255:
/// an opaque block) in that channel's place, which the decoder swaps back.
fn encode_separate(
    pixels: &[[u8; 4]; BLOCK_PIXELS],
    valid: u16,
    mode: usize,
    rotation: u32,
    selector: u32,
) -> Candidate {
    let m = at(&MODES, mode);
    let mut stored = *pixels;
    if rotation > 0 {
        let r = rotation as usize - 1;
        for p in &mut stored {
            if let Some(&v) = p.get(r) {
                p[3] = v;
            }
            if let Some(v) = p.get_mut(r) {
                *v = 255;
            }
        }
    }
    let (colour_index, alpha_index) =
        if selector == 0 { (m.index_bits, m.index2_bits) } else { (m.index2_bits, m.index_bits) };
    // A rotated block's slot holds 255 on every pixel, so it decodes as 255: both endpoints
    // quantize to the top code (its expansion 255), and least squares returns 255 exactly for a
    // constant (its numerators are 255 times the determinant).
    let colour = Subset::new(&stored, valid, &RGB)
        .fit(&Precision { bits: [m.color_bits; 4], pbits: None }, colour_index);
    let alpha = Subset::new(&stored, valid, &ALPHA)
        .fit(&Precision { bits: [m.alpha_bits; 4], pbits: None }, alpha_index);
    let mut ends = colour.ends;
    for (e, a) in ends.iter_mut().zip(&alpha.ends) {
        e[3] = a[0];
    }
    let (index, index2) =
        if selector == 0 { (colour.index, alpha.index) } else { (alpha.index, colour.index) };
    Candidate {
        mode,
        partition: 0,
        rotation,
        selector,
        ends: [ends, [[0; 4]; 2], [[0; 4]; 2]],
        pbits: [[0; 2]; 3],
        index,
        index2,
        error: colour.error + alpha.error,
    }
}

/// Encodes one block. With `alpha` false the pixels' alpha is ignored and every pixel decodes
/// with alpha 255 (an RGB texture); with `alpha` true, blocks whose valid pixels all have alpha
/// 255 are encoded as opaque, the others with alpha (modes 5 and 6).
pub fn encode_bc7(pixels: &[[u8; 4]; BLOCK_PIXELS], valid: u16, alpha: bool) -> [u8; 16] {
    choose(pixels, valid, alpha).pack()
}

/// The candidate [`encode_bc7`] packs.
fn choose(pixels: &[[u8; 4]; BLOCK_PIXELS], valid: u16, alpha: bool) -> Candidate {
    let translucent =
        alpha && pixels.iter().enumerate().any(|(i, p)| counts(valid, i) && p[3] != 255);
    if valid == 0 {
        return encode_mode6(&[[0, 0, 0, 255]; BLOCK_PIXELS], super::ALL_VALID, false);
    }
    if translucent {
        let (a, b) = (encode_mode6(pixels, valid, true), encode_separate(pixels, valid, 5, 0, 0));
        return if b.error < a.error { b } else { a };
    }
    let mut best = encode_mode6(pixels, valid, false);
    if best.error > 0 {
        let [two, _] = rank_partitions(pixels, valid, 2);
        encode_subsets(pixels, valid, 1, &two, &mut best);
        encode_subsets(pixels, valid, 3, two.get(..2).unwrap_or(&[]), &mut best);
        let [three, first16] = rank_partitions(pixels, valid, 3);
        encode_subsets(pixels, valid, 2, three.get(..2).unwrap_or(&[]), &mut best);
        // Mode 0 has the first 16 three-subset partitions only.
        encode_subsets(pixels, valid, 0, first16.get(..2).unwrap_or(&[]), &mut best);
        // One channel with indices of its own: mode 5 for each channel, mode 4 (both index
        // precisions) for the channel mode 5 did best with.
        let mut rotation = (u64::MAX, 1);
        for r in 1..=3 {
            let c = encode_separate(pixels, valid, 5, r, 0);
            if c.error < rotation.0 {
                rotation = (c.error, r);
            }
            if c.error < best.error {
                best = c;
            }
        }
        for selector in 0..2 {
            let c = encode_separate(pixels, valid, 4, rotation.1, selector);
            if c.error < best.error {
                best = c;
            }
        }
    }
    best
}

/// [`encode_bc7`]'s block and the squared error its search computed for it (over RGB, or RGBA
/// for a block encoded with alpha).
#[cfg(test)]
pub(super) fn tests_encode(
    pixels: &[[u8; 4]; BLOCK_PIXELS],
    valid: u16,
    alpha: bool,
) -> ([u8; 16], u64) {
    let c = choose(pixels, valid, alpha);
    (c.pack(), c.error)
}

/// The least squared error over RGB of an opaque block when, besides the encoder's own search,
/// every partition of modes 0–3 is encoded in full (the encoder ranks them and encodes the best
/// few).
#[cfg(test)]
pub(super) fn tests_every_partition_error(pixels: &[[u8; 4]; BLOCK_PIXELS], valid: u16) -> u64 {
    let every: [usize; 64] = core::array::from_fn(|p| p);
    let mut best = choose(pixels, valid, false);
    for (mode, count) in [(1, 64), (3, 64), (2, 64), (0, 16)] {
        encode_subsets(pixels, valid, mode, every.get(..count).unwrap_or(&[]), &mut best);
    }
    best.error
}

/// The anchor pixel of each subset ([`anchors`]).
#[cfg(test)]
pub(super) fn tests_anchors(subsets: usize, partition: usize) -> [usize; 3] {
    anchors(subsets, partition)
}

/// The 8-bit value of the stored component [`Precision::quantize`] picks for `target`, in
/// endpoints of `bits` bits, with p-bit `p` when `pbit`.
#[cfg(test)]
pub(super) fn tests_quantized(bits: u32, pbit: bool, p: u32, target: i32) -> u32 {
    let q = Precision { bits: [bits; 4], pbits: pbit.then_some(&ENDPOINT_PBITS[..]) };
    q.value(0, q.quantize(0, target, p), p)
}
