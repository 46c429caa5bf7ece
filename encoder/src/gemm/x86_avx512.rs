//! AVX-512F (x86-64): 16 lanes. A register block is R rows × 16 columns (one vector), R = 8
//! when 8 rows remain: 8 independent chains cover the FMA latency on two FMA pipes. `unsafe`
//! here is `core::arch` loads and stores through pointers whose bounds follow from `Matrix`'s
//! invariants (checked by the callers in `gemm.rs`) and the CPU check done there.
#![allow(unsafe_code)]

use core::arch::x86_64::*;

use super::Matrix;

pub(super) const PROBE_FMAS: u64 = 8 * 16;

/// # Safety
/// The CPU has AVX-512F; `depth ≤ a.cols, b.rows`, `c.rows == a.rows`, `c.stride == b.stride`,
/// `init` (if any) has `b.stride` elements.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn matmul(
    a: &Matrix,
    depth: usize,
    b: &Matrix,
    init: Option<&[f32]>,
    c: &mut Matrix,
) {
    let mut r = 0;
    while r + 8 <= a.rows {
        // SAFETY: rows r .. r + 8 exist; the rest is the caller's contract.
        unsafe { rows::<8>(a, depth, b, init, c, r) };
        r += 8;
    }
    while r < a.rows {
        // SAFETY: as above, one row.
        unsafe { rows::<1>(a, depth, b, init, c, r) };
        r += 1;
    }
}

#[target_feature(enable = "avx512f")]
unsafe fn rows<const R: usize>(
    a: &Matrix,
    depth: usize,
    b: &Matrix,
    init: Option<&[f32]>,
    c: &mut Matrix,
    r0: usize,
) {
    let (ap, bp, cp) = (a.data.as_ptr(), b.data.as_ptr(), c.data.as_mut_ptr());
    let mut n = 0;
    while n < b.stride {
        // Bounds of the loads and stores below: n + 16 ≤ stride (a multiple of 16); k < depth ≤
        // b.rows; rows r0 .. r0 + R of a and c exist (callers); k < depth ≤ a.cols ≤ a.stride.
        let i0 = match init {
            // SAFETY: `init` holds b.stride ≥ n + 16 values (the bounds above).
            Some(i) => unsafe { _mm512_loadu_ps(i.as_ptr().add(n)) },
            None => _mm512_setzero_ps(),
        };
        let mut acc = [i0; R];
        for k in 0..depth {
            // SAFETY: row k and columns n .. n + 16 of b (the bounds above).
            let b0 = unsafe { _mm512_loadu_ps(bp.add(k * b.stride + n)) };
            for (i, acc) in acc.iter_mut().enumerate() {
                // SAFETY: one element of a within its rows and columns (the bounds above).
                let av = unsafe { _mm512_set1_ps(*ap.add((r0 + i) * a.stride + k)) };
                *acc = _mm512_fmadd_ps(av, b0, *acc);
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            // SAFETY: the row of c and columns n .. n + 16 (the bounds above).
            unsafe { _mm512_storeu_ps(cp.add((r0 + i) * c.stride + n), *acc) };
        }
        n += 16;
    }
}

/// # Safety
/// The CPU has AVX-512F; `a.rows == b.rows`, `c.rows ≤ a.cols`, `c.stride == b.stride`.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn matmul_at_acc(a: &Matrix, b: &Matrix, c: &mut Matrix) {
    let mut m = 0;
    while m + 8 <= c.rows {
        // SAFETY: rows m .. m + 8 of c exist; the rest is the caller's contract.
        unsafe { at_rows::<8>(a, b, c, m) };
        m += 8;
    }
    while m < c.rows {
        // SAFETY: as above, one row.
        unsafe { at_rows::<1>(a, b, c, m) };
        m += 1;
    }
}

#[target_feature(enable = "avx512f")]
unsafe fn at_rows<const R: usize>(a: &Matrix, b: &Matrix, c: &mut Matrix, m0: usize) {
    let (ap, bp, cp) = (a.data.as_ptr(), b.data.as_ptr(), c.data.as_mut_ptr());
    let mut n = 0;
    while n < b.stride {
        // Bounds of the loads and stores below: n + 16 ≤ stride; k < a.rows == b.rows; columns
        // m0 .. m0 + R of a exist (c.rows ≤ a.cols ≤ a.stride) and so do rows m0 .. m0 + R of c.
        let mut acc = [_mm512_setzero_ps(); R];
        for (i, acc) in acc.iter_mut().enumerate() {
            // SAFETY: row m0 + i and columns n .. n + 16 of c (the bounds above).
            *acc = unsafe { _mm512_loadu_ps(cp.add((m0 + i) * c.stride + n)) };
        }
        for k in 0..a.rows {
            // SAFETY: row k and columns n .. n + 16 of b (the bounds above).
            let b0 = unsafe { _mm512_loadu_ps(bp.add(k * b.stride + n)) };
            for (i, acc) in acc.iter_mut().enumerate() {
                // SAFETY: one element of a within its rows and columns (the bounds above).
                let av = unsafe { _mm512_set1_ps(*ap.add(k * a.stride + m0 + i)) };
                *acc = _mm512_fmadd_ps(av, b0, *acc);
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            // SAFETY: the row of c and columns n .. n + 16 (the bounds above).
            unsafe { _mm512_storeu_ps(cp.add((m0 + i) * c.stride + n), *acc) };
        }
        n += 16;
    }
}

/// # Safety
/// The CPU has AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn probe(rounds: u64) -> f32 {
    let x = _mm512_set1_ps(std::hint::black_box(0.999_999));
    let y = _mm512_set1_ps(std::hint::black_box(1e-7));
    let mut acc = [_mm512_set1_ps(1.0); 8];
    for _ in 0..rounds {
        for v in &mut acc {
            *v = _mm512_fmadd_ps(*v, x, y);
        }
    }
    acc.iter().map(|&v| _mm512_reduce_add_ps(v)).sum()
}

/// `f()`, compiled with AVX-512F where it is inlined here.
///
/// # Safety
/// The CPU has AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn run<R>(f: impl FnOnce() -> R) -> R {
    f()
}
