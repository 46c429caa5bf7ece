//! The AVX2 integer layer (x86-64): `vpmaddwd` over 8 rows per vector, requantization mostly in
//! 32-bit lanes (AVX2 has no 64-bit arithmetic shift), with its lane tables (`Avx2Lanes` in
//! `decoder/lanes.rs`).

use core::arch::x86_64::*;
use core::ops::Range;

use super::{GROUP, Job, Kernel, Layers, PackedLayer};
use crate::limits::MAX_WIDTH;

/// The AVX2 kernel. A value exists only inside [`run`], whose caller checked the CPU.
#[derive(Clone, Copy, Debug)]
pub(super) struct Avx2(());

/// Runs `job` with the AVX2 kernel, in code compiled for AVX2: what it inlines (the span
/// gather, the output conversion) gets the wider instructions too.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn run<J: Job>(job: J) -> J::Output {
    job.run(Avx2(()))
}

impl Layers for Avx2 {
    const KERNEL: Kernel = Kernel::Avx2;
    const SKIPS_PAIRS: bool = true;

    #[inline(always)]
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        // SAFETY: an `Avx2` exists only inside `run`, whose caller checked the CPU has AVX2.
        unsafe { forward_avx2(l, x, y, blocks) }
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
        unsafe { forward_group_avx2(l, xs, init, l.pairs_within(pairs), ys, blocks) }
    }

    #[inline(always)]
    fn sums(
        self,
        l: &PackedLayer,
        x: &[i16; MAX_WIDTH],
        pairs: Range<usize>,
        sums: &mut [i32; MAX_WIDTH],
    ) {
        // SAFETY: as in `forward`.
        unsafe { sums_avx2(l, x, l.pairs_within(pairs), sums) }
    }

    fn probe(self, rounds: u64) -> i64 {
        // SAFETY: as in `forward`.
        unsafe { probe_avx2(rounds) }
    }
}

#[target_feature(enable = "avx2")]
fn forward_avx2(l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
    let count = l.out_pad() / 8;
    let mut b = 0;
    while b < count {
        // 8 blocks (64 rows) per pass where all are wanted: one broadcast of an input pair serves
        // 8 multiply-adds (the accumulators and the broadcast fit the 16 registers).
        if b + 8 <= count && (blocks >> b) & 0xFF == 0xFF {
            block::<8, 1>(l, x, y, b);
            b += 8;
        } else if b + 4 <= count && (blocks >> b) & 0xF == 0xF {
            block::<4, 2>(l, x, y, b);
            b += 4;
        } else {
            if (blocks >> b) & 1 != 0 {
                block::<1, 4>(l, x, y, b);
            }
            b += 1;
        }
    }
}

