//! AVX2 + FMA3 (x86-64): 8 lanes. A register block is R rows × 16 columns (2 vectors), R = 4
//! when 4 rows remain: 8 independent chains cover the FMA latency on two FMA pipes. `unsafe`
//! here is `core::arch` loads and stores through pointers whose bounds follow from `Matrix`'s
//! invariants (checked by the callers in `gemm.rs`) and the CPU check done there.
#![allow(unsafe_code)]

use core::arch::x86_64::*;

use super::Matrix;

pub(super) const PROBE_FMAS: u64 = 8 * 8;

/// # Safety
/// The CPU has AVX2 and FMA; `depth ≤ a.cols, b.rows`, `c.rows == a.rows`,
/// `c.stride == b.stride`, `init` (if any) has `b.stride` elements.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn matmul(
    a: &Matrix,
    depth: usize,
    b: &Matrix,
    init: Option<&[f32]>,
    c: &mut Matrix,
) {
    let mut r = 0;
    while r + 4 <= a.rows {
        // SAFETY: rows r .. r + 4 exist; the rest is the caller's contract.
        unsafe { rows::<4>(a, depth, b, init, c, r) };
        r += 4;
    }
    while r < a.rows {
        // SAFETY: as above, one row.
        unsafe { rows::<1>(a, depth, b, init, c, r) };
        r += 1;
    }
}

#[target_feature(enable = "avx2,fma")]
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
        let (i0, i1) = match init {
            // SAFETY: `init` holds b.stride ≥ n + 16 values (the bounds above).
            Some(i) => unsafe {
                (_mm256_loadu_ps(i.as_ptr().add(n)), _mm256_loadu_ps(i.as_ptr().add(n + 8)))
            },
            None => (_mm256_setzero_ps(), _mm256_setzero_ps()),
        };
        let mut acc = [[i0, i1]; R];
        for k in 0..depth {
            // SAFETY: row k and columns n .. n + 16 of b (the bounds above).
            let (b0, b1) = unsafe {
                let row = bp.add(k * b.stride + n);
                (_mm256_loadu_ps(row), _mm256_loadu_ps(row.add(8)))
            };
            for (i, acc) in acc.iter_mut().enumerate() {
                // SAFETY: one element of a within its rows and columns (the bounds above).
                let av = unsafe { _mm256_broadcast_ss(&*ap.add((r0 + i) * a.stride + k)) };
                acc[0] = _mm256_fmadd_ps(av, b0, acc[0]);
                acc[1] = _mm256_fmadd_ps(av, b1, acc[1]);
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            // SAFETY: the row of c and columns n .. n + 16 (the bounds above).
            unsafe {
                let row = cp.add((r0 + i) * c.stride + n);
                _mm256_storeu_ps(row, acc[0]);
                _mm256_storeu_ps(row.add(8), acc[1]);
            }
        }
        n += 16;
    }
}

/// # Safety
/// The CPU has AVX2 and FMA; `a.rows == b.rows`, `c.rows ≤ a.cols`, `c.stride == b.stride`.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn matmul_at_acc(a: &Matrix, b: &Matrix, c: &mut Matrix) {
    let mut m = 0;
    while m + 4 <= c.rows {
        // SAFETY: rows m .. m + 4 of c exist; the rest is the caller's contract.
        unsafe { at_rows::<4>(a, b, c, m) };
        m += 4;
    }
    while m < c.rows {
        // SAFETY: as above, one row.
        unsafe { at_rows::<1>(a, b, c, m) };
        m += 1;
    }
}

#[target_feature(enable = "avx2,fma")]
unsafe fn at_rows<const R: usize>(a: &Matrix, b: &Matrix, c: &mut Matrix, m0: usize) {
    let (ap, bp, cp) = (a.data.as_ptr(), b.data.as_ptr(), c.data.as_mut_ptr());
    let mut n = 0;
    while n < b.stride {
        // Bounds of the loads and stores below: n + 16 ≤ stride; k < a.rows == b.rows; columns
        // m0 .. m0 + R of a exist (c.rows ≤ a.cols ≤ a.stride) and so do rows m0 .. m0 + R of c.
        let mut acc = [[_mm256_setzero_ps(); 2]; R];
        for (i, acc) in acc.iter_mut().enumerate() {
            // SAFETY: the row of c and columns n .. n + 16 (the bounds above).
            unsafe {
                let row = cp.add((m0 + i) * c.stride + n);
                *acc = [_mm256_loadu_ps(row), _mm256_loadu_ps(row.add(8))];
            }
        }
        for k in 0..a.rows {
            // SAFETY: row k and columns n .. n + 16 of b (the bounds above).
            let (b0, b1) = unsafe {
                let row = bp.add(k * b.stride + n);
                (_mm256_loadu_ps(row), _mm256_loadu_ps(row.add(8)))
            };
            for (i, acc) in acc.iter_mut().enumerate() {
                // SAFETY: one element of a within its rows and columns (the bounds above).
                let av = unsafe { _mm256_broadcast_ss(&*ap.add(k * a.stride + m0 + i)) };
                acc[0] = _mm256_fmadd_ps(av, b0, acc[0]);
                acc[1] = _mm256_fmadd_ps(av, b1, acc[1]);
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            // SAFETY: the row of c and columns n .. n + 16 (the bounds above).
            unsafe {
                let row = cp.add((m0 + i) * c.stride + n);
                _mm256_storeu_ps(row, acc[0]);
                _mm256_storeu_ps(row.add(8), acc[1]);
            }
        }
        n += 16;
    }
}

/// # Safety
/// The CPU has AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn probe(rounds: u64) -> f32 {
    let x = _mm256_set1_ps(std::hint::black_box(0.999_999));
    let y = _mm256_set1_ps(std::hint::black_box(1e-7));
    let mut acc = [_mm256_set1_ps(1.0); 8];
    for _ in 0..rounds {
        for v in &mut acc {
            *v = _mm256_fmadd_ps(*v, x, y);
        }
    }
    let mut sum = [0f32; 8];
    for v in acc {
        let mut lanes = [0f32; 8];
        // SAFETY: `lanes` holds 8 floats.
        unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), v) };
        for (s, l) in sum.iter_mut().zip(lanes) {
            *s += l;
        }
    }
    sum.iter().sum()
}

/// `f()`, compiled with AVX2 and FMA where it is inlined here.
///
/// # Safety
/// The CPU has AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn run<R>(f: impl FnOnce() -> R) -> R {
    f()
}
