//! The AVX-512 VNNI integer layer (x86-64): 16 rows per vector, `vpdpwssd` fusing the pair
//! multiply-add with the accumulation, a native 64-bit arithmetic shift for requantization, and
//! its lane tables (`Avx512Lanes` in `decoder/lanes.rs`).

use core::arch::x86_64::*;
use core::ops::Range;

use super::{GROUP, Job, Kernel, Layers, PackedLayer};
use crate::limits::MAX_WIDTH;

/// The AVX-512 VNNI kernel. A value exists only inside [`run`], whose caller checked the CPU.
#[derive(Clone, Copy, Debug)]
pub(super) struct Avx512(());

/// Runs `job` with the AVX-512 VNNI kernel, in code compiled for AVX-512: what it inlines (the
/// span gather, the output conversion) gets the wider instructions too.
///
/// # Safety
/// The CPU must support AVX-512 F, BW and VNNI.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn run<J: Job>(job: J) -> J::Output {
    job.run(Avx512(()))
}

impl Layers for Avx512 {
    const KERNEL: Kernel = Kernel::Avx512Vnni;
    const SKIPS_PAIRS: bool = true;

    #[inline(always)]
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        // SAFETY: an `Avx512` exists only inside `run`, whose caller checked the CPU has AVX-512
        // F, BW and VNNI.
        unsafe { forward_avx512(l, x, y, blocks) }
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
        unsafe { forward_group_avx512(l, xs, init, l.pairs_within(pairs), ys, blocks) }
    }

    /// The AVX2 form (`vpmaddwd` over 8 rows): the sums are a small share of a span's work.
    #[inline(always)]
    fn sums(
        self,
        l: &PackedLayer,
        x: &[i16; MAX_WIDTH],
        pairs: Range<usize>,
        sums: &mut [i32; MAX_WIDTH],
    ) {
        // SAFETY: an `Avx512Vnni` exists only inside `run`, whose caller checked the CPU has
        // AVX-512 F, which implies AVX2 (and `run` is compiled with it).
        unsafe { super::avx2::sums_avx2(l, x, l.pairs_within(pairs), sums) }
    }

    fn probe(self, rounds: u64) -> i64 {
        // SAFETY: as in `forward`.
        unsafe { probe_avx512(rounds) }
    }
}

#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn forward_avx512(l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
    let count = l.out_pad() / 16;
    let selected = |b: usize| (blocks >> (2 * b)) & 3 != 0;
    let mut b = 0;
    while b < count {
        if b + 4 <= count && (b..b + 4).all(selected) {
            block::<4, 2>(l, x, y, b);
            b += 4;
        } else {
            if selected(b) {
                block::<1, 4>(l, x, y, b);
            }
            b += 1;
        }
    }
}

/// Rows `16·first .. 16·(first + B)`: B blocks of 16 rows, one pass over the input pairs. The
/// pairs are dealt round-robin to S partial sums per block, so B·S independent `vpdpwssd` chains
/// hide the instruction's latency; integer sums do not depend on their order.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn block<const B: usize, const S: usize>(
    l: &PackedLayer,
    x: &[i16; MAX_WIDTH],
    y: &mut [i16; MAX_WIDTH],
    first: usize,
) {
    // Bounds: 16·(first + B) ≤ out_pad ≤ MAX_WIDTH (caller), 2·in_pairs ≤ MAX_WIDTH, and
    // weights has in_pairs · out_pad · 2 entries (PackedLayer invariants).
    debug_assert!(16 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(
        2 * l.in_pairs() <= MAX_WIDTH && l.weights().len() == l.in_pairs() * l.out_pad() * 2
    );
    let mut acc = [[_mm512_setzero_si512(); S]; B];
    // SAFETY: every pointer access below stays within the bounds stated above.
    unsafe {
        let bias = l.bias().as_ptr().add(16 * first);
        for (k, a) in acc.iter_mut().enumerate() {
            if let Some(a) = a.first_mut() {
                *a = _mm512_loadu_si512(bias.add(16 * k).cast());
            }
        }
        let pairs = x.as_ptr().cast::<i32>();
        let base = l.weights().as_ptr().add(32 * first);
        let step = 2 * l.out_pad();
        let mut p = 0;
        while p + S <= l.in_pairs() {
            for s in 0..S {
                let both = _mm512_set1_epi32(pairs.add(p + s).read_unaligned());
                let row = base.add((p + s) * step);
                for (k, a) in acc.iter_mut().enumerate() {
                    let w = _mm512_loadu_si512(row.add(32 * k).cast());
                    if let Some(a) = a.get_mut(s) {
                        *a = _mm512_dpwssd_epi32(*a, w, both);
                    }
                }
            }
            p += S;
        }
        for (s, p) in (p..l.in_pairs()).enumerate() {
            let both = _mm512_set1_epi32(pairs.add(p).read_unaligned());
            let row = base.add(p * step);
            for (k, a) in acc.iter_mut().enumerate() {
                let w = _mm512_loadu_si512(row.add(32 * k).cast());
                if let Some(a) = a.get_mut(s) {
                    *a = _mm512_dpwssd_epi32(*a, w, both);
                }
            }
        }
    }
    for (k, partial) in acc.into_iter().enumerate() {
        let sum = partial.into_iter().fold(_mm512_setzero_si512(), |a, b| _mm512_add_epi32(a, b));
        let values = requantize(l, sum, first + k);
        // SAFETY: 16·(first + k) + 16 ≤ MAX_WIDTH.
        unsafe { _mm256_storeu_si256(y.as_mut_ptr().add(16 * (first + k)).cast(), values) };
    }
}

/// `Layers::forward_group` for `G` texels, `pairs` within `in_pairs`, `init` rows of `out_pad`.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn forward_group_avx512<const G: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    blocks: u32,
) {
    let count = l.out_pad() / 16;
    let selected = |b: usize| (blocks >> (2 * b)) & 3 != 0;
    let mut b = 0;
    while b < count {
        if b + 4 <= count && (b..b + 4).all(selected) {
            group_block::<G, 4>(l, x, init, pairs.clone(), y, b);
            b += 4;
        } else if b + 2 <= count && (b..b + 2).all(selected) {
            group_block::<G, 2>(l, x, init, pairs.clone(), y, b);
            b += 2;
        } else {
            if selected(b) {
                group_block::<G, 1>(l, x, init, pairs.clone(), y, b);
            }
            b += 1;
        }
    }
}

