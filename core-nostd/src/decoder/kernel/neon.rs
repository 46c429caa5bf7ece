//! The NEON integer layer (AArch64). The weights keep the prepared layout (`[pair][row][2]`), so
//! one 128-bit load holds 4 rows × 2 inputs; a broadcast of the input pair `(x0, x1)` lines up
//! with it, and `smlal` (low half) and `smlal2` (high half) add the 8 products to two
//! accumulators of 4 lanes each, every row's two products in neighbouring lanes. After the last
//! pair one pairwise add (`addp`) folds them into 4 rows. Every step wraps like the scalar
//! twin's i32 sums, so the result is the same integer.
//!
//! Requantization is native: `smull` widens acc·m to 64 bits, `srshl` by −s is exactly
//! `(acc·m + 2^(s−1)) >> s`, and two saturating narrows (`sqxtn` to i32, then to i16) are the i16
//! saturation. hardGELU divides by 3 through f32 and rounds down (`fcvtms`), exact for every
//! input as in `avx512::hard_gelu`.

use core::arch::aarch64::*;
use core::ops::Range;

use super::{GROUP, Job, Kernel, Layers, PackedLayer};
use crate::limits::MAX_WIDTH;

/// The NEON kernel. A value exists only inside [`run`], whose caller checked the CPU (NEON is
/// part of every AArch64 target Rust builds for).
#[derive(Clone, Copy, Debug)]
pub(super) struct Neon(());

/// Runs `job` with the NEON kernel.
///
/// # Safety
/// The CPU must support NEON (Advanced SIMD).
#[target_feature(enable = "neon")]
pub(super) unsafe fn run<J: Job>(job: J) -> J::Output {
    job.run(Neon(()))
}

impl Layers for Neon {
    const KERNEL: Kernel = Kernel::Neon;
    /// Not measured on an AArch64 CPU yet: spans keep summing every pair per texel.
    const SKIPS_PAIRS: bool = false;

    #[inline(always)]
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        // SAFETY: a `Neon` exists only inside `run`, whose caller checked the CPU has NEON.
        unsafe { forward_neon(l, x, y, blocks) }
    }

    #[inline(always)]
    fn forward_group(
        self,
        l: &PackedLayer,
        xs: &[[i16; MAX_WIDTH]; GROUP],
        init: [&[i32]; GROUP],
        pairs: Range<usize>,
        ys: &mut [[i16; MAX_WIDTH]; GROUP],
        blocks: u32,
        _count: usize,
    ) {
        let init = init.map(|s| l.start_row(s).as_ptr());
        // SAFETY: as in `forward`; every start row holds out_pad entries (`start_row`).
        unsafe { forward_group_neon(l, xs, init, l.pairs_within(pairs), ys, blocks) }
    }

    fn probe(self, rounds: u64) -> i64 {
        // SAFETY: as in `forward`.
        unsafe { probe_neon(rounds) }
    }
}

#[target_feature(enable = "neon")]
fn forward_neon(l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
    let count = l.out_pad() / 8;
    let mut b = 0;
    while b < count {
        if b + 4 <= count && (blocks >> b) & 0xF == 0xF {
            block::<4>(l, x, y, b);
            b += 4;
        } else if b + 2 <= count && (blocks >> b) & 3 == 3 {
            block::<2>(l, x, y, b);
            b += 2;
        } else {
            if (blocks >> b) & 1 != 0 {
                block::<1>(l, x, y, b);
            }
            b += 1;
        }
    }
}

/// The broadcast of input pair `p` of `x`: lanes x[2p], x[2p + 1], x[2p], ….
///
/// # Safety
/// `2p + 2 ≤ MAX_WIDTH`.
#[target_feature(enable = "neon")]
#[inline]
unsafe fn pair(x: &[i16; MAX_WIDTH], p: usize) -> int16x8_t {
    // SAFETY: the caller keeps p within the array.
    let both = unsafe { x.as_ptr().cast::<i32>().add(p).read_unaligned() };
    vreinterpretq_s16_s32(vdupq_n_s32(both))
}

/// Adds the products of one weight vector (4 rows × the 2 inputs of a pair) and a pair
/// broadcast to a block's accumulators `[lo, hi]` (rows 0–1 and 2–3 of the 4, two lanes each).
#[target_feature(enable = "neon")]
#[inline]
fn mac(acc: &mut [int32x4_t; 2], w: int16x8_t, both: int16x8_t) {
    let [lo, hi] = acc;
    *lo = vmlal_s16(*lo, vget_low_s16(w), vget_low_s16(both));
    *hi = vmlal_high_s16(*hi, w, both);
}

