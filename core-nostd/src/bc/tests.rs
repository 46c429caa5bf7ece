//! The block codecs' properties: exact where the format allows it, near the optimum elsewhere,
//! blind to pixels that do not exist, and opaque. (Agreement with an independent decoder is
//! tested in `tests/tests/bc.rs`.)

use super::*;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn byte(&mut self) -> u8 {
        (self.next() >> 56) as u8
    }
    /// A block like a texture's: a base value, a gradient and some noise, clamped (so sometimes
    /// touching 0 or 255), or a step; one in six pure noise.
    fn block(&mut self) -> [u8; 16] {
        let kind = self.next() % 6;
        self.block_of(kind)
    }

    /// [`Rng::block`] without the pure noise.
    fn texture_block(&mut self) -> [u8; 16] {
        let kind = 1 + self.next() % 5;
        self.block_of(kind)
    }

    fn block_of(&mut self, kind: u64) -> [u8; 16] {
        let base = i32::from(self.byte());
        let (gx, gy) = (i32::from(self.byte() % 32) - 16, i32::from(self.byte() % 32) - 16);
        let noise = i32::from(self.byte() % 24) + 1;
        core::array::from_fn(|i| {
            let (x, y) = ((i % 4) as i32, (i / 4) as i32);
            let n = i32::from(self.byte()) % noise - noise / 2;
            let v = match kind {
                0 => i32::from(self.byte()),
                1 => base + 60 * x + n - 100,
                _ => base + gx * x + gy * y + n,
            };
            v.clamp(0, 255) as u8
        })
    }
}

fn bc4_error(values: &[u8; 16], valid: u16, block: &[u8; 8]) -> u32 {
    let got = decode_bc4(block);
    (0..16).filter(|&i| counts(valid, i)).map(|i| sq(values[i], got[i])).sum()
}

/// The best BC4 error any endpoint pair reaches (every pair tried): the oracle.
fn bc4_optimum(values: &[u8; 16]) -> u32 {
    let mut best = u32::MAX;
    for a0 in 0..=255u8 {
        for a1 in 0..=255u8 {
            let p = bc4::tests_palette(a0, a1);
            let e: u32 = values.iter().map(|&v| p.iter().map(|&q| sq(v, q)).min().unwrap()).sum();
            best = best.min(e);
        }
    }
    best
}

#[test]
fn valid_masks_follow_the_image_edges() {
    assert_eq!(valid_mask(0, 0, 8, 8), ALL_VALID);
    assert_eq!(valid_mask(1, 1, 8, 8), ALL_VALID);
    assert_eq!(valid_mask(0, 0, 1, 1), 0b1);
    assert_eq!(valid_mask(0, 0, 3, 2), 0b0111_0111);
    assert_eq!(valid_mask(1, 0, 6, 5), 0b0011_0011_0011_0011);
    assert_eq!(valid_mask(1, 1, 6, 5), 0b0011);
    assert_eq!(valid_mask(2, 0, 6, 5), 0);
}

#[test]
fn bc4_is_exact_for_one_or_two_values_and_for_0_and_255() {
    for v in [0u8, 1, 127, 254, 255] {
        let block = encode_bc4(&[v; 16], ALL_VALID);
        assert_eq!(decode_bc4(&block), [v; 16], "constant {v}");
    }
    let mut rng = Rng(1);
    for _ in 0..500 {
        let (a, b) = (rng.byte(), rng.byte());
        let values: [u8; 16] =
            core::array::from_fn(|_| if rng.next().is_multiple_of(2) { a } else { b });
        assert_eq!(decode_bc4(&encode_bc4(&values, ALL_VALID)), values, "{a} {b}");
        // 0, 255 and two values between: the six-value palette holds all four.
        let (lo, hi) = (a.min(b).max(1), a.max(b).min(254));
        let four: [u8; 16] = core::array::from_fn(|i| [0, lo, hi, 255][i % 4]);
        assert_eq!(decode_bc4(&encode_bc4(&four, ALL_VALID)), four, "{lo} {hi}");
    }
}

