//! BC4 (one channel, 8 bytes per block) and BC5 (two BC4 blocks: red, then green).
//!
//! A block is two endpoints `a0`, `a1` (a byte each) and a 3-bit index per pixel (pixel `i` at
//! bits `16 + 3i` of the little-endian 64-bit block). With `a0 > a1` the palette is `a0`, `a1`
//! and six values between them; otherwise `a0`, `a1`, four values between them, 0 and 255.

use super::{BLOCK_PIXELS, counts};

/// The 8 palette values of endpoints `a0`, `a1` (exactly rounded interpolation).
fn palette(a0: u8, a1: u8) -> [u8; 8] {
    let (e0, e1) = (u32::from(a0), u32::from(a1));
    let mut p = [a0, a1, 0, 0, 0, 0, 0, 255];
    if a0 > a1 {
        for (k, slot) in (1u32..).zip(p.iter_mut().skip(2)) {
            // k = 1..=6: ((7 − k)·a0 + k·a1) / 7, rounded to nearest (7 is odd: no ties).
            *slot = (((7 - k) * e0 + k * e1 + 3) / 7) as u8;
        }
    } else {
        for (k, slot) in (1u32..).zip(p.iter_mut().skip(2).take(4)) {
            *slot = (((5 - k) * e0 + k * e1 + 2) / 5) as u8;
        }
    }
    p
}

/// The palette's entries in ascending order of value, as indices: with `a0 > a1` (eight values:
/// a1, then the interpolated ones from a1's side, then a0) and without (0, a0, …, a1, 255).
const ASCENDING_EIGHT: [u8; 8] = [1, 7, 6, 5, 4, 3, 2, 0];
const ASCENDING_SIX: [u8; 8] = [6, 0, 2, 3, 4, 5, 1, 7];

/// The indices of the nearest palette entries of endpoints `a0`, `a1` (the smaller value on a
/// tie; index 0 for pixels that do not count). The entries are sorted, so a pixel's entry is the
/// number of midpoints between neighbours below it: seven comparisons per pixel, which the
/// compiler runs on all 16 pixels at once.
fn indices(values: &[u8; BLOCK_PIXELS], valid: u16, a0: u8, a1: u8) -> u64 {
    let p = palette(a0, a1);
    let order = if a0 > a1 { ASCENDING_EIGHT } else { ASCENDING_SIX };
    let sorted = order.map(|k| u16::from(p.get(usize::from(k)).copied().unwrap_or(0)));
    let mut position = [0u8; BLOCK_PIXELS];
    for pair in sorted.windows(2) {
        // Twice the midpoint of neighbours j and j + 1: a pixel above it is nearer j + 1.
        let mid = pair.iter().sum::<u16>();
        for (at, &v) in position.iter_mut().zip(values) {
            *at += u8::from(2 * u16::from(v) > mid);
        }
    }
    let mut indices = 0u64;
    for (i, &at) in position.iter().enumerate().filter(|&(i, _)| counts(valid, i)) {
        indices |= u64::from(order.get(usize::from(at)).copied().unwrap_or(0)) << (3 * i);
    }
    indices
}

/// The squared error of endpoints `a0`, `a1` over the pixels of `mask` (1 valid, 0 not), each
/// pixel at its nearest palette entry (as [`indices`] picks it), computed on all 16 pixels at once in
/// 16-bit lanes (a squared difference of bytes fits 16 bits).
fn error(values: &[u16; BLOCK_PIXELS], mask: &[u16; BLOCK_PIXELS], a0: u8, a1: u8) -> u32 {
    let p = palette(a0, a1);
    let mut best = [u16::MAX; BLOCK_PIXELS];
    for q in p.map(u16::from) {
        for (b, &v) in best.iter_mut().zip(values) {
            let d = v.abs_diff(q);
            *b = (*b).min(d * d);
        }
    }
    best.iter().zip(mask).map(|(&e, &m)| u32::from(e * m)).sum()
}

/// The endpoints that minimize the squared error for the given indices (least squares, rounded
/// and clamped to bytes), in the eight-value palette (`eight`) or the six-value one (whose 0 and
/// 255 entries do not depend on the endpoints); `None` if every pixel has the same weight.
fn refine(values: &[u8; BLOCK_PIXELS], valid: u16, eight: bool, indices: u64) -> Option<(u8, u8)> {
    // Entry k is (α·a0 + β·a1)/d with α + β = d: α = d, 0, then d − 1 … 1 for k = 2, 3, ….
    let d: i64 = if eight { 7 } else { 5 };
    let (mut aa, mut bb, mut ab, mut x, mut y) = (0i64, 0i64, 0i64, 0i64, 0i64);
    for (i, &v) in values.iter().enumerate() {
        let k = ((indices >> (3 * i)) & 7) as i64;
        if !counts(valid, i) || (!eight && k >= 6) {
            continue;
        }
        let alpha = match k {
            0 => d,
            1 => 0,
            _ => d + 1 - k,
        };
        let beta = d - alpha;
        aa += alpha * alpha;
        bb += beta * beta;
        ab += alpha * beta;
        x += alpha * i64::from(v);
        y += beta * i64::from(v);
    }
    let det = aa * bb - ab * ab;
    if det == 0 {
        return None;
    }
    // A·a0 + C·a1 = d·X and C·a0 + B·a1 = d·Y; det > 0 (a Gram determinant).
    let solve = |num: i64| (2 * d * num + det).div_euclid(2 * det).clamp(0, 255) as u8;
    Some((solve(bb * x - ab * y), solve(aa * y - ab * x)))
}