/// Rows `8·first .. 8·(first + B)`: B blocks of 8 rows, one pass over the input pairs, dealt
/// round-robin to S partial sums per block (B·S independent chains; see `avx512::block`).
#[target_feature(enable = "avx2")]
fn block<const B: usize, const S: usize>(
    l: &PackedLayer,
    x: &[i16; MAX_WIDTH],
    y: &mut [i16; MAX_WIDTH],
    first: usize,
) {
    // Bounds: 8·(first + B) ≤ out_pad ≤ MAX_WIDTH (caller), 2·in_pairs ≤ MAX_WIDTH, and
    // weights has in_pairs · out_pad · 2 entries (PackedLayer invariants).
    debug_assert!(8 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(
        2 * l.in_pairs() <= MAX_WIDTH && l.weights().len() == l.in_pairs() * l.out_pad() * 2
    );
    let mut acc = [[_mm256_setzero_si256(); S]; B];
    // SAFETY: every pointer access below stays within the bounds stated above.
    unsafe {
        let bias = l.bias().as_ptr().add(8 * first);
        for (k, a) in acc.iter_mut().enumerate() {
            if let Some(a) = a.first_mut() {
                *a = _mm256_loadu_si256(bias.add(8 * k).cast());
            }
        }
        let pairs = x.as_ptr().cast::<i32>();
        let base = l.weights().as_ptr().add(16 * first);
        let step = 2 * l.out_pad();
        let mut p = 0;
        while p + S <= l.in_pairs() {
            for s in 0..S {
                let both = _mm256_set1_epi32(pairs.add(p + s).read_unaligned());
                let row = base.add((p + s) * step);
                for (k, a) in acc.iter_mut().enumerate() {
                    let w = _mm256_loadu_si256(row.add(16 * k).cast());
                    if let Some(a) = a.get_mut(s) {
                        *a = _mm256_add_epi32(*a, _mm256_madd_epi16(w, both));
                    }
                }
            }
            p += S;
        }
        for (s, p) in (p..l.in_pairs()).enumerate() {
            let both = _mm256_set1_epi32(pairs.add(p).read_unaligned());
            let row = base.add(p * step);
            for (k, a) in acc.iter_mut().enumerate() {
                let w = _mm256_loadu_si256(row.add(16 * k).cast());
                if let Some(a) = a.get_mut(s) {
                    *a = _mm256_add_epi32(*a, _mm256_madd_epi16(w, both));
                }
            }
        }
    }
    for (k, partial) in acc.into_iter().enumerate() {
        let sum = partial.into_iter().fold(_mm256_setzero_si256(), |a, b| _mm256_add_epi32(a, b));
        let values = requantize(l, sum, first + k);
        // SAFETY: 8·(first + k) + 8 ≤ MAX_WIDTH.
        unsafe { _mm_storeu_si128(y.as_mut_ptr().add(8 * (first + k)).cast(), values) };
    }
}

/// `Layers::sums` for `pairs` within `in_pairs`: 4 blocks of 8 rows per pass over the pairs
/// (out_pad is a multiple of 16, so passes of 4 or 2 blocks cover it), each broadcast of an input
/// pair serving 4 independent chains.
#[target_feature(enable = "avx2")]
pub(super) fn sums_avx2(
    l: &PackedLayer,
    x: &[i16; MAX_WIDTH],
    pairs: Range<usize>,
    sums: &mut [i32; MAX_WIDTH],
) {
    let count = l.out_pad() / 8;
    let mut b = 0;
    while b < count {
        if b + 4 <= count {
            sums_block::<4>(l, x, pairs.clone(), sums, b);
            b += 4;
        } else {
            sums_block::<2>(l, x, pairs.clone(), sums, b);
            b += 2;
        }
    }
}

/// Rows `8·first .. 8·(first + B)` of `Layers::sums`.
#[target_feature(enable = "avx2")]
fn sums_block<const B: usize>(
    l: &PackedLayer,
    x: &[i16; MAX_WIDTH],
    pairs: Range<usize>,
    sums: &mut [i32; MAX_WIDTH],
    first: usize,
) {
    // Bounds as in `block`; pairs.end ≤ in_pairs (`pairs_within`).
    debug_assert!(8 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(
        2 * l.in_pairs() <= MAX_WIDTH && l.weights().len() == l.in_pairs() * l.out_pad() * 2
    );
    debug_assert!(pairs.start <= pairs.end && pairs.end <= l.in_pairs());
    let mut acc = [_mm256_setzero_si256(); B];
    // SAFETY: every pointer access below stays within the bounds stated above.
    unsafe {
        let inputs = x.as_ptr().cast::<i32>();
        let mut row = l.weights().as_ptr().add(16 * first + 2 * l.out_pad() * pairs.start);
        for p in pairs {
            let both = _mm256_set1_epi32(inputs.add(p).read_unaligned());
            for (k, a) in acc.iter_mut().enumerate() {
                let w = _mm256_loadu_si256(row.add(16 * k).cast());
                *a = _mm256_add_epi32(*a, _mm256_madd_epi16(w, both));
            }
            row = row.add(2 * l.out_pad());
        }
        for (k, a) in acc.into_iter().enumerate() {
            // 8·(first + k) + 8 ≤ out_pad ≤ MAX_WIDTH.
            _mm256_storeu_si256(sums.as_mut_ptr().add(8 * (first + k)).cast(), a);
        }
    }
}

/// `Layers::forward_group` for `G` texels, `pairs` within `in_pairs`, `init` rows of `out_pad`.
#[target_feature(enable = "avx2")]
fn forward_group_avx2<const G: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    blocks: u32,
) {
    let count = l.out_pad() / 8;
    let mut b = 0;
    while b < count {
        // Two blocks per pass: G·2 accumulators, 2 weight vectors and a broadcast fit the 16
        // registers.
        if b + 2 <= count && (blocks >> b) & 3 == 3 {
            group_block::<G, 2>(l, x, init, pairs.clone(), y, b);
            b += 2;
        } else {
            if (blocks >> b) & 1 != 0 {
                group_block::<G, 1>(l, x, init, pairs.clone(), y, b);
            }
            b += 1;
        }
    }
}

/// Rows `8·first .. 8·(first + B)` for `G` texels: G·B independent chains.
#[target_feature(enable = "avx2")]
fn group_block<const G: usize, const B: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: Range<usize>,
    y: &mut [[i16; MAX_WIDTH]; G],
    first: usize,
) {
    // Bounds as in `block`; each `init` row holds out_pad entries and pairs ≤ in_pairs (callers).
    debug_assert!(8 * (first + B) <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(
        2 * l.in_pairs() <= MAX_WIDTH && l.weights().len() == l.in_pairs() * l.out_pad() * 2
    );
    debug_assert!(pairs.end <= l.in_pairs());
    let mut acc = [[_mm256_setzero_si256(); B]; G];
    // SAFETY: every pointer access below stays within the bounds stated above.
    unsafe {
        for (texel, start) in acc.iter_mut().zip(init) {
            let start = start.add(8 * first);
            for (k, a) in texel.iter_mut().enumerate() {
                *a = _mm256_loadu_si256(start.add(8 * k).cast());
            }
        }
        let mut row = l.weights().as_ptr().add(16 * first + 2 * l.out_pad() * pairs.start);
        for p in pairs {
            let mut w = [_mm256_setzero_si256(); B];
            for (k, v) in w.iter_mut().enumerate() {
                *v = _mm256_loadu_si256(row.add(16 * k).cast());
            }
            for (texel, inputs) in acc.iter_mut().zip(x) {
                let both = _mm256_set1_epi32(inputs.as_ptr().cast::<i32>().add(p).read_unaligned());
                for (a, &w) in texel.iter_mut().zip(&w) {
                    *a = _mm256_add_epi32(*a, _mm256_madd_epi16(w, both));
                }
            }
            row = row.add(2 * l.out_pad());
        }
    }
    for (texel, out) in acc.into_iter().zip(y.iter_mut()) {
        for (k, a) in texel.into_iter().enumerate() {
            let values = requantize(l, a, first + k);
            // SAFETY: 8·(first + k) + 8 ≤ MAX_WIDTH.
            unsafe { _mm_storeu_si128(out.as_mut_ptr().add(8 * (first + k)).cast(), values) };
        }
    }
}

/// Requantization, saturation and activation of the 8 accumulators of block `b`, exactly as
/// `Requant::apply`, `saturate_i16` and `hard_gelu_q`, mostly in 32-bit lanes (the constants
/// and why each step is exact: `Avx2Lanes` in `decoder/lanes.rs`). AVX2 has no 64-bit
/// arithmetic shift; here the only 64-bit steps are the multiply, the rounding add and the left
/// shift, and the high halves hold the result.
#[target_feature(enable = "avx2")]
fn requantize(l: &PackedLayer, acc: __m256i, b: usize) -> __m128i {
    let lanes = &l.tables().avx2;
    debug_assert!(lanes.round.len() >= 8 * b + 8 && lanes.lift.len() >= 8 * b + 8);
    debug_assert!(lanes.clamp_lo.len() >= 8 * b + 8 && lanes.clamp_hi.len() >= 8 * b + 8);
    debug_assert!(lanes.post_shift.len() >= 8 * b + 8 && l.multiplier().len() >= 8 * b + 8);
    // SAFETY: every per-row vector holds out_pad ≥ 8·b + 8 entries.
    let row = |v: *const i32| unsafe { _mm256_loadu_si256(v.add(8 * b).cast()) };
    // SAFETY: as for `row`: the 64-bit vectors hold out_pad ≥ 8·b + 8 entries too.
    let wide = |v: *const i64| unsafe {
        let v = v.add(8 * b);
        (_mm256_loadu_si256(v.cast()), _mm256_loadu_si256(v.add(4).cast()))
    };
    let acc = _mm256_min_epi32(
        _mm256_max_epi32(acc, row(lanes.clamp_lo.as_ptr())),
        row(lanes.clamp_hi.as_ptr()),
    );
    let round = wide(lanes.round.as_ptr());
    // The multiply reads the even 32-bit lanes: rows 2i as they are, rows 2i + 1 shifted down.
    let m = row(l.multiplier().as_ptr());
    let mut even = _mm256_add_epi64(_mm256_mul_epi32(acc, m), round.0);
    let (odd_acc, odd_m) = (_mm256_srli_epi64::<32>(acc), _mm256_srli_epi64::<32>(m));
    let mut odd = _mm256_add_epi64(_mm256_mul_epi32(odd_acc, odd_m), round.1);
    if lanes.lifted {
        let lift = wide(lanes.lift.as_ptr().cast());
        even = _mm256_sllv_epi64(even, lift.0);
        odd = _mm256_sllv_epi64(odd, lift.1);
    }
    // The high halves: row 2i's from `even` moved down, row 2i + 1's in place.
    let high = _mm256_blend_epi32::<0b1010_1010>(_mm256_srli_epi64::<32>(even), odd);
    let v = _mm256_srav_epi32(high, row(lanes.post_shift.as_ptr().cast()));
    let z = if l.activation() == crate::neural::mlp::Activation::HardGelu {
        let v = _mm256_min_epi32(
            _mm256_max_epi32(v, _mm256_set1_epi32(i32::from(i16::MIN))),
            _mm256_set1_epi32(i32::from(i16::MAX)),
        );
        hard_gelu(v, u32::from(l.out_frac_bits().clamp(1, 14)))
    } else {
        v
    };
    // The saturating pack is the i16 saturation (a no-op after hardGELU); it interleaves
    // 128-bit halves, and the permute puts rows 0–3 and 4–7 back together.
    let packed = _mm256_packs_epi32(z, z);
    _mm256_castsi256_si128(_mm256_permute4x64_epi64::<0b00_00_10_00>(packed))
}

/// `hard_gelu_q` on 8 lanes. In the middle region (|z| < t = 1.5·2^f) the result is
/// floor(floor(num / 2^f) / 3) with num = z(z + t) + t; u = floor(num / 2^f) + 3·2^f lies in
/// [0, 2^17), so floor(u / 3) is exact through f32 as trunc(u · f32(1/3)): f32(1/3) is above 1/3,
/// so the exact product is at least u/3 and, u/3 being k, k + 1/3 or k + 2/3, its rounding can
/// neither fall below k nor (the excess being below 2^17 · 2^-25 + one rounding) reach k + 1.
#[target_feature(enable = "avx2")]
fn hard_gelu(z: __m256i, f: u32) -> __m256i {
    let t = 3i32 << (f - 1);
    let tv = _mm256_set1_epi32(t);
    let num = _mm256_add_epi32(_mm256_mullo_epi32(z, _mm256_add_epi32(z, tv)), tv);
    let floor_f = _mm256_sra_epi32(num, _mm_cvtsi32_si128(f as i32));
    let offset = 1i32 << f;
    let u = _mm256_add_epi32(floor_f, _mm256_set1_epi32(3 * offset));
    let third = _mm256_set1_ps(1.0 / 3.0);
    let q = _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_cvtepi32_ps(u), third));
    let mid = _mm256_sub_epi32(q, _mm256_set1_epi32(offset));
    let above = _mm256_cmpgt_epi32(z, _mm256_set1_epi32(t - 1));
    let below = _mm256_cmpgt_epi32(_mm256_set1_epi32(1 - t), z);
    _mm256_andnot_si256(below, _mm256_blendv_epi8(mid, z, above))
}

