//! GPU block compression: encoders and decoders for the BC formats engines sample with hardware
//! filtering (BC1 for RGB, BC4 for one channel, BC5 for two, BC7 for RGB or RGBA at higher
//! quality), so a material decoded at load time
//! can be handed to an unchanged shader as an ordinary block-compressed texture.
//!
//! Every function works on one 4×4 block: `no_std`, no allocation, and integer arithmetic only,
//! so the bytes written are the same on every machine. Pixels are in row-major order
//! (`4·y + x`); `valid` has bit `i` set for the pixels that exist — a block at the right or bottom
//! edge of an image whose size is not a multiple of 4 has pixels past the edge, which GPUs never
//! show, and the encoders ignore them (they get index 0).
//!
//! The decoders define each palette entry as the exactly rounded value of the ideal interpolation
//! (e.g. BC4's (6·a0 + a1)/7 rounded to nearest, BC1's 5- and 6-bit endpoints expanded to
//! round(v·255/31) and round(v·255/63)): the values Direct3D's block-compression rules describe
//! and well-kept software decoders (`bcdec`) produce; GPUs may differ from them by a code on
//! interpolated BC1 colours.
//!
//! Which file holds what: `bc1.rs` (BC1: principal-axis endpoints, least-squares refinement,
//! exact single-colour matches), `bc4.rs` (BC4 and BC5: endpoint search in both palette modes),
//! `bc7.rs` (BC7: the decoder for every mode, the encoder in modes 0–6),
//! `layout.rs` (which material channels go into which BC texture). Whole regions of a material
//! are transcoded by `Decoder::transcode_blocks` (feature `alloc`).
//!
//! Quality and speed against reference encoders are measured by `nmat-bc` (the `bench` crate)
//! and reported in docs/TRANSCODING.md.

mod bc1;
mod bc4;
mod bc7;
mod layout;

pub use bc1::{bc1_single_colour_endpoints, decode_bc1, encode_bc1};
pub use bc4::{decode_bc4, decode_bc5, encode_bc4, encode_bc5};
pub use bc7::{decode_bc7, encode_bc7};
pub use layout::{
    BcFormat, BcTexture, MapChannels, auto_textures, default_layout, layout_with, maps, textures_in,
};

/// Pixels of a block.
pub const BLOCK_PIXELS: usize = 16;

/// Every pixel of a block exists.
pub const ALL_VALID: u16 = u16::MAX;

/// The pixels of a block at `(bx, by)` (in blocks) that lie inside an image of
/// `width` × `height` pixels, as a `valid` mask.
pub fn valid_mask(bx: u32, by: u32, width: u32, height: u32) -> u16 {
    let cols = width.saturating_sub(4 * bx).min(4);
    let rows = height.saturating_sub(4 * by).min(4);
    let row = (1u16 << cols) - 1;
    (0..rows).fold(0, |mask, y| mask | (row << (4 * y)))
}

/// Encodes one block of `format` from RGBA pixels (BC1 and BC7 RGB read R, G, B; BC4 R; BC5 R
/// and G) into the first `format.block_bytes()` bytes of `out` (nothing if `out` is shorter).
pub fn encode_block(
    format: BcFormat,
    pixels: &[[u8; 4]; BLOCK_PIXELS],
    valid: u16,
    out: &mut [u8],
) {
    let channel = |c: usize| -> [u8; BLOCK_PIXELS] {
        core::array::from_fn(|i| pixels.get(i).and_then(|p| p.get(c)).copied().unwrap_or(0))
    };
    let Some(dst) = out.get_mut(..format.block_bytes()) else { return };
    match format {
        BcFormat::Bc1 => {
            dst.copy_from_slice(&encode_bc1(&pixels.map(|[r, g, b, _]| [r, g, b]), valid))
        }
        BcFormat::Bc4 => dst.copy_from_slice(&encode_bc4(&channel(0), valid)),
        BcFormat::Bc5 => dst.copy_from_slice(&encode_bc5(&channel(0), &channel(1), valid)),
        BcFormat::Bc7Rgb => dst.copy_from_slice(&encode_bc7(pixels, valid, false)),
        BcFormat::Bc7Rgba => dst.copy_from_slice(&encode_bc7(pixels, valid, true)),
    }
}

