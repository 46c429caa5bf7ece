//! BC1 (RGB, 8 bytes per block): two RGB 5:6:5 endpoints and a 2-bit index per pixel (pixel `i`
//! at bits `32 + 2i` of the little-endian block). With `c0 > c1` (as 16-bit numbers) the palette
//! is `c0`, `c1`, (2·c0 + c1)/3 and (c0 + 2·c1)/3; otherwise `c0`, `c1`, (c0 + c1)/2 and
//! transparent black. The encoder never uses transparent black, so its blocks are opaque
//! under any decoder.
//!
//! Encoding: the endpoints start at the pixels at both ends of the block's principal axis (power
//! iteration on the integer covariance), are refined by least squares for the chosen indices
//! (twice), and every candidate is tried in both endpoint orders (the 4- and the 3-colour
//! palette); the one with the least squared RGB error wins. A block of one colour uses the
//! endpoint pair whose 1/3 interpolation comes closest to it, per channel (`SINGLE5`, `SINGLE6`).

use super::{BLOCK_PIXELS, counts, principal_ends, sq};

/// Expands a 5-bit channel to 8 bits, round(v·255/31).
const fn expand5(v: u32) -> u32 {
    (v * 255 * 2 + 31) / 62
}

/// Expands a 6-bit channel to 8 bits, round(v·255/63).
const fn expand6(v: u32) -> u32 {
    (v * 255 * 2 + 63) / 126
}

/// round((2a + b)·255 / (3·max)) for channel values `a`, `b` of `max` = 31 or 63: the 1/3 point
/// between two endpoints, from their exact (not yet rounded) expansions.
const fn third(a: u32, b: u32, max: u32) -> u32 {
    ((2 * a + b) * 255 * 2 + 3 * max) / (6 * max)
}

/// round((a + b)·255 / (2·max)): the midpoint.
const fn half(a: u32, b: u32, max: u32) -> u32 {
    ((a + b) * 255 * 2 + 2 * max) / (4 * max)
}

/// An RGB 5:6:5 colour split into its channels.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
struct Rgb565 {
    r: u32,
    g: u32,
    b: u32,
}

impl Rgb565 {
    fn from_bits(c: u16) -> Rgb565 {
        let c = u32::from(c);
        Rgb565 { r: (c >> 11) & 31, g: (c >> 5) & 63, b: c & 31 }
    }

    fn bits(self) -> u16 {
        ((self.r << 11) | (self.g << 5) | self.b) as u16
    }

    /// The 5:6:5 colour whose channels expand closest to an 8-bit colour's.
    fn nearest(c: [i32; 3]) -> Rgb565 {
        let q = |v: i32, max: u32| ((v.clamp(0, 255) as u32 * max + 127) / 255).min(max);
        Rgb565 { r: q(c[0], 31), g: q(c[1], 63), b: q(c[2], 31) }
    }

    fn expand(self) -> [u8; 3] {
        [expand5(self.r) as u8, expand6(self.g) as u8, expand5(self.b) as u8]
    }
}

/// The palette of endpoints `c0`, `c1` (as stored) and how many of its entries are colours the
/// encoder may use (4, or 3 in the mode whose fourth entry is transparent black).
fn palette(c0: u16, c1: u16) -> ([[u8; 3]; 4], usize) {
    let (a, b) = (Rgb565::from_bits(c0), Rgb565::from_bits(c1));
    let mut p = [a.expand(), b.expand(), [0; 3], [0; 3]];
    if c0 > c1 {
        let (t0, t1) = (
            [third(a.r, b.r, 31), third(a.g, b.g, 63), third(a.b, b.b, 31)],
            [third(b.r, a.r, 31), third(b.g, a.g, 63), third(b.b, a.b, 31)],
        );
        p[2] = t0.map(|v| v as u8);
        p[3] = t1.map(|v| v as u8);
        (p, 4)
    } else {
        p[2] = [half(a.r, b.r, 31), half(a.g, b.g, 63), half(a.b, b.b, 31)].map(|v| v as u8);
        (p, 3)
    }
}

fn distance(a: [u8; 3], b: [u8; 3]) -> u32 {
    a.iter().zip(&b).map(|(&x, &y)| sq(x, y)).sum()
}

/// The nearest usable palette entry of every valid pixel (the lowest index on a tie) and the
/// squared RGB error.
fn fit(pixels: &[[u8; 3]; BLOCK_PIXELS], valid: u16, c0: u16, c1: u16) -> (u32, u32) {
    let (p, usable) = palette(c0, c1);
    let mut error = 0;
    let mut indices = 0u32;
    for (i, &px) in pixels.iter().enumerate() {
        if !counts(valid, i) {
            continue;
        }
        let (k, e) = p
            .iter()
            .take(usable)
            .enumerate()
            .map(|(k, &q)| (k, distance(px, q)))
            .fold((0, u32::MAX), |best, c| if c.1 < best.1 { c } else { best });
        error += e;
        indices |= (k as u32) << (2 * i);
    }
    (error, indices)
}