/// The endpoint search against the best any pair of endpoints reaches (every pair tried): never
/// above twice it, and within 15 % overall on texture-like blocks (12 % when written; pure noise
/// is harder, and rare in textures).
#[test]
fn bc4_is_near_the_exhaustive_optimum() {
    let mut rng = Rng(7);
    let (mut ours, mut best) = (0u64, 0u64);
    for k in 0..48 {
        let values = if k % 4 == 0 { rng.block() } else { rng.texture_block() };
        let e = bc4_error(&values, ALL_VALID, &encode_bc4(&values, ALL_VALID));
        let o = bc4_optimum(&values);
        assert!(e <= 2 * o + 16, "error {e}, optimum {o}, block {values:?}");
        if k % 4 != 0 {
            ours += u64::from(e);
            best += u64::from(o);
        }
    }
    assert!(ours * 100 <= best * 115, "total error {ours}, optimum {best}");
}

/// Whatever endpoints the search picks, each pixel gets its nearest palette entry, and on a tie
/// (a value exactly between two entries) the smaller one, as the module says; checked against
/// the palette read from the block's own bytes.
#[test]
fn bc4_pixels_take_the_nearest_entry_the_smaller_on_a_tie() {
    let mut rng = Rng(11);
    let mut ties = 0;
    for _ in 0..3000 {
        let values = rng.block();
        let block = encode_bc4(&values, ALL_VALID);
        let palette = bc4::tests_palette(block[0], block[1]);
        let decoded = decode_bc4(&block);
        for (&v, &got) in values.iter().zip(&decoded) {
            let nearest = palette.iter().map(|&q| sq(v, q)).min().unwrap();
            let mut candidates = palette.iter().filter(|&&q| sq(v, q) == nearest);
            let want = *candidates.clone().min().unwrap();
            ties += usize::from(candidates.any(|&q| q != want));
            assert_eq!(got, want, "value {v}, endpoints {} {}", block[0], block[1]);
        }
    }
    assert!(ties > 200, "only {ties} ties: the test needs more of them");
}

/// Pixels outside the image do not change the block, and get index 0.
#[test]
fn invalid_pixels_are_ignored() {
    let mut rng = Rng(3);
    for _ in 0..200 {
        let valid = (rng.next() as u16) | 1;
        let a = rng.block();
        let mut b = rng.block();
        for i in (0..16).filter(|&i| counts(valid, i)) {
            b[i] = a[i];
        }
        let (ea, eb) = (encode_bc4(&a, valid), encode_bc4(&b, valid));
        assert_eq!(ea, eb);
        let bits = u64::from_le_bytes(ea) >> 16;
        for i in (0..16).filter(|&i| !counts(valid, i)) {
            assert_eq!((bits >> (3 * i)) & 7, 0, "pixel {i}");
        }
        let rgb = |v: &[u8; 16]| -> [[u8; 3]; 16] {
            core::array::from_fn(|i| [v[i], v[(i + 5) % 16], 255 - v[i]])
        };
        let (mut ca, cb) = (rgb(&a), rgb(&b));
        // Only the valid pixels of the RGB blocks must agree: copy them over.
        for i in (0..16).filter(|&i| !counts(valid, i)) {
            ca[i] = [rng.byte(), rng.byte(), rng.byte()];
        }
        let mut cb2 = cb;
        for i in (0..16).filter(|&i| counts(valid, i)) {
            cb2[i] = ca[i];
        }
        assert_eq!(encode_bc1(&ca, valid), encode_bc1(&cb2, valid));
    }
    assert_eq!(encode_bc4(&[9; 16], 0), [0; 8]);
    assert_eq!(encode_bc1(&[[9; 3]; 16], 0), [0; 8]);
}

fn bc1_error(pixels: &[[u8; 3]; 16], block: &[u8; 8]) -> u32 {
    let got = decode_bc1(block);
    pixels.iter().zip(&got).map(|(p, q)| (0..3).map(|c| sq(p[c], q[c])).sum::<u32>()).sum()
}