/// Rows `8·first .. 8·(first + B)`: B blocks of 8 rows (4 accumulators each, 4·B independent
/// chains), one pass over the input pairs.
#[target_feature(enable = "neon")]
fn block<const B: usize>(
    l: &PackedLayer,
    x: &[i16; MAX_WIDTH],
    y: &mut [i16; MAX_WIDTH],
    first: usize,
) {
    // Bounds: 8·(first + B) ≤ out_pad ≤ MAX_WIDTH (caller), 2·in_pairs ≤ MAX_WIDTH, and
    // weights has in_pairs · out_pad · 2 entries (PackedLayer invariants).
    debug_assert!(8 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(2 * l.in_pairs() <= MAX_WIDTH);
    debug_assert!(l.weights().len() == l.in_pairs() * l.out_pad() * 2);
    let zero = vdupq_n_s32(0);
    let mut acc = [[[zero; 2]; 2]; B];
    let step = 2 * l.out_pad();
    let mut row = l.weights().as_ptr().wrapping_add(16 * first);
    for p in 0..l.in_pairs() {
        // SAFETY: p < in_pairs, within the bounds stated above.
        let both = unsafe { pair(x, p) };
        for (k, quads) in acc.iter_mut().enumerate() {
            for (h, a) in quads.iter_mut().enumerate() {
                // SAFETY: row + 16k + 8h + 8 ≤ (p + 1)·step, within the weights.
                let w = unsafe { vld1q_s16(row.add(16 * k + 8 * h)) };
                mac(a, w, both);
            }
        }
        row = row.wrapping_add(step);
    }
    for (k, quads) in acc.into_iter().enumerate() {
        let o = 8 * (first + k);
        // SAFETY: the bias holds out_pad ≥ o + 8 rows.
        let bias = unsafe {
            [vld1q_s32(l.bias().as_ptr().add(o)), vld1q_s32(l.bias().as_ptr().add(o + 4))]
        };
        let values = requantize(l, fold(quads, bias), o);
        // SAFETY: o + 8 ≤ MAX_WIDTH.
        unsafe { vst1q_s16(y.as_mut_ptr().add(o), values) };
    }
}

/// A block's 8 row sums: each pair of neighbouring lanes added (`addp`), plus the start values.
#[target_feature(enable = "neon")]
#[inline]
fn fold(quads: [[int32x4_t; 2]; 2], init: [int32x4_t; 2]) -> [int32x4_t; 2] {
    let [[a, b], [c, d]] = quads;
    [vaddq_s32(vpaddq_s32(a, b), init[0]), vaddq_s32(vpaddq_s32(c, d), init[1])]
}

/// `Layers::forward_group` for `G` texels, `pairs` within `in_pairs`, `init` rows of `out_pad`.
#[target_feature(enable = "neon")]
fn forward_group_neon<const G: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    blocks: u32,
) {
    for b in (0..l.out_pad() / 8).filter(|b| (blocks >> b) & 1 != 0) {
        group_block(l, x, init, pairs.clone(), y, b);
    }
}