/// The best single-colour match per 8-bit value: the endpoints (a, b) of `BITS` bits whose 1/3
/// point round((2a + b)·255/(3·max)) — or, for a = b, whose expansion — is nearest the value,
/// preferring a = b, then the smallest a, then the smallest b, when several are as near.
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time only (the statics below): an index out of bounds fails the build"
)]
const fn single<const BITS: u32>() -> [[u8; 2]; 256] {
    let max = (1 << BITS) - 1;
    // Every value some pair reaches exactly, with the first such pair in that order.
    let mut reached = [false; 256];
    let mut table = [[0u8; 2]; 256];
    let mut a = 0;
    while a <= max {
        let v = (if BITS == 5 { expand5(a) } else { expand6(a) }) as usize;
        if !reached[v] {
            reached[v] = true;
            table[v] = [a as u8, a as u8];
        }
        a += 1;
    }
    a = 0;
    while a <= max {
        let mut b = 0;
        while b <= max {
            let v = third(a, b, max) as usize;
            if !reached[v] {
                reached[v] = true;
                table[v] = [a as u8, b as u8];
            }
            b += 1;
        }
        a += 1;
    }
    // A value no pair reaches takes the nearest reached one's pair (the lower on a tie).
    let mut filled = table;
    let mut v = 0;
    while v < 256 {
        if !reached[v] {
            let mut d = 1;
            while d < 256 {
                if v >= d && reached[v - d] {
                    filled[v] = table[v - d];
                    break;
                }
                if v + d < 256 && reached[v + d] {
                    filled[v] = table[v + d];
                    break;
                }
                d += 1;
            }
        }
        v += 1;
    }
    filled
}

/// Single-colour endpoint pairs for the 5-bit channels (red, blue).
static SINGLE5: [[u8; 2]; 256] = single::<5>();
/// Single-colour endpoint pairs for the 6-bit channel (green).
static SINGLE6: [[u8; 2]; 256] = single::<6>();

/// The endpoints BC1 gives a block whose every pixel has 8-bit value `value` in a channel, as
/// `[five, six]`: the pair `[a, b]` for a 5-bit channel (red, blue) and for the 6-bit one (green)
/// (`a` = `b` where an endpoint expands to the value exactly; else the pair whose 1/3 point
/// comes closest).
/// For ports of this encoder that must write the same bytes (`nmat-wgpu` embeds the table in
/// its shader).
pub fn bc1_single_colour_endpoints(value: u8) -> [[u8; 2]; 2] {
    let pick = |table: &[[u8; 2]; 256]| table.get(usize::from(value)).copied().unwrap_or([0, 0]);
    [pick(&SINGLE5), pick(&SINGLE6)]
}

/// The block of one colour: per channel the pair from `SINGLE5`/`SINGLE6`, index 2 (the 1/3
/// point) for every pixel, or the endpoint itself where the pair is equal.
fn single_colour(c: [u8; 3], valid: u16) -> (u32, u16, u16, u32) {
    let ([[r0, r1], _], [_, [g0, g1]], [[b0, b1], _]) = (
        bc1_single_colour_endpoints(c[0]),
        bc1_single_colour_endpoints(c[1]),
        bc1_single_colour_endpoints(c[2]),
    );
    let a = Rgb565 { r: r0.into(), g: g0.into(), b: b0.into() }.bits();
    let b = Rgb565 { r: r1.into(), g: g1.into(), b: b1.into() }.bits();
    let pixels = [c; BLOCK_PIXELS];
    let (e1, i1) = fit(&pixels, valid, a, b);
    let (e2, i2) = fit(&pixels, valid, b, a);
    if e2 < e1 { (e2, b, a, i2) } else { (e1, a, b, i1) }
}

/// Least-squares endpoints (8-bit, unquantized) for the given indices of a 4-colour palette
/// (weights 1, 0, 2/3, 1/3 on `c0`), or `None` if every pixel has the same weight.
fn refine(pixels: &[[u8; 3]; BLOCK_PIXELS], valid: u16, indices: u32) -> Option<[[i32; 3]; 2]> {
    let (mut aa, mut bb, mut ab) = (0i64, 0i64, 0i64);
    let (mut x, mut y) = ([0i64; 3], [0i64; 3]);
    for (i, px) in pixels.iter().enumerate() {
        if !counts(valid, i) {
            continue;
        }
        let alpha: i64 = match (indices >> (2 * i)) & 3 {
            0 => 3,
            1 => 0,
            2 => 2,
            _ => 1,
        };
        let beta = 3 - alpha;
        aa += alpha * alpha;
        bb += beta * beta;
        ab += alpha * beta;
        for ((xc, yc), &v) in x.iter_mut().zip(y.iter_mut()).zip(px) {
            *xc += alpha * i64::from(v);
            *yc += beta * i64::from(v);
        }
    }
    let det = aa * bb - ab * ab;
    if det == 0 {
        return None;
    }
    // A·e0 + C·e1 = 3X and C·e0 + B·e1 = 3Y (A = Σα², B = Σβ², C = Σαβ; α, β in thirds).
    let solve = |num: i64| -> i32 {
        // num / det rounded to nearest (det > 0 as a Gram determinant of independent vectors).
        let q = (2 * num + det).div_euclid(2 * det);
        q.clamp(0, 255) as i32
    };
    let e0 = core::array::from_fn(|c| {
        let (xc, yc) = (x.get(c).copied().unwrap_or(0), y.get(c).copied().unwrap_or(0));
        solve(3 * (bb * xc - ab * yc))
    });
    let e1 = core::array::from_fn(|c| {
        let (xc, yc) = (x.get(c).copied().unwrap_or(0), y.get(c).copied().unwrap_or(0));
        solve(3 * (aa * yc - ab * xc))
    });
    Some([e0, e1])
}