/// A block of one colour decodes to within the best any endpoint pair reaches per channel
/// (checked against every pair), and opaque.
#[test]
fn bc1_single_colours_are_as_close_as_the_format_allows() {
    let best = |v: u8, max: u32| -> u32 {
        let expand = |a: u32| (a * 255 * 2 + max) / (2 * max);
        let mut best = u32::MAX;
        for a in 0..=max {
            for b in 0..=max {
                let exact = (2.0 * expand_exact(a, max) + expand_exact(b, max)) / 3.0;
                let third = libm::floor(exact + 0.5) as u32;
                best = best.min(third.abs_diff(u32::from(v))).min(expand(a).abs_diff(u32::from(v)));
            }
        }
        best
    };
    for v in 0..=255u8 {
        let (r5, g6) = (best(v, 31), best(v, 63));
        let block = encode_bc1(&[[v, v, v]; 16], ALL_VALID);
        for px in decode_bc1(&block) {
            assert_eq!(px[3], 255);
            assert!(u32::from(px[0].abs_diff(v)) <= r5, "red {v}: {px:?}");
            assert!(u32::from(px[1].abs_diff(v)) <= g6, "green {v}: {px:?}");
            assert!(u32::from(px[2].abs_diff(v)) <= r5, "blue {v}: {px:?}");
        }
    }
}

/// v·255/max as a real number (in f64, for the oracle above).
fn expand_exact(v: u32, max: u32) -> f64 {
    f64::from(v) * 255.0 / f64::from(max)
}

/// Two colours that are exact 5:6:5 values decode exactly.
#[test]
fn bc1_is_exact_for_two_565_colours() {
    let mut rng = Rng(11);
    for _ in 0..500 {
        let colour = |rng: &mut Rng| {
            let (r, g, b) =
                (rng.byte() as u32 % 32, rng.byte() as u32 % 64, rng.byte() as u32 % 32);
            [((r * 510 + 31) / 62) as u8, ((g * 510 + 63) / 126) as u8, ((b * 510 + 31) / 62) as u8]
        };
        let (a, b) = (colour(&mut rng), colour(&mut rng));
        let pixels: [[u8; 3]; 16] = core::array::from_fn(|i| if i % 3 == 0 { a } else { b });
        assert_eq!(bc1_error(&pixels, &encode_bc1(&pixels, ALL_VALID)), 0, "{a:?} {b:?}");
    }
}

/// On texture-like blocks the encoder beats the plain one (the luminance extremes as endpoints)
/// by a clear margin overall, never uses transparent black, and fits its palette's best indices.
#[test]
fn bc1_beats_the_plain_endpoints_and_stays_opaque() {
    let mut rng = Rng(5);
    let (mut ours, mut plain) = (0u64, 0u64);
    for _ in 0..3000 {
        let (r, g, b) = (rng.block(), rng.block(), rng.block());
        let mix = rng.next() % 3;
        let pixels: [[u8; 3]; 16] = core::array::from_fn(|i| match mix {
            // Correlated channels, as in most albedo.
            0 => [r[i], r[i].saturating_add(g[i] / 8), r[i] / 2 + b[i] / 4],
            _ => [r[i], g[i], b[i]],
        });
        let block = encode_bc1(&pixels, ALL_VALID);
        assert!(decode_bc1(&block).iter().all(|p| p[3] == 255), "transparent: {pixels:?}");
        ours += u64::from(bc1_error(&pixels, &block));
        let luma = |p: &[u8; 3]| 2 * u32::from(p[0]) + 5 * u32::from(p[1]) + u32::from(p[2]);
        let hi = *pixels.iter().max_by_key(|p| luma(p)).unwrap();
        let lo = *pixels.iter().min_by_key(|p| luma(p)).unwrap();
        let q = |c: [u8; 3]| bc1::tests_nearest(c);
        let (c0, c1) = (q(hi).max(q(lo)), q(hi).min(q(lo)));
        plain += u64::from(bc1::tests_fit_error(&pixels, c0, c1));
    }
    // 0.612 of the plain endpoints' error on 2026-12-04; 0.84 without the least-squares
    // refinement, 0.70–0.77 with its sums broken (mutants).
    assert!(ours * 100 < plain * 65, "ours {ours}, plain {plain}");
}