/// Rows `16·first .. 16·(first + B)` for `G` texels: G·B independent `vpdpwssd` chains.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn group_block<const G: usize, const B: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    first: usize,
) {
    // Bounds as in `block`; each `init` row holds out_pad entries and pairs ≤ in_pairs (callers).
    debug_assert!(16 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(
        2 * l.in_pairs() <= MAX_WIDTH && l.weights().len() == l.in_pairs() * l.out_pad() * 2
    );
    debug_assert!(pairs.end <= l.in_pairs());
    let mut acc = [[_mm512_setzero_si512(); B]; G];
    // SAFETY: every pointer access below stays within the bounds stated above.
    unsafe {
        for (texel, start) in acc.iter_mut().zip(init) {
            let start = start.add(16 * first);
            for (k, a) in texel.iter_mut().enumerate() {
                *a = _mm512_loadu_si512(start.add(16 * k).cast());
            }
        }
        let mut row = l.weights().as_ptr().add(32 * first + 2 * l.out_pad() * pairs.start);
        for p in pairs {
            let mut w = [_mm512_setzero_si512(); B];
            for (k, v) in w.iter_mut().enumerate() {
                *v = _mm512_loadu_si512(row.add(32 * k).cast());
            }
            for (texel, inputs) in acc.iter_mut().zip(x) {
                let both = _mm512_set1_epi32(inputs.as_ptr().cast::<i32>().add(p).read_unaligned());
                for (a, &w) in texel.iter_mut().zip(&w) {
                    *a = _mm512_dpwssd_epi32(*a, w, both);
                }
            }
            row = row.add(2 * l.out_pad());
        }
    }
    for (texel, out) in acc.into_iter().zip(y.iter_mut()) {
        for (k, a) in texel.into_iter().enumerate() {
            let values = requantize(l, a, first + k);
            // SAFETY: 16·(first + k) + 16 ≤ MAX_WIDTH.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().add(16 * (first + k)).cast(), values) };
        }
    }
}

/// Requantization, saturation and activation of the 16 accumulators of block `b`, exactly as
/// `Requant::apply`, `saturate_i16` and `hard_gelu_q`. The 64-bit products of even and odd rows
/// are rounded and shifted with per-lane constants (`Avx512Lanes` in `decoder/lanes.rs`),
/// saturated to i16 while narrowing (`vpmovsqw`) and interleaved back into row order.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn requantize(l: &PackedLayer, acc: __m512i, b: usize) -> __m256i {
    let lanes = &l.tables().avx512;
    debug_assert!(lanes.wide_multiplier.len() >= 16 * b + 16);
    debug_assert!(lanes.wide_round.len() >= 16 * b + 16 && lanes.wide_shift.len() >= 16 * b + 16);
    // SAFETY: the lane vectors hold out_pad ≥ 16·b + 16 entries.
    let load =
        |v: *const i64, half: usize| unsafe { _mm512_loadu_si512(v.add(16 * b + 8 * half).cast()) };
    let (m, r, s) = (
        lanes.wide_multiplier.as_ptr(),
        lanes.wide_round.as_ptr(),
        lanes.wide_shift.as_ptr().cast::<i64>(),
    );
    // Even rows sit in the low halves of the 64-bit lanes, odd rows in the high halves.
    let even = _mm512_mul_epi32(acc, load(m, 0));
    let odd = _mm512_mul_epi32(_mm512_srli_epi64::<32>(acc), load(m, 1));
    let even = _mm512_srav_epi64(_mm512_add_epi64(even, load(r, 0)), load(s, 0));
    let odd = _mm512_srav_epi64(_mm512_add_epi64(odd, load(r, 1)), load(s, 1));
    let (even, odd) = (_mm512_cvtsepi64_epi16(even), _mm512_cvtsepi64_epi16(odd));
    let rows = _mm256_set_m128i(_mm_unpackhi_epi16(even, odd), _mm_unpacklo_epi16(even, odd));
    if l.activation() != crate::neural::mlp::Activation::HardGelu {
        return rows;
    }
    let z = hard_gelu(_mm512_cvtepi16_epi32(rows), u32::from(l.out_frac_bits().clamp(1, 14)));
    // Every value is in i16 range, so truncating to 16 bits is exact.
    _mm512_cvtepi32_epi16(z)
}

