//! The NEON dot-product kernel (AArch64 CPUs with `FEAT_DotProd`, the `dotprod` feature:
//! Cortex-A55, Cortex-A75 and later Arm cores). `sdot` adds four products of signed
//! bytes to each 32-bit lane: 16 products per instruction where `smlal` makes 4.
//!
//! The weights are bytes, the activations i16, so each activation is split into two bytes:
//! x = 256·h + l + 128 with h = x >> 8 (the signed high byte) and l = (x & 255) − 128 (the low
//! byte, biased into i8 range). Then per row
//!
//! Σ w·x = 256·Σ w·h + Σ w·l + 128·Σ w,
//!
//! two `sdot`s per 4 inputs × 4 rows (8 products of the layer per instruction, twice `smlal`'s
//! 4) and a per-row constant. Every sum wraps mod 2^32 like the scalar twin's i32 accumulators,
//! and the identity holds mod 2^32, so the result is the same integer. The constant depends on
//! which inputs are summed (a group pass may sum only the first ones), so its table
//! (`NeonDotLanes` in `decoder/lanes.rs`) keeps it per 16-input chunk as a prefix sum; inputs
//! a pass leaves out are split as 0 (h = 0, l = −128), whose −128·w the constant cancels.
//!
//! The weights get their own layout, `[quad][row][4]` (the 4 bytes of inputs 4q..4q + 4 of each
//! row, quads padded with zeros to whole chunks of 16 inputs), so one 128-bit load holds 4 rows
//! × 4 inputs and the indexed `sdot` (`sdot v.4s, w.16b, x.4b[k]`) takes quad k of a chunk's
//! split activations from a register. Requantization and hardGELU are the NEON kernel's.
//!
//! `sdot` is reached through inline assembly: the `vdotq` intrinsics are not stable in Rust yet.

use core::arch::aarch64::*;
use core::arch::asm;
use core::ops::Range;

use super::super::lanes::CHUNK;
use super::neon::requantize;
use super::{GROUP, Job, Kernel, Layers, PackedLayer};
use crate::limits::MAX_WIDTH;

/// Chunks of the widest layer.
const MAX_CHUNKS: usize = MAX_WIDTH / CHUNK;

/// The NEON dot-product kernel. A value exists only inside [`run`], whose caller checked the
/// CPU.
#[derive(Clone, Copy, Debug)]
pub(super) struct NeonDot(());

/// Runs `job` with the NEON dot-product kernel.
///
/// # Safety
/// The CPU must support NEON and the dot-product extension (`dotprod`).
#[target_feature(enable = "neon,dotprod")]
pub(super) unsafe fn run<J: Job>(job: J) -> J::Output {
    job.run(NeonDot(()))
}

impl Layers for NeonDot {
    const KERNEL: Kernel = Kernel::NeonDot;
    /// Its chunks of 16 inputs carry a correction for the split activations summed over whole
    /// chunks from the first: a later start sums the pairs before it as zeros (no work saved).
    const SKIPS_PAIRS: bool = false;

    #[inline(always)]
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        // SAFETY: a `NeonDot` exists only inside `run`, whose caller checked the CPU.
        unsafe { forward_dot(l, x, y, blocks) }
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
        let pairs = l.pairs_within(pairs);
        let mut zeroed;
        let xs = if pairs.start > 0 {
            zeroed = *xs;
            for x in &mut zeroed {
                x.iter_mut().take(2 * pairs.start).for_each(|v| *v = 0);
            }
            &zeroed
        } else {
            xs
        };
        // SAFETY: as in `forward`; every start row holds out_pad entries (`start_row`).
        unsafe { forward_group_dot(l, xs, init, pairs.end, ys, blocks) }
    }

    fn probe(self, rounds: u64) -> i64 {
        // SAFETY: as in `forward`.
        unsafe { probe_dot(rounds) }
    }
}