#[test]
fn bc1_three_colour_blocks_decode_index_3_as_transparent_black() {
    // c0 = c1 = white (0xFFFF): the 3-colour palette; indices 0, 1, 2, 3.
    let block = [0xFF, 0xFF, 0xFF, 0xFF, 0b1110_0100, 0, 0, 0];
    let px = decode_bc1(&block);
    assert_eq!(
        &px[..4],
        &[[255, 255, 255, 255], [255, 255, 255, 255], [255, 255, 255, 255], [0, 0, 0, 0]]
    );
}

#[test]
fn bc5_is_two_bc4_blocks() {
    let mut rng = Rng(9);
    for _ in 0..100 {
        let (r, g) = (rng.block(), rng.block());
        let block = encode_bc5(&r, &g, ALL_VALID);
        assert_eq!(block[..8], encode_bc4(&r, ALL_VALID));
        assert_eq!(block[8..], encode_bc4(&g, ALL_VALID));
        let (dr, dg) = decode_bc5(&block);
        assert_eq!(dr, decode_bc4(&encode_bc4(&r, ALL_VALID)));
        assert_eq!(dg, decode_bc4(&encode_bc4(&g, ALL_VALID)));
    }
}

/// Squared RGB(A) error of a BC7 block against the pixels it encodes.
fn bc7_error(pixels: &[[u8; 4]; 16], valid: u16, block: &[u8; 16], comps: usize) -> u32 {
    let got = decode_bc7(block);
    (0..16)
        .filter(|&i| counts(valid, i))
        .map(|i| (0..comps).map(|c| sq(pixels[i][c], got[i][c])).sum::<u32>())
        .sum()
}

fn rgba_block(rng: &mut Rng) -> [[u8; 4]; 16] {
    let (r, g, b) = (rng.texture_block(), rng.texture_block(), rng.block());
    core::array::from_fn(|i| [r[i], g[i], b[i], 255])
}

/// BC7 beats BC1 on every texture-like block (it has every BC1 palette's precision and more)
/// and by far on the sum; RGB blocks decode opaque.
#[test]
fn bc7_is_better_than_bc1_and_opaque() {
    let mut rng = Rng(0xB7);
    let (mut e1, mut e7) = (0u64, 0u64);
    for _ in 0..2000 {
        let px = rgba_block(&mut rng);
        let rgb = px.map(|[r, g, b, _]| [r, g, b]);
        let b1 = decode_bc1(&encode_bc1(&rgb, ALL_VALID));
        let one: u32 = (0..16).map(|i| (0..3).map(|c| sq(px[i][c], b1[i][c])).sum::<u32>()).sum();
        let block = encode_bc7(&px, ALL_VALID, false);
        let seven = bc7_error(&px, ALL_VALID, &block, 3);
        assert!(seven <= one, "BC7 {seven} > BC1 {one} on {px:?}");
        assert!(decode_bc7(&block).iter().all(|p| p[3] == 255));
        e1 += u64::from(one);
        e7 += u64::from(seven);
    }
    assert!(e7 * 4 < e1, "BC7 total {e7}, BC1 {e1}");
}

/// One colour: within a code per channel (7-bit endpoints with a p-bit reach every even or odd
/// value, interpolation the rest), in RGB and with alpha.
#[test]
fn bc7_single_colours_are_near_exact() {
    let mut rng = Rng(5);
    for _ in 0..500 {
        let c = [rng.byte(), rng.byte(), rng.byte(), rng.byte()];
        let got = decode_bc7(&encode_bc7(&[c; 16], ALL_VALID, true));
        for p in got {
            for k in 0..4 {
                assert!(p[k].abs_diff(c[k]) <= 1, "{c:?} -> {p:?}");
            }
        }
    }
}