/// Decodes one block of `format` (its first `format.block_bytes()` bytes; missing bytes read as
/// 0) into RGBA pixels: BC1's and BC7's colours and alpha, BC4 in R, BC5 in R and G (the other
/// components 0, alpha 255).
pub fn decode_block(format: BcFormat, block: &[u8]) -> [[u8; 4]; BLOCK_PIXELS] {
    let bytes = |from: usize| -> [u8; 8] {
        core::array::from_fn(|k| block.get(from + k).copied().unwrap_or(0))
    };
    match format {
        BcFormat::Bc1 => decode_bc1(&bytes(0)),
        BcFormat::Bc4 => decode_bc4(&bytes(0)).map(|v| [v, 0, 0, 255]),
        BcFormat::Bc5 => {
            let (r, g) = (decode_bc4(&bytes(0)), decode_bc4(&bytes(8)));
            core::array::from_fn(|i| {
                [r.get(i).copied().unwrap_or(0), g.get(i).copied().unwrap_or(0), 0, 255]
            })
        }
        BcFormat::Bc7Rgb | BcFormat::Bc7Rgba => {
            decode_bc7(&core::array::from_fn(|k| block.get(k).copied().unwrap_or(0)))
        }
    }
}

/// The indices (into `points`) of the points at the low and the high end of their principal axis
/// (power iteration on the integer covariance of the first `dims` coordinates, from the
/// covariance row of the widest coordinate), or `None` when the points do not spread (all equal,
/// or none). The first point wins a tie at the low end, the last at the high end.
fn principal_ends(points: &[[i64; 4]], dims: usize) -> Option<(usize, usize)> {
    let n = points.len() as i64;
    let mut sum = [0i64; 4];
    for p in points {
        for (s, &v) in sum.iter_mut().zip(p).take(dims) {
            *s += v;
        }
    }
    // Deviations scaled by n (integers): d = n·p − Σp.
    let dev = |p: &[i64; 4]| -> [i64; 4] {
        core::array::from_fn(|c| {
            if c < dims {
                n * p.get(c).copied().unwrap_or(0) - sum.get(c).copied().unwrap_or(0)
            } else {
                0
            }
        })
    };
    let mut cov = [[0i64; 4]; 4];
    for p in points {
        let d = dev(p);
        for (row, &dr) in cov.iter_mut().zip(&d) {
            for (cell, &dc) in row.iter_mut().zip(&d) {
                *cell += dr * dc;
            }
        }
    }
    let widest =
        (0..dims).max_by_key(|&c| cov.get(c).and_then(|r| r.get(c)).copied().unwrap_or(0))?;
    // v scaled down (arithmetic shift) to below 2^16, or `None` if it is zero.
    let small = |v: [i64; 4]| -> Option<[i64; 4]> {
        let scale = v.iter().map(|c| c.unsigned_abs()).max().filter(|&s| s != 0)?;
        let shift = (64 - scale.leading_zeros()).saturating_sub(16);
        Some(v.map(|c| c >> shift))
    };
    let mut v = cov.get(widest).copied().unwrap_or([0; 4]);
    for _ in 0..8 {
        let s = small(v)?;
        v = cov.map(|row| row.iter().zip(&s).map(|(a, b)| a * b).sum());
    }
    let v = small(v)?;
    let project = |p: &[i64; 4]| -> i64 { dev(p).iter().zip(&v).map(|(a, b)| a * b).sum() };
    let lo = points.iter().enumerate().min_by_key(|(_, p)| project(p))?.0;
    let hi = points.iter().enumerate().max_by_key(|(_, p)| project(p))?.0;
    Some((lo, hi))
}

/// `(a − b)²` of two codes.
fn sq(a: u8, b: u8) -> u32 {
    let d = u32::from(a.abs_diff(b));
    d * d
}

/// Whether pixel `i` counts.
fn counts(valid: u16, i: usize) -> bool {
    (valid >> i) & 1 != 0
}

#[cfg(test)]
mod tests;
