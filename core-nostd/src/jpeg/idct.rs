//! The 8×8 inverse DCT of indexed JPEG streams (docs/FORMAT.md §11.4): the integer
//! Loeffler–Ligtenberg–Moschytz factorisation with 13-bit constants and 2 extra bits between the
//! passes, the "islow" method of the IJG decoder (`djpeg -dct int`). Every operation wraps in 32
//! bits, so any coefficients give a defined result (conforming streams never wrap).

/// round(x · 2^13) of the rotation constants.
const C0_298: i32 = 2446;
const C0_390: i32 = 3196;
const C0_541: i32 = 4433;
const C0_765: i32 = 6270;
const C0_899: i32 = 7373;
const C1_175: i32 = 9633;
const C1_501: i32 = 12299;
const C1_847: i32 = 15137;
const C1_961: i32 = 16069;
const C2_053: i32 = 16819;
const C2_562: i32 = 20995;
const C3_072: i32 = 25172;

/// One 1-D pass over `x` (8 inputs); outputs scaled by 2^13, not yet rounded.
#[inline(always)]
fn pass(x: [i32; 8]) -> [i32; 8] {
    let [x0, x1, x2, x3, x4, x5, x6, x7] = x;
    // Even part.
    let z1 = x2.wrapping_add(x6).wrapping_mul(C0_541);
    let t2 = z1.wrapping_add(x6.wrapping_mul(-C1_847));
    let t3 = z1.wrapping_add(x2.wrapping_mul(C0_765));
    let t0 = x0.wrapping_add(x4).wrapping_shl(13);
    let t1 = x0.wrapping_sub(x4).wrapping_shl(13);
    let (e10, e13) = (t0.wrapping_add(t3), t0.wrapping_sub(t3));
    let (e11, e12) = (t1.wrapping_add(t2), t1.wrapping_sub(t2));
    // Odd part.
    let (z1, z2) = (x7.wrapping_add(x1), x5.wrapping_add(x3));
    let (z3, z4) = (x7.wrapping_add(x3), x5.wrapping_add(x1));
    let z5 = z3.wrapping_add(z4).wrapping_mul(C1_175);
    let z1 = z1.wrapping_mul(-C0_899);
    let z2 = z2.wrapping_mul(-C2_562);
    let z3 = z3.wrapping_mul(-C1_961).wrapping_add(z5);
    let z4 = z4.wrapping_mul(-C0_390).wrapping_add(z5);
    let o0 = x7.wrapping_mul(C0_298).wrapping_add(z1).wrapping_add(z3);
    let o1 = x5.wrapping_mul(C2_053).wrapping_add(z2).wrapping_add(z4);
    let o2 = x3.wrapping_mul(C3_072).wrapping_add(z2).wrapping_add(z3);
    let o3 = x1.wrapping_mul(C1_501).wrapping_add(z1).wrapping_add(z4);
    [
        e10.wrapping_add(o3),
        e11.wrapping_add(o2),
        e12.wrapping_add(o1),
        e13.wrapping_add(o0),
        e13.wrapping_sub(o0),
        e12.wrapping_sub(o1),
        e11.wrapping_sub(o2),
        e10.wrapping_sub(o3),
    ]
}

/// `(v + 2^(n−1)) >> n` in wrapping arithmetic.
#[inline(always)]
fn descale(v: i32, n: u32) -> i32 {
    v.wrapping_add(1 << (n - 1)) >> n
}

/// Dequantized coefficients (row-major: `c[8·v + u]`, v the vertical frequency) to samples
/// (row-major), each `clamp(value + 128, 0, 255)`.
pub(crate) fn idct(c: &[i32; 64], out: &mut [u8; 64]) {
    let mut ws = [0i32; 64];
    for col in 0..8 {
        let column = core::array::from_fn(|k| c.get(8 * k + col).copied().unwrap_or(0));
        for (k, v) in pass(column).into_iter().enumerate() {
            if let Some(w) = ws.get_mut(8 * k + col) {
                *w = descale(v, 11);
            }
        }
    }
    for (row, samples) in ws.chunks_exact(8).zip(out.chunks_exact_mut(8)) {
        let x = core::array::from_fn(|k| row.get(k).copied().unwrap_or(0));
        for (s, v) in samples.iter_mut().zip(pass(x)) {
            *s = descale(v, 18).wrapping_add(128).clamp(0, 255) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The float IDCT of JPEG (ITU T.81 A.3.3), rounded and clamped.
    fn float_idct(c: &[i32; 64]) -> [u8; 64] {
        let mut out = [0u8; 64];
        for y in 0..8 {
            for x in 0..8 {
                let mut s = 0.0f64;
                for v in 0..8 {
                    for u in 0..8 {
                        let cu = if u == 0 { core::f64::consts::FRAC_1_SQRT_2 } else { 1.0 };
                        let cv = if v == 0 { core::f64::consts::FRAC_1_SQRT_2 } else { 1.0 };
                        let pi = core::f64::consts::PI;
                        s += cu
                            * cv
                            * f64::from(c[8 * v + u])
                            * libm::cos((2 * x + 1) as f64 * u as f64 * pi / 16.0)
                            * libm::cos((2 * y + 1) as f64 * v as f64 * pi / 16.0);
                    }
                }
                out[8 * y + x] = libm::round(s / 4.0 + 128.0).clamp(0.0, 255.0) as u8;
            }
        }
        out
    }

    #[test]
    fn a_dc_block_is_flat_and_exact() {
        for dc in [-1024, -8, -1, 0, 1, 7, 8, 100, 1016, 2000] {
            let mut c = [0i32; 64];
            c[0] = dc;
            let mut out = [0u8; 64];
            idct(&c, &mut out);
            let want = (f64::from(dc) / 8.0 + 128.0).round().clamp(0.0, 255.0) as u8;
            // The integer path rounds dc/8 half up: (dc·4 + 16) >> 5.
            let exact = ((dc * 4 + 16) >> 5).wrapping_add(128).clamp(0, 255) as u8;
            assert!(out.iter().all(|&s| s == exact), "dc {dc}: {out:?}");
            assert!(exact.abs_diff(want) <= 1, "dc {dc}");
        }
    }

    #[test]
    fn within_one_of_the_float_transform_on_random_blocks() {
        let mut seed = 0x1234_5678_9abc_def0u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..500 {
            let mut c = [0i32; 64];
            for (k, v) in c.iter_mut().enumerate() {
                // Larger at low frequencies, like real blocks; some zeros.
                let span = if k < 10 { 400 } else { 60 };
                *v = (next() % (2 * span + 1)) as i32 - span as i32;
                if next() % 3 == 0 {
                    *v = 0;
                }
            }
            let mut out = [0u8; 64];
            idct(&c, &mut out);
            let want = float_idct(&c);
            for (i, (&a, &b)) in out.iter().zip(&want).enumerate() {
                assert!(a.abs_diff(b) <= 1, "sample {i}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn hostile_coefficients_give_a_defined_result() {
        let mut out = [0u8; 64];
        idct(&[i32::MAX; 64], &mut out);
        idct(&[i32::MIN; 64], &mut out);
    }
}