/// The two pixels at the ends of the block's principal axis, or `None` if all valid pixels
/// are the same colour.
fn axis_ends(pixels: &[[u8; 3]; BLOCK_PIXELS], valid: u16) -> Option<([u8; 3], [u8; 3])> {
    let mut used = [[0u8; 3]; BLOCK_PIXELS];
    let mut points = [[0i64; 4]; BLOCK_PIXELS];
    let mut n = 0;
    for (_, p) in pixels.iter().enumerate().filter(|&(i, _)| counts(valid, i)) {
        if let (Some(u), Some(q)) = (used.get_mut(n), points.get_mut(n)) {
            *u = *p;
            *q = [p[0], p[1], p[2], 0].map(i64::from);
            n += 1;
        }
    }
    let (lo, hi) = principal_ends(points.get(..n)?, 3)?;
    let (lo, hi) = (*used.get(lo)?, *used.get(hi)?);
    (lo != hi).then_some((hi, lo))
}

/// Encodes one block of RGB pixels (see the module documentation of [`crate::bc`] for `valid`).
pub fn encode_bc1(pixels: &[[u8; 3]; BLOCK_PIXELS], valid: u16) -> [u8; 8] {
    let first = pixels.iter().enumerate().find(|&(i, _)| counts(valid, i)).map(|(_, &p)| p);
    let Some(first) = first else {
        return [0; 8];
    };
    let (_, c0, c1, indices) = match axis_ends(pixels, valid) {
        None => single_colour(first, valid),
        Some((hi, lo)) => {
            let widen = |c: [u8; 3]| c.map(i32::from);
            let mut best: Option<(u32, u16, u16, u32)> = None;
            let mut ends = [widen(hi), widen(lo)];
            for round in 0..3 {
                let (a, b) = (Rgb565::nearest(ends[0]).bits(), Rgb565::nearest(ends[1]).bits());
                // Both orders: (a, b) and (b, a) are the 4- and 3-colour palettes of the pair.
                let mut last = None;
                for (c0, c1) in [(a, b), (b, a)] {
                    let (error, indices) = fit(pixels, valid, c0, c1);
                    if best.is_none_or(|b| error < b.0) {
                        best = Some((error, c0, c1, indices));
                    }
                    if c0 > c1 {
                        last = Some(indices);
                    }
                }
                let Some(indices) = last.filter(|_| round < 2) else { break };
                let Some(next) = refine(pixels, valid, indices) else { break };
                ends = next;
            }
            best.unwrap_or((0, 0, 0, 0))
        }
    };
    let mut block = [0u8; 8];
    let (ends, bits) = block.split_at_mut(4);
    ends.copy_from_slice(&(u32::from(c0) | (u32::from(c1) << 16)).to_le_bytes());
    bits.copy_from_slice(&indices.to_le_bytes());
    block
}

/// Decodes one BC1 block into RGBA (alpha 255, or 0 for the transparent-black entry).
pub fn decode_bc1(block: &[u8; 8]) -> [[u8; 4]; BLOCK_PIXELS] {
    let word = u64::from_le_bytes(*block);
    let (c0, c1) = (word as u16, (word >> 16) as u16);
    let (p, usable) = palette(c0, c1);
    core::array::from_fn(|i| {
        let k = ((word >> (32 + 2 * i)) & 3) as usize;
        match p.get(k) {
            Some(&[r, g, b]) if k < usable => [r, g, b, 255],
            _ => [0, 0, 0, 0],
        }
    })
}

#[cfg(test)]
pub(super) fn tests_nearest(c: [u8; 3]) -> u16 {
    Rgb565::nearest(c.map(i32::from)).bits()
}

#[cfg(test)]
pub(super) fn tests_fit_error(pixels: &[[u8; 3]; BLOCK_PIXELS], c0: u16, c1: u16) -> u32 {
    fit(pixels, super::ALL_VALID, c0, c1).0
}