/// `sdot acc.4s, w.16b, x.4b[K]`: lane r of `acc` plus the dot product of bytes 4r..4r + 4 of
/// `w` with bytes 4K..4K + 4 of `x` (wrapping).
#[target_feature(enable = "neon,dotprod")]
#[inline]
fn sdot<const K: i32>(acc: int32x4_t, w: int8x16_t, x: int8x16_t) -> int32x4_t {
    let mut acc = acc;
    // SAFETY: register-only arithmetic of the dot-product extension this function is compiled
    // for; its callers run only where the CPU has it.
    unsafe {
        asm!(
            "sdot {acc:v}.4s, {w:v}.16b, {x:v}.4b[{k}]",
            acc = inout(vreg) acc,
            w = in(vreg) w,
            x = in(vreg) x,
            k = const K,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    acc
}

/// A texel's activations split into bytes, chunk by chunk: `[c] = (h, l)` for inputs
/// 16c..16c + 16.
type Split = [[int8x16_t; 2]; MAX_CHUNKS];

/// The split of the first `n` inputs of `x` (see the module documentation); inputs from `n` on
/// count as 0. Fills the chunks holding inputs below `n`.
#[target_feature(enable = "neon,dotprod")]
#[inline]
fn split(x: &[i16; MAX_WIDTH], n: usize) -> Split {
    let mut out = [[vdupq_n_s8(0); 2]; MAX_CHUNKS];
    let bias = vdupq_n_u8(0x80);
    let lanes: [u8; CHUNK] = core::array::from_fn(|k| k as u8);
    // SAFETY: 16 bytes.
    let index = unsafe { vld1q_u8(lanes.as_ptr()) };
    for (c, slot) in out.iter_mut().enumerate().take(n.div_ceil(CHUNK)) {
        // SAFETY: 16c + 16 ≤ MAX_WIDTH (c < MAX_CHUNKS).
        let (a, b) = unsafe {
            let p = x.as_ptr().add(CHUNK * c);
            (vreinterpretq_u8_s16(vld1q_s16(p)), vreinterpretq_u8_s16(vld1q_s16(p.add(8))))
        };
        // Inputs 16c + k with k < n − 16c are kept; the others become 0 (h 0, low byte 0).
        let keep = vcltq_u8(index, vdupq_n_u8((n - CHUNK * c).min(CHUNK) as u8));
        let low = vandq_u8(vuzp1q_u8(a, b), keep);
        let high = vandq_u8(vuzp2q_u8(a, b), keep);
        *slot = [vreinterpretq_s8_u8(high), vreinterpretq_s8_u8(veorq_u8(low, bias))];
    }
    out
}

/// The 4 accumulators of 8 rows (`[h rows 0–3, h rows 4–7, l rows 0–3, l rows 4–7]`) into row
/// sums: 256·h + l + the byte split's constant + the start values.
#[target_feature(enable = "neon,dotprod")]
#[inline]
fn combine(acc: [int32x4_t; 4], offset: [int32x4_t; 2], start: [int32x4_t; 2]) -> [int32x4_t; 2] {
    let [h0, h1, l0, l1] = acc;
    let row = |h: int32x4_t, l: int32x4_t, o: int32x4_t, s: int32x4_t| {
        vaddq_s32(vaddq_s32(vshlq_n_s32::<8>(h), l), vaddq_s32(o, s))
    };
    [row(h0, l0, offset[0], start[0]), row(h1, l1, offset[1], start[1])]
}

/// Rows `o .. o + 8` of the byte split's constant for `chunks` chunks summed.
///
/// # Safety
/// `o + 8 ≤ out_pad` and `chunks ≤` the layer's chunks.
#[target_feature(enable = "neon,dotprod")]
#[inline]
unsafe fn offset(l: &PackedLayer, chunks: usize, o: usize) -> [int32x4_t; 2] {
    let lanes = &l.tables().neon_dot;
    debug_assert!(chunks <= lanes.chunks && o + 8 <= l.out_pad());
    // SAFETY: the table holds (chunks + 1)·out_pad entries (caller's bounds).
    unsafe {
        let p = lanes.offset.as_ptr().add(chunks * l.out_pad() + o);
        [vld1q_s32(p), vld1q_s32(p.add(4))]
    }
}

#[target_feature(enable = "neon,dotprod")]
fn forward_dot(l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
    let chunks = l.tables().neon_dot.chunks;
    let split = split(x, CHUNK * chunks);
    let count = l.out_pad() / 8;
    let mut b = 0;
    while b < count {
        if b + 4 <= count && (blocks >> b) & 0xF == 0xF {
            block::<8>(l, &split, y, 2 * b);
            b += 4;
        } else if b + 2 <= count && (blocks >> b) & 3 == 3 {
            block::<4>(l, &split, y, 2 * b);
            b += 2;
        } else {
            if (blocks >> b) & 1 != 0 {
                block::<2>(l, &split, y, 2 * b);
            }
            b += 1;
        }
    }
}

/// Adds quad `K` of a chunk to the accumulators of `R` 4-row vectors, their weights loaded from
/// `w` (one 16-byte vector per 4 rows, consecutive): `acc[r] = [h, l]`.
///
/// # Safety
/// `w` points at `16·R` readable bytes.
#[target_feature(enable = "neon,dotprod")]
#[inline]
unsafe fn quad<const K: i32, const R: usize>(
    acc: &mut [[int32x4_t; 2]; R],
    w: *const i8,
    split: [int8x16_t; 2],
) {
    for (r, [h, l]) in acc.iter_mut().enumerate() {
        // SAFETY: within the caller's 16·R bytes.
        let w = unsafe { vld1q_s8(w.add(16 * r)) };
        *h = sdot::<K>(*h, w, split[0]);
        *l = sdot::<K>(*l, w, split[1]);
    }
}

/// Rows `4·first .. 4·(first + R)`: `R` 4-row vectors (R even), `2R` accumulators, one pass
/// over the chunks.
#[target_feature(enable = "neon,dotprod")]
fn block<const R: usize>(l: &PackedLayer, split: &Split, y: &mut [i16; MAX_WIDTH], first: usize) {
    let lanes = &l.tables().neon_dot;
    // Bounds: 4·(first + R) ≤ out_pad ≤ MAX_WIDTH (caller); the weights hold 4·chunks quads of
    // out_pad rows × 4 bytes (`NeonDotLanes::new`).
    debug_assert!(
        R.is_multiple_of(2) && 4 * (first + R) <= l.out_pad() && l.out_pad() <= MAX_WIDTH
    );
    debug_assert!(lanes.weights.len() == CHUNK * lanes.chunks * l.out_pad());
    let zero = vdupq_n_s32(0);
    let mut acc = [[zero; 2]; R];
    let step = 4 * l.out_pad();
    let base = lanes.weights.as_ptr().wrapping_add(16 * first);
    for (c, &chunk) in split.iter().enumerate().take(lanes.chunks) {
        let w = base.wrapping_add(4 * c * step);
        // SAFETY: quad 4c + k's rows 4·first .. 4·(first + R) are the 16R bytes from
        // w + k·step, within the weights (bounds above).
        unsafe {
            quad::<0, R>(&mut acc, w, chunk);
            quad::<1, R>(&mut acc, w.wrapping_add(step), chunk);
            quad::<2, R>(&mut acc, w.wrapping_add(2 * step), chunk);
            quad::<3, R>(&mut acc, w.wrapping_add(3 * step), chunk);
        }
    }
    for (k, pair) in acc.chunks_exact(2).enumerate() {
        let o = 4 * first + 8 * k;
        let &[[h0, l0], [h1, l1]] = pair else { continue };
        // SAFETY: o + 8 ≤ out_pad, the bias holds out_pad rows; all chunks were summed.
        let (bias, offset) = unsafe {
            let p = l.bias().as_ptr().add(o);
            ([vld1q_s32(p), vld1q_s32(p.add(4))], offset(l, lanes.chunks, o))
        };
        let values = requantize(l, combine([h0, h1, l0, l1], offset, bias), o);
        // SAFETY: o + 8 ≤ MAX_WIDTH.
        unsafe { vst1q_s16(y.as_mut_ptr().add(o), values) };
    }
}

/// `Layers::forward_group` for `G` texels, `pairs` ≤ `in_pairs`, `init` rows of `out_pad`.
#[target_feature(enable = "neon,dotprod")]
fn forward_group_dot<const G: usize>(
    l: &PackedLayer,
    x: &[[i16; MAX_WIDTH]; G],
    init: [*const i32; G],
    pairs: usize,
    y: &mut [[i16; MAX_WIDTH]; G],
    blocks: u32,
) {
    let n = 2 * pairs;
    let splits = x.each_ref().map(|x| split(x, n));
    for b in (0..l.out_pad() / 8).filter(|b| (blocks >> b) & 1 != 0) {
        group_block(l, &splits, n.div_ceil(CHUNK), init, y, b);
    }
}

/// Adds quad `K` of a chunk to the accumulators of `G` texels × 8 rows (two 4-row vectors, their
/// weights loaded once for the group from `w` and `w + 16`): `acc[t][v] = [h, l]`.
///
/// # Safety
/// `w` points at 32 readable bytes.
#[target_feature(enable = "neon,dotprod")]
#[inline]
unsafe fn group_quad<const K: i32, const G: usize>(
    acc: &mut [[[int32x4_t; 2]; 2]; G],
    w: *const i8,
    splits: [[int8x16_t; 2]; G],
) {
    // SAFETY: within the caller's 32 bytes.
    let w = unsafe { [vld1q_s8(w), vld1q_s8(w.add(16))] };
    for (texel, split) in acc.iter_mut().zip(splits) {
        for ([h, l], &w) in texel.iter_mut().zip(&w) {
            *h = sdot::<K>(*h, w, split[0]);
            *l = sdot::<K>(*l, w, split[1]);
        }
    }
}

/// Rows `8·b .. 8·b + 8` for `G` texels over the first `chunks` chunks: 4·G independent
/// chains, each weight vector loaded once for the group.
#[target_feature(enable = "neon,dotprod")]
fn group_block<const G: usize>(
    l: &PackedLayer,
    splits: &[Split; G],
    chunks: usize,
    init: [*const i32; G],
    y: &mut [[i16; MAX_WIDTH]; G],
    b: usize,
) {
    let lanes = &l.tables().neon_dot;
    // Bounds as in `block`; chunks ≤ the layer's (pairs ≤ in_pairs) and each `init` row holds
    // out_pad entries (callers).
    debug_assert!(8 * b + 8 <= l.out_pad() && l.out_pad() <= MAX_WIDTH);
    debug_assert!(chunks <= lanes.chunks);
    let zero = vdupq_n_s32(0);
    let mut acc = [[[zero; 2]; 2]; G];
    let step = 4 * l.out_pad();
    let base = lanes.weights.as_ptr().wrapping_add(32 * b);
    for c in 0..chunks {
        let w = base.wrapping_add(4 * c * step);
        let chunk = splits.each_ref().map(|s| s.get(c).copied().unwrap_or([vdupq_n_s8(0); 2]));
        // SAFETY: quad 4c + k's rows 8b .. 8b + 8 are the 32 bytes from w + k·step, within the
        // weights (bounds above).
        unsafe {
            group_quad::<0, G>(&mut acc, w, chunk);
            group_quad::<1, G>(&mut acc, w.wrapping_add(step), chunk);
            group_quad::<2, G>(&mut acc, w.wrapping_add(2 * step), chunk);
            group_quad::<3, G>(&mut acc, w.wrapping_add(3 * step), chunk);
        }
    }
    let o = 8 * b;
    // SAFETY: o + 8 ≤ out_pad and chunks ≤ the layer's.
    let offset = unsafe { offset(l, chunks, o) };
    for ((texel, start), out) in acc.into_iter().zip(init).zip(y.iter_mut()) {
        let [[h0, l0], [h1, l1]] = texel;
        // SAFETY: each start row holds out_pad ≥ o + 8 entries.
        let start = unsafe { [vld1q_s32(start.add(o)), vld1q_s32(start.add(o + 4))] };
        let values = requantize(l, combine([h0, h1, l0, l1], offset, start), o);
        // SAFETY: o + 8 ≤ MAX_WIDTH.
        unsafe { vst1q_s16(out.as_mut_ptr().add(o), values) };
    }
}

/// The peak-rate probe of this instruction set: `rounds` × 16 independent `sdot`s on registers
/// only, counted as 128 multiply-adds of the layer (each `sdot` makes 16 byte products, half of
/// an i16 activation's 8 products: see the module documentation).
#[target_feature(enable = "neon,dotprod")]
fn probe_dot(rounds: u64) -> i64 {
    let w = [0x0103_0507, 0x0209_0401, 0x7F80_0102, 0x0301_0203]
        .map(|v: i32| vreinterpretq_s8_s32(vdupq_n_s32(v)));
    let mut x = vdupq_n_s8(1);
    let step = vdupq_n_s8(1);
    let mut acc = [vdupq_n_s32(0); 16];
    for _ in 0..rounds {
        for (k, quad) in acc.chunks_exact_mut(4).enumerate() {
            let w = w.get(k).copied().unwrap_or(step);
            if let [p, q, r, s] = quad {
                *p = sdot::<0>(*p, w, x);
                *q = sdot::<1>(*q, w, x);
                *r = sdot::<2>(*r, w, x);
                *s = sdot::<3>(*s, w, x);
            }
        }
        x = vaddq_s8(x, step);
    }
    let sum = acc.into_iter().fold(vdupq_n_s32(0), |s, v| vaddq_s32(s, v));
    vaddlvq_s32(sum)
}