/// Alpha is kept with `alpha` (modes 5 and 6) and ignored without; pixels outside `valid`
/// change nothing.
#[test]
fn bc7_alpha_and_invalid_pixels() {
    let mut rng = Rng(77);
    let (mut seven, mut split) = (0u64, 0u64);
    for _ in 0..500 {
        let a = rng.texture_block();
        let mut px = rgba_block(&mut rng);
        px.iter_mut().zip(a).for_each(|(p, a)| p[3] = a);
        let block = encode_bc7(&px, ALL_VALID, true);
        seven += u64::from(bc7_error(&px, ALL_VALID, &block, 4));
        // The same 16 bytes as BC1 for the colour and BC4 for the alpha.
        let b1 = decode_bc1(&encode_bc1(&px.map(|[r, g, b, _]| [r, g, b]), ALL_VALID));
        let b4 = decode_bc4(&encode_bc4(&a, ALL_VALID));
        split += (0..16)
            .map(|i| (0..3).map(|c| sq(px[i][c], b1[i][c])).sum::<u32>() + sq(a[i], b4[i]))
            .map(u64::from)
            .sum::<u64>();
        let valid = 0b0000_0110_0110_0000;
        let mut other = px;
        for (i, p) in other.iter_mut().enumerate() {
            if !counts(valid, i) {
                *p = [1, 2, 3, 4];
            }
        }
        assert_eq!(encode_bc7(&px, valid, true), encode_bc7(&other, valid, true));
        assert_eq!(encode_bc7(&px, valid, false), encode_bc7(&other, valid, false));
        // Opaque where it counts, transparent elsewhere: the block of an RGB texture.
        let mut hidden = px.map(|[r, g, b, _]| [r, g, b, 255]);
        let rgb = encode_bc7(&hidden, valid, false);
        hidden
            .iter_mut()
            .enumerate()
            .filter(|&(i, _)| !counts(valid, i))
            .for_each(|(_, p)| p[3] = 0);
        assert_eq!(encode_bc7(&hidden, valid, true), rgb);
    }
    assert!(seven < split, "BC7 with alpha {seven}, BC1 + BC4 {split}");
}

/// The principal axis's ends are the extreme points of a set spread along one direction, far
/// from the origin and in any order (the covariance is centred on the mean), and only the first
/// `dims` coordinates count (BC1 and BC7 RGB pass 3 with alpha in the fourth). Which end comes
/// first follows the axis's sign, which the encoders do not rely on.
#[test]
fn principal_ends_are_the_extremes_along_the_spread() {
    let ends =
        |points: &[[i64; 4]], dims| principal_ends(points, dims).map(|(a, b)| (a.min(b), a.max(b)));
    // Along (1, −1, 0) around (200, 200, 200): every point has the same sum, the mean's
    // direction, and the ends are points 1 (t = 6) and 3 (t = −5).
    let t = [0i64, 6, 2, -5, 1, -3, 4];
    let points: [[i64; 4]; 7] =
        core::array::from_fn(|i| [200 + 9 * t[i], 200 - 9 * t[i], 200, (i as i64 * 97) % 256]);
    assert_eq!(ends(&points, 3), Some((1, 3)));
    // The fourth coordinate (spread more than the others, in another order) counts at 4 dims.
    let alpha = points.map(|[r, g, b, a]| [r, g, b, a * 4]);
    assert_eq!(ends(&alpha, 3), Some((1, 3)));
    // Alpha 4 · (97 · i mod 256): 0 at point 0, 916 at point 5, the next 140 away.
    assert_eq!(ends(&alpha, 4), Some((0, 5)));
    // No spread: none.
    assert_eq!(principal_ends(&[[7, 7, 7, 0]; 5], 3), None);
}