/// The peak-rate probe of this instruction set: `rounds` × 8 independent `vpmaddwd` + `vpaddd`
/// (128 multiply-adds per round) on registers only. Returns a value that depends on every
/// product, so the work cannot be optimized away.
#[target_feature(enable = "avx2")]
fn probe_avx2(rounds: u64) -> i64 {
    let a = [0x0003_0001, 0x0005_0002, 0x0007_0004, 0x0001_0009].map(|v| _mm256_set1_epi32(v));
    let (mut b0, mut b1) = (_mm256_set1_epi32(0x0001_0001), _mm256_set1_epi32(0x0002_0003));
    let step = _mm256_set1_epi16(1);
    let mut acc = [_mm256_setzero_si256(); 8];
    for _ in 0..rounds {
        for (k, pair) in acc.chunks_exact_mut(2).enumerate() {
            let w = a.get(k).copied().unwrap_or(step);
            if let [p, q] = pair {
                *p = _mm256_add_epi32(*p, _mm256_madd_epi16(w, b0));
                *q = _mm256_add_epi32(*q, _mm256_madd_epi16(w, b1));
            }
        }
        b0 = _mm256_add_epi16(b0, step);
        b1 = _mm256_add_epi16(b1, step);
    }
    let sum = acc.into_iter().fold(_mm256_setzero_si256(), |s, v| _mm256_add_epi32(s, v));
    i64::from(_mm256_extract_epi32::<0>(sum)) + i64::from(_mm256_extract_epi32::<7>(sum))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// hardGELU on every i16 input at every Q-format, against `hard_gelu_q`.
    #[test]
    fn avx2_hard_gelu_is_exact_for_every_input() {
        if !Kernel::Avx2.is_available() {
            return;
        }
        for f in 1..=14u32 {
            for start in (i32::from(i16::MIN)..=i32::from(i16::MAX)).step_by(8) {
                let z: [i32; 8] = core::array::from_fn(|k| start + k as i32);
                let mut got = [0i32; 8];
                // SAFETY: AVX2 checked above; the arrays are 32 bytes.
                unsafe {
                    let v = _mm256_loadu_si256(z.as_ptr().cast());
                    _mm256_storeu_si256(got.as_mut_ptr().cast(), hard_gelu(v, f));
                }
                for k in 0..8 {
                    let want = crate::neural::mlp::hard_gelu_q(z[k] as i16, f as u8);
                    assert_eq!(got[k], i32::from(want), "z {} f {f}", z[k]);
                }
            }
        }
    }
}