/// `hard_gelu_q` on 16 lanes. In the middle region (|z| < t = 1.5·2^f) the result is
/// floor(n / 3) with n = floor(num / 2^f), num = z(z + t) + t, and |n| < 2^17 (f ≤ 14). Here the
/// division is one f32 multiply converted rounding down: f32(1/3) = (1/3)(1 + 2^-25), so with
/// n = 3k + r the exact product is k + r/3 + n·2^-25/3. For r = 0 it is k plus less than half an
/// ulp of k (|k|·2^-25 < ulp(k)/2), so it rounds to k; for r = 1, 2 it lies strictly between k
/// and k + 1 by more than its rounding error. Either way the floor is k (tested exhaustively).
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn hard_gelu(z: __m512i, f: u32) -> __m512i {
    let t = 3i32 << (f - 1);
    let tv = _mm512_set1_epi32(t);
    let num = _mm512_add_epi32(_mm512_mullo_epi32(z, _mm512_add_epi32(z, tv)), tv);
    let n = _mm512_sra_epi32(num, _mm_cvtsi32_si128(f as i32));
    let third = _mm512_mul_ps(_mm512_cvtepi32_ps(n), _mm512_set1_ps(1.0 / 3.0));
    let mid = _mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(third);
    let above = _mm512_cmpge_epi32_mask(z, tv);
    let below = _mm512_cmple_epi32_mask(z, _mm512_set1_epi32(-t));
    let v = _mm512_mask_blend_epi32(above, mid, z);
    _mm512_mask_blend_epi32(below, v, _mm512_setzero_si512())
}

/// The peak-rate probe of this instruction set: `rounds` × 8 independent `vpdpwssd` (256
/// multiply-adds per round) on registers only; see `avx2::probe_avx2`.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
fn probe_avx512(rounds: u64) -> i64 {
    let a = [0x0003_0001, 0x0005_0002, 0x0007_0004, 0x0001_0009].map(|v| _mm512_set1_epi32(v));
    let (mut b0, mut b1) = (_mm512_set1_epi32(0x0001_0001), _mm512_set1_epi32(0x0002_0003));
    let step = _mm512_set1_epi16(1);
    let mut acc = [_mm512_setzero_si512(); 8];
    for _ in 0..rounds {
        for (k, pair) in acc.chunks_exact_mut(2).enumerate() {
            let w = a.get(k).copied().unwrap_or(step);
            if let [p, q] = pair {
                *p = _mm512_dpwssd_epi32(*p, w, b0);
                *q = _mm512_dpwssd_epi32(*q, w, b1);
            }
        }
        b0 = _mm512_add_epi16(b0, step);
        b1 = _mm512_add_epi16(b1, step);
    }
    let sum = acc.into_iter().fold(_mm512_setzero_si512(), |s, v| _mm512_add_epi32(s, v));
    i64::from(_mm512_reduce_add_epi32(sum))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// hardGELU on every i16 input at every Q-format, against `hard_gelu_q`.
    #[test]
    fn avx512_hard_gelu_is_exact_for_every_input() {
        if !Kernel::Avx512Vnni.is_available() {
            return;
        }
        for f in 1..=14u32 {
            for start in (i32::from(i16::MIN)..=i32::from(i16::MAX)).step_by(16) {
                let z: [i32; 16] = core::array::from_fn(|k| start + k as i32);
                let mut got = [0i32; 16];
                // SAFETY: AVX-512 checked above; the arrays are 64 bytes.
                unsafe {
                    let v = _mm512_loadu_si512(z.as_ptr().cast());
                    _mm512_storeu_si512(got.as_mut_ptr().cast(), hard_gelu(v, f));
                }
                for k in 0..16 {
                    let want = crate::neural::mlp::hard_gelu_q(z[k] as i16, f as u8);
                    assert_eq!(got[k], i32::from(want), "z {} f {f}", z[k]);
                }
            }
        }
    }
}