/// BC7's endpoint quantizer picks, for every 8-bit target and every precision the encoder
/// uses (4–8 bits, with and without a p-bit of either value), a stored value whose expansion
/// is as near the target as any: checked against every stored value, expanded as the format
/// defines it (the `n`-bit pattern repeated from its top bit until 8 bits are filled).
#[test]
fn bc7_endpoints_quantize_to_the_nearest_expansion() {
    let widened = |v: u32, n: u32| -> u32 {
        (0..8).fold(0, |acc, j| (acc << 1) | ((v >> (n - 1 - j % n)) & 1))
    };
    for bits in 4..=8u32 {
        for (pbit, choices) in [(false, &[0u32][..]), (true, &[0, 1][..])] {
            let n = bits + u32::from(pbit);
            if n > 8 {
                continue;
            }
            for &p in choices {
                let reach = || (0..1u32 << bits).map(|q| widened((q << u32::from(pbit)) | p, n));
                for target in -3..=258i32 {
                    let t = target.clamp(0, 255) as u32;
                    let best = reach().map(|v| v.abs_diff(t)).min().unwrap();
                    let got = bc7::tests_quantized(bits, pbit, p, target);
                    assert!(reach().any(|v| v == got), "{bits} bits, p-bit {pbit} {p}: {got}");
                    assert_eq!(got.abs_diff(t), best, "{bits} bits, p-bit {pbit} {p}, {target}");
                }
            }
        }
    }
}

/// BC7 ranks the partitions of each mode by the error of one colour per subset and encodes the
/// best few in full: against its own search with every partition of modes 0–3 added in full, on
/// texture-like blocks (RGB; some with a sharp edge, whose subsets matter most).
#[test]
fn bc7_partitions_ranked_are_near_every_partition_tried() {
    let mut rng = Rng(0xB77);
    let (mut ours, mut every) = (0u64, 0u64);
    for k in 0..200 {
        let mut px = rgba_block(&mut rng);
        if k % 2 == 0 {
            // An edge: another colour beyond a line through the block.
            let (c, slope) = ([rng.byte(), rng.byte(), rng.byte(), 255], rng.next() % 5);
            for (i, p) in px.iter_mut().enumerate() {
                if (i % 4) as u64 * 2 + (i / 4) as u64 * slope > 5 {
                    *p = c;
                }
            }
        }
        let e = bc7_error(&px, ALL_VALID, &encode_bc7(&px, ALL_VALID, false), 3);
        let o = bc7::tests_every_partition_error(&px, ALL_VALID);
        ours += u64::from(e);
        every += o;
        assert!(u64::from(e) >= o, "every partition tried is the larger search: {px:?}");
    }
    // 1.30 (2026-12-04, with modes 0, 4 and 5; partitions 0–3 alone, unranked: 1.46; before
    // modes 0, 4 and 5 were searched, 1.56 and 1.79). The ranking misses the best partition of
    // many blocks, mostly in modes 2 and 3, which encode only the best two — a lead for the
    // search, which the GPU's encoder would have to follow byte for byte. The bound holds the
    // ranking to today's.
    assert!(ours * 100 <= every * 140, "ranked {ours}, every partition {every}");
}

/// Blocks for the BC7 index tests: texture-like RGB, flat, and with alpha, some with pixels
/// outside the texture.
fn bc7_test_blocks() -> impl Iterator<Item = ([[u8; 4]; 16], u16, bool)> {
    let mut rng = Rng(0xB7B7);
    (0..600).map(move |k| {
        let mut px = rgba_block(&mut rng);
        if k % 3 == 1 {
            let a = rng.texture_block();
            px.iter_mut().zip(a).for_each(|(p, a)| p[3] = a);
        }
        if k % 7 == 0 {
            let c = px[0];
            px.iter_mut().for_each(|p| *p = c);
        }
        let valid = if k % 5 == 0 { valid_mask((k % 2) as u32, 0, 6, 7) } else { ALL_VALID };
        (px, valid, k % 3 != 0)
    })
}