/// Encodes one block of one channel (see the module documentation of [`crate::bc`] for
/// `valid`). Candidates: in the eight-value palette, the 28 ramps on which the block's extremes
/// fall on two of its entries; in the six-value one (exact 0 and 255), the extremes of the other
/// pixels and their neighbours; then, three times, the least-squares endpoints of the best so far
/// and their neighbours. The pair with the least squared error is kept (the first found on a
/// tie), so the result is a pure function of the valid pixels.
pub fn encode_bc4(values: &[u8; BLOCK_PIXELS], valid: u16) -> [u8; 8] {
    let pixels = || values.iter().enumerate().filter(|&(i, _)| counts(valid, i)).map(|(_, &v)| v);
    let (Some(lo), Some(hi)) = (pixels().min(), pixels().max()) else {
        return [0; 8];
    };
    let wide = values.map(u16::from);
    let mask: [u16; BLOCK_PIXELS] = core::array::from_fn(|i| u16::from(counts(valid, i)));
    // The best (error, a0, a1) so far; indices only where needed.
    let mut best: Option<(u32, u8, u8)> = None;
    let consider = |best: &mut Option<(u32, u8, u8)>, a0: u8, a1: u8| {
        let e = error(&wide, &mask, a0, a1);
        if best.is_none_or(|b| e < b.0) {
            *best = Some((e, a0, a1));
        }
    };
    // The extremes themselves (for a block of one value: both endpoints equal to it).
    consider(&mut best, hi, lo);
    if lo != hi {
        // Eight values (a0 > a1): ramps on which the extremes fall on entries i < j of the 8
        // (i = 0, j = 7 is the extremes themselves; others let clusters in between land on every
        // other entry, say), each with its least-squares refinement.
        for (i, j) in (0..8i64).flat_map(|i| (i + 1..8).map(move |j| (i, j))) {
            let (l, h, n) = (i64::from(lo), i64::from(hi), j - i);
            let at = |k: i64| (2 * (l * n + k * (h - l)) + n).div_euclid(2 * n).clamp(0, 255) as u8;
            let (a0, a1) = (at(7 - i), at(-i));
            if a0 > a1 {
                consider(&mut best, a0, a1);
            }
        }
        // Six values and exact 0 and 255 (a0 ≤ a1): the endpoints near the extremes of the
        // pixels strictly between 0 and 255.
        let inner = || pixels().filter(|&v| v != 0 && v != 255);
        if let (Some(lo), Some(hi)) = (inner().min(), inner().max()) {
            for a0 in lo.saturating_sub(1)..=lo.saturating_add(1) {
                for a1 in hi.saturating_sub(1)..=hi.saturating_add(1) {
                    if a0 <= a1 {
                        consider(&mut best, a0, a1);
                    }
                }
            }
        } else {
            consider(&mut best, 0, 0);
        }
    }
    // Least-squares endpoints for the best indices so far, and their neighbours, three times.
    for _ in 0..3 {
        let Some((_, a0, a1)) = best else { break };
        let fitted = indices(values, valid, a0, a1);
        let Some((e0, e1)) = refine(values, valid, a0 > a1, fitted) else { break };
        for a0 in e0.saturating_sub(1)..=e0.saturating_add(1) {
            for a1 in e1.saturating_sub(1)..=e1.saturating_add(1) {
                if (a0 > a1) == (e0 > e1) {
                    consider(&mut best, a0, a1);
                }
            }
        }
    }
    let (_, a0, a1) = best.unwrap_or((0, lo, lo));
    let bits = u64::from(a0) | (u64::from(a1) << 8) | (indices(values, valid, a0, a1) << 16);
    bits.to_le_bytes()
}

/// Encodes one BC5 block: `red` as the first BC4 block, `green` as the second.
pub fn encode_bc5(red: &[u8; BLOCK_PIXELS], green: &[u8; BLOCK_PIXELS], valid: u16) -> [u8; 16] {
    let mut block = [0u8; 16];
    let (r, g) = block.split_at_mut(8);
    r.copy_from_slice(&encode_bc4(red, valid));
    g.copy_from_slice(&encode_bc4(green, valid));
    block
}

/// Decodes one BC4 block into its 16 values (row-major).
pub fn decode_bc4(block: &[u8; 8]) -> [u8; BLOCK_PIXELS] {
    let bits = u64::from_le_bytes(*block);
    let p = palette(block[0], block[1]);
    core::array::from_fn(|i| {
        let k = ((bits >> (16 + 3 * i)) & 7) as usize;
        p.get(k).copied().unwrap_or(0)
    })
}

/// Decodes one BC5 block into its red and green values (row-major).
pub fn decode_bc5(block: &[u8; 16]) -> ([u8; BLOCK_PIXELS], [u8; BLOCK_PIXELS]) {
    let (r, g) = block.split_at(8);
    let half = |s: &[u8]| -> [u8; 8] { core::array::from_fn(|k| s.get(k).copied().unwrap_or(0)) };
    (decode_bc4(&half(r)), decode_bc4(&half(g)))
}

#[cfg(test)]
pub(super) fn tests_palette(a0: u8, a1: u8) -> [u8; 8] {
    palette(a0, a1)
}