/// Rows `8·b .. 8·b + 8` for `G` texels: 4·G independent chains, each weight vector loaded once
/// for the group.
#[target_feature(enable = "neon")]
fn group_block<const G: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    b: usize,
) {
    // Bounds as in `block`; each `init` row holds out_pad entries and pairs ≤ in_pairs (callers).
    debug_assert!(8 * b + 8 <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(2 * l.in_pairs() <= MAX_WIDTH && pairs.end <= l.in_pairs());
    debug_assert!(l.weights().len() == l.in_pairs() * l.out_pad() * 2);
    let zero = vdupq_n_s32(0);
    let mut acc = [[[zero; 2]; 2]; G];
    let step = 2 * l.out_pad();
    let mut row = l.weights().as_ptr().wrapping_add(16 * b + step * pairs.start);
    for p in pairs {
        // SAFETY: row + 16 ≤ (p + 1)·step, within the weights.
        let w = unsafe { [vld1q_s16(row), vld1q_s16(row.add(8))] };
        for (texel, inputs) in acc.iter_mut().zip(x) {
            // SAFETY: p < pairs ≤ in_pairs.
            let both = unsafe { pair(inputs, p) };
            for (a, &w) in texel.iter_mut().zip(&w) {
                mac(a, w, both);
            }
        }
        row = row.wrapping_add(step);
    }
    for ((quads, start), out) in acc.into_iter().zip(init).zip(y.iter_mut()) {
        let o = 8 * b;
        // SAFETY: each start row holds out_pad ≥ o + 8 entries.
        let start = unsafe { [vld1q_s32(start.add(o)), vld1q_s32(start.add(o + 4))] };
        let values = requantize(l, fold(quads, start), o);
        // SAFETY: o + 8 ≤ MAX_WIDTH.
        unsafe { vst1q_s16(out.as_mut_ptr().add(o), values) };
    }
}

/// Requantization, saturation and activation of the 8 row sums from row `o`, exactly as
/// `Requant::apply`, `saturate_i16` and `hard_gelu_q`.
#[target_feature(enable = "neon")]
#[inline]
pub(super) fn requantize(l: &PackedLayer, acc: [int32x4_t; 2], o: usize) -> int16x8_t {
    debug_assert!(l.multiplier().len() >= o + 8 && l.tables().neon.neg_shift.len() >= o + 8);
    let (m, s) = (l.multiplier().as_ptr(), l.tables().neon.neg_shift.as_ptr());
    let narrow = |acc: int32x4_t, r: usize| {
        // SAFETY: the per-row vectors hold out_pad ≥ o + 8 entries; r ≤ o + 4.
        let (m, s) =
            unsafe { (vld1q_s32(m.add(r)), [vld1q_s64(s.add(r)), vld1q_s64(s.add(r + 2))]) };
        // |acc·m| < 2^62 and the rounding term is at most 2^61: the exact value fits i64.
        let low = vrshlq_s64(vmull_s32(vget_low_s32(acc), vget_low_s32(m)), s[0]);
        let high = vrshlq_s64(vmull_high_s32(acc, m), s[1]);
        vqmovn_high_s64(vqmovn_s64(low), high)
    };
    let rows = vqmovn_high_s32(vqmovn_s32(narrow(acc[0], o)), narrow(acc[1], o + 4));
    if l.activation() != crate::neural::mlp::Activation::HardGelu {
        return rows;
    }
    let f = i32::from(l.out_frac_bits().clamp(1, 14));
    let low = hard_gelu(vmovl_s16(vget_low_s16(rows)), f);
    let high = hard_gelu(vmovl_high_s16(rows), f);
    // Every value is in i16 range, so narrowing is exact.
    vmovn_high_s32(vmovn_s32(low), high)
}

/// `hard_gelu_q` on 4 lanes (`f` in 1..=14), by the method and argument of `avx512::hard_gelu`:
/// n = floor(num / 2^f) with num = z(z + t) + t, then floor(n · f32(1/3)) in the middle region.
#[target_feature(enable = "neon")]
#[inline]
fn hard_gelu(z: int32x4_t, f: i32) -> int32x4_t {
    let t = 3i32 << (f - 1);
    let tv = vdupq_n_s32(t);
    let num = vaddq_s32(vmulq_s32(z, vaddq_s32(z, tv)), tv);
    let n = vshlq_s32(num, vdupq_n_s32(-f));
    let mid = vcvtmq_s32_f32(vmulq_f32(vcvtq_f32_s32(n), vdupq_n_f32(1.0 / 3.0)));
    let above = vcgeq_s32(z, tv);
    let below = vcleq_s32(z, vdupq_n_s32(-t));
    vbslq_s32(below, vdupq_n_s32(0), vbslq_s32(above, z, mid))
}

/// The peak-rate probe of this instruction set: `rounds` × 16 independent `smlal`/`smlal2`
/// (64 multiply-adds per round) on registers only; see `avx2::probe_avx2`.
#[target_feature(enable = "neon")]
fn probe_neon(rounds: u64) -> i64 {
    let a = [0x0003_0001, 0x0005_0002, 0x0007_0004, 0x0001_0009]
        .map(|v| vreinterpretq_s16_s32(vdupq_n_s32(v)));
    let (mut b0, mut b1) = (vdupq_n_s16(1), vdupq_n_s16(3));
    let step = vdupq_n_s16(1);
    let mut acc = [vdupq_n_s32(0); 16];
    for _ in 0..rounds {
        for (k, quad) in acc.chunks_exact_mut(4).enumerate() {
            let w = a.get(k).copied().unwrap_or(step);
            if let [p, q, r, s] = quad {
                *p = vmlal_s16(*p, vget_low_s16(w), vget_low_s16(b0));
                *q = vmlal_high_s16(*q, w, b0);
                *r = vmlal_s16(*r, vget_low_s16(w), vget_low_s16(b1));
                *s = vmlal_high_s16(*s, w, b1);
            }
        }
        b0 = vaddq_s16(b0, step);
        b1 = vaddq_s16(b1, step);
    }
    let sum = acc.into_iter().fold(vdupq_n_s32(0), |s, v| vaddq_s32(s, v));
    vaddlvq_s32(sum)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// hardGELU on every i16 input at every Q-format, against `hard_gelu_q`.
    #[test]
    fn neon_hard_gelu_is_exact_for_every_input() {
        assert!(Kernel::Neon.is_available(), "NEON is part of every AArch64 target");
        for f in 1..=14i32 {
            for start in (i32::from(i16::MIN)..=i32::from(i16::MAX)).step_by(4) {
                let z: [i32; 4] = core::array::from_fn(|k| start + k as i32);
                let mut got = [0i32; 4];
                // SAFETY: NEON checked above; the arrays are 16 bytes.
                unsafe {
                    let v = vld1q_s32(z.as_ptr());
                    vst1q_s32(got.as_mut_ptr(), hard_gelu(v, f));
                }
                for k in 0..4 {
                    let want = crate::neural::mlp::hard_gelu_q(z[k] as i16, f as u8);
                    assert_eq!(got[k], i32::from(want), "z {} f {f}", z[k]);
                }
            }
        }
    }
}