/// The squared error the encoder's search computed for the block it chose is the block's
/// error as decoded: the palette it measured candidates on (endpoints expanded with their
/// p-bits, interpolated) is the decoder's, for every mode it writes.
#[test]
fn bc7_search_measures_the_block_it_writes() {
    let mut modes = [0u32; 8];
    let mut seen = [[false; 2]; 4];
    for (px, valid, alpha) in bc7_test_blocks() {
        let (block, claimed) = bc7::tests_encode(&px, valid, alpha);
        let comps = if alpha { 4 } else { 3 };
        assert_eq!(u64::from(bc7_error(&px, valid, &block, comps)), claimed, "{px:?} {valid:#x}");
        let mode = block[0].trailing_zeros() as usize;
        modes[mode] += 1;
        // Modes 4 and 5: the rotation (2 bits after the mode's) and mode 4's selector bit.
        if mode == 4 || mode == 5 {
            let fields = u32::from(block[0]) >> (mode + 1);
            let rotation = (fields & 3) as usize;
            let selector = if mode == 4 { (fields >> 2) & 1 } else { 0 };
            seen[rotation][selector as usize] = true;
        }
    }
    // Every mode the encoder writes was met: 0–6 (not 7), and modes 4 and 5 with each
    // channel rotated into the alpha slot (and mode 5 without, for alpha), mode 4 with both
    // selectors.
    for m in 0..7 {
        assert!(modes[m] > 0, "mode {m} never chosen: {modes:?}");
    }
    assert!(seen[1..].iter().flatten().all(|&s| s) && seen[0][0], "{seen:?}");
}

/// Every pixel of a BC7 block takes the palette entry nearest it: no other index (written into
/// the block's bits and decoded) brings that pixel nearer. The index fields are the block's last
/// bits (Table.M: 2–4 bits a pixel, one fewer at each subset's anchor; mode 5's alpha indices
/// last), so this asks only the decoder.
#[test]
fn bc7_pixels_take_their_nearest_palette_entry() {
    let mut changed = 0u32;
    for (px, valid, alpha) in bc7_test_blocks() {
        let block = encode_bc7(&px, valid, alpha);
        let mode = block[0].trailing_zeros();
        // (subsets, partition bits, index bits, secondary index bits) of the modes written.
        let (subsets, partition_bits, ib, ib2) = match mode {
            0 => (3, 4, 3, 0),
            1 => (2, 6, 3, 0),
            2 => (3, 6, 2, 0),
            3 => (2, 6, 2, 0),
            4 => (1, 0, 2, 3),
            5 => (1, 0, 2, 2),
            6 => (1, 0, 4, 0),
            _ => panic!("mode {mode} written"),
        };
        let word = u128::from_le_bytes(block);
        let partition = ((word >> (mode + 1)) & ((1 << partition_bits) - 1)) as usize;
        let anchors = bc7::tests_anchors(subsets, partition);
        // (pixel, first bit, bits) of every index field, in the block's order.
        let mut fields = [(0usize, 0u32, 0u32); 32];
        let mut count = 0;
        let mut at = 128 - (16 * ib - subsets as u32) - if ib2 > 0 { 16 * ib2 - 1 } else { 0 };
        for (bits, first) in [(ib, &anchors[..subsets]), (ib2, &[0][..])] {
            for i in (0..16).filter(|_| bits > 0) {
                let n = bits - u32::from(first.contains(&i));
                fields[count] = (i, at, n);
                count += 1;
                at += n;
            }
        }
        assert_eq!(at, 128, "mode {mode}");
        let comps = if alpha { 4 } else { 3 };
        let err = |b: u128, i: usize| -> u32 {
            let got = decode_bc7(&b.to_le_bytes())[i];
            (0..comps).map(|c| sq(px[i][c], got[c])).sum()
        };
        for &(i, at, n) in fields[..count].iter().filter(|&&(i, _, _)| counts(valid, i)) {
            let now = err(word, i);
            for k in 0..1u128 << n {
                let other = (word & !(((1 << n) - 1) << at)) | (k << at);
                assert!(err(other, i) >= now, "pixel {i}, index {k} of mode {mode}: {px:?}");
                changed += u32::from(other != word);
            }
        }
    }
    assert!(changed > 10_000, "{changed} other indices tried");
}
