//! The portable twin: the same fma chains as the SIMD kernels, one element at a time.

use super::Matrix;

pub(super) const PROBE_FMAS: u64 = 8;

pub(super) fn matmul(a: &Matrix, depth: usize, b: &Matrix, init: Option<&[f32]>, c: &mut Matrix) {
    for r in 0..a.rows {
        let a_row = &a.row(r)[..depth];
        let c_row = c.row_mut(r);
        match init {
            Some(i) => c_row.copy_from_slice(i),
            None => c_row.fill(0.0),
        }
        for (k, &av) in a_row.iter().enumerate() {
            for (cv, &bv) in c_row.iter_mut().zip(b.row(k)) {
                *cv = av.mul_add(bv, *cv);
            }
        }
    }
}

pub(super) fn matmul_at_acc(a: &Matrix, b: &Matrix, c: &mut Matrix) {
    for k in 0..a.rows {
        let (a_row, b_row) = (a.row(k), b.row(k));
        for (m, &av) in a_row.iter().enumerate().take(c.rows) {
            for (cv, &bv) in c.row_mut(m).iter_mut().zip(b_row) {
                *cv = av.mul_add(bv, *cv);
            }
        }
    }
}

pub(super) fn probe(rounds: u64) -> f32 {
    let mut acc = [1.0f32, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.7];
    let (x, y) = (std::hint::black_box(0.999_999f32), std::hint::black_box(1e-7f32));
    for _ in 0..rounds {
        for v in &mut acc {
            *v = v.mul_add(x, y);
        }
    }
    acc.iter().sum()
}
