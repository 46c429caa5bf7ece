//! The trainer's matrix products (docs/ENCODING.md, "Trainer kernels"). Every product is defined
//! element by element as a chain of fused multiply-adds in a fixed order — `c = fma(a_k, b_k, c)`
//! for k = 0, 1, … — and every kernel evaluates exactly that chain; kernels differ only in how
//! many independent chains they run side by side (columns in SIMD lanes, rows in registers).
//! So the scalar twin, AVX2 and AVX-512 give bit-identical results, and a trained file does not
//! depend on the CPU that trained it.

mod scalar;
#[cfg(target_arch = "x86_64")]
mod x86_avx2;
#[cfg(target_arch = "x86_64")]
mod x86_avx512;

/// Columns are padded to a multiple of this (the widest kernel's lane count).
pub const LANES: usize = 16;

/// Which code runs the trainer's matrix products.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TrainKernel {
    /// Portable Rust with `f32::mul_add` (a library call where the target lacks FMA): the twin
    /// every SIMD kernel is tested against.
    Scalar,
    /// x86-64 AVX2 with FMA3: 8 lanes, 4 rows × 16 columns per register block.
    Avx2,
    /// x86-64 AVX-512F: 16 lanes, 8 rows × 16 columns per register block.
    Avx512,
}

// `probe` runs a SIMD kernel after its own CPU check.
#[allow(unsafe_code)]
impl TrainKernel {
    /// Every kernel this build knows, slowest first.
    pub const ALL: [TrainKernel; 3] = [TrainKernel::Scalar, TrainKernel::Avx2, TrainKernel::Avx512];

    /// The fastest kernel this CPU runs.
    pub fn best() -> TrainKernel {
        [TrainKernel::Avx512, TrainKernel::Avx2]
            .into_iter()
            .find(|k| k.is_available())
            .unwrap_or(TrainKernel::Scalar)
    }

    /// Whether this CPU can run the kernel.
    pub fn is_available(self) -> bool {
        match self {
            TrainKernel::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => {
                std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => std::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Short lowercase name for tables, logs and `--kernel`.
    pub fn name(self) -> &'static str {
        match self {
            TrainKernel::Scalar => "scalar",
            TrainKernel::Avx2 => "avx2",
            TrainKernel::Avx512 => "avx512",
        }
    }

    /// The kernel called `name` ([`TrainKernel::name`]).
    pub fn by_name(name: &str) -> Option<TrainKernel> {
        TrainKernel::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Fused multiply-adds (f32 lanes) one round of [`TrainKernel::probe`] performs.
    pub fn probe_fmas_per_round(self) -> u64 {
        match self {
            TrainKernel::Scalar => scalar::PROBE_FMAS,
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => x86_avx2::PROBE_FMAS,
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => x86_avx512::PROBE_FMAS,
            #[cfg(not(target_arch = "x86_64"))]
            _ => 0,
        }
    }

    /// A register-only loop of this kernel's fused multiply-add, for measuring the CPU's f32 FMA
    /// peak: time it and divide `rounds · probe_fmas_per_round()` by the time. Returns a value
    /// depending on every product, or `None` if this CPU lacks the kernel.
    pub fn probe(self, rounds: u64) -> Option<f32> {
        if !self.is_available() {
            return None;
        }
        Some(match self {
            // SAFETY: `is_available` said this CPU has AVX2 and FMA.
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => unsafe { x86_avx2::probe(rounds) },
            // SAFETY: `is_available` said this CPU has AVX-512F.
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => unsafe { x86_avx512::probe(rounds) },
            _ => scalar::probe(rounds),
        })
    }

    /// This kernel, if this CPU runs it: the one CPU check, after which the matrix products run
    /// it without asking again.
    pub(crate) fn available(self) -> Option<Available> {
        self.is_available().then_some(Available(self))
    }
}

/// A kernel this CPU was found to run, made only by [`TrainKernel::available`]: the trainer picks
/// its kernel once and the products below dispatch on it without a check per call (the pattern
/// of the decoder's kernels in nmat-core).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Available(TrainKernel);

// The dispatch into the SIMD kernels: an `Available` holds a kernel only after the CPU check.
#[allow(unsafe_code)]
impl Available {
    /// `kernel` if this CPU runs it, else the portable kernel, which every CPU runs.
    pub(crate) fn or_scalar(kernel: TrainKernel) -> Available {
        kernel.available().unwrap_or(Available(TrainKernel::Scalar))
    }

    /// `c[r][n] = init[n]` (or 0), then `c[r][n] = fma(a[r][k], b[k][n], c[r][n])` for
    /// k = 0 .. depth in order; every row of `a`, every (padded) column of `b`.
    pub(crate) fn matmul(
        self,
        a: &Matrix,
        depth: usize,
        b: &Matrix,
        init: Option<&[f32]>,
        c: &mut Matrix,
    ) {
        assert!(depth <= a.cols && depth <= b.rows, "matmul: depth {depth} out of range");
        assert!(c.rows == a.rows && c.stride == b.stride, "matmul: output shape");
        assert!(init.is_none_or(|i| i.len() == b.stride), "matmul: init length");
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => {
                // SAFETY: the CPU has AVX2 and FMA (an `Available` exists only then); the shapes were checked
                // against the matrices' invariants (rows × stride elements, stride % LANES == 0).
                unsafe { x86_avx2::matmul(a, depth, b, init, c) }
            }
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => {
                // SAFETY: as for AVX2, the CPU having AVX-512F.
                unsafe { x86_avx512::matmul(a, depth, b, init, c) }
            }
            _ => scalar::matmul(a, depth, b, init, c),
        }
    }

    /// Runs `f` compiled for this kernel's instruction set as far as the compiler inlines it into
    /// the call (mark the closure `#[inline(always)]`, and what it calls small or
    /// `#[inline(always)]`). Only for code whose every operation gives the same bits in any
    /// instruction set — IEEE add, multiply, divide, square root, min/max; Rust never fuses a
    /// multiply and an add by itself — so only its speed depends on the kernel.
    pub(crate) fn run<R>(self, f: impl FnOnce() -> R) -> R {
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => {
                // SAFETY: the CPU has AVX2 and FMA (an `Available` exists only then).
                unsafe { x86_avx2::run(f) }
            }
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => {
                // SAFETY: the CPU has AVX-512F (an `Available` exists only then).
                unsafe { x86_avx512::run(f) }
            }
            _ => f(),
        }
    }

    /// `c[m][n] = fma(a[k][m], b[k][n], c[m][n])` for k = 0 .. rows of `a` in order, for every
    /// row m of `c` and every (padded) column n: accumulates `aᵀ·b` into `c`.
    pub(crate) fn matmul_at_acc(self, a: &Matrix, b: &Matrix, c: &mut Matrix) {
        assert!(a.rows == b.rows, "matmul_at_acc: depth");
        assert!(c.rows <= a.cols && c.stride == b.stride, "matmul_at_acc: output shape");
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx2 => {
                // SAFETY: as in `matmul`.
                unsafe { x86_avx2::matmul_at_acc(a, b, c) }
            }
            #[cfg(target_arch = "x86_64")]
            TrainKernel::Avx512 => {
                // SAFETY: as in `matmul`.
                unsafe { x86_avx512::matmul_at_acc(a, b, c) }
            }
            _ => scalar::matmul_at_acc(a, b, c),
        }
    }
}

/// A row-major f32 matrix whose rows are padded with zeros to a multiple of [`LANES`] columns.
/// The kernels rely on `data.len() == rows · stride` and `stride % LANES == 0`; only the
/// constructor sets them.
#[derive(Clone, Debug)]
pub(crate) struct Matrix {
    data: Vec<f32>,
    rows: usize,
    cols: usize,
    stride: usize,
}

impl Matrix {
    pub fn zeros(rows: usize, cols: usize) -> Matrix {
        let stride = cols.next_multiple_of(LANES).max(LANES);
        Matrix { data: vec![0.0; rows * stride], rows, cols, stride }
    }
    pub fn rows(&self) -> usize {
        self.rows
    }
    pub fn stride(&self) -> usize {
        self.stride
    }
    /// Row `r` with its padding.
    pub fn row(&self, r: usize) -> &[f32] {
        &self.data[r * self.stride..(r + 1) * self.stride]
    }
    pub fn row_mut(&mut self, r: usize) -> &mut [f32] {
        &mut self.data[r * self.stride..(r + 1) * self.stride]
    }
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }
    pub fn as_mut_slice(&mut self) -> &mut [f32] {
        &mut self.data
    }
    /// `f` applied to every element, padding included (so `f(0)` must be 0).
    pub fn map(&self, f: impl Fn(f32) -> f32) -> Matrix {
        debug_assert!(f(0.0) == 0.0, "Matrix::map: f(0) must keep the padding zero");
        Matrix { data: self.data.iter().map(|&v| f(v)).collect(), ..*self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(rows: usize, cols: usize, seed: u32) -> Matrix {
        let mut m = Matrix::zeros(rows, cols);
        let mut s = seed;
        for r in 0..rows {
            for v in &mut m.row_mut(r)[..cols] {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                // Values of mixed magnitude, so roundings differ between fused and unfused.
                *v = ((s >> 8) as f32 / (1u32 << 24) as f32 - 0.5)
                    * if s & 1 == 0 { 3.0 } else { 1e-3 };
            }
        }
        m
    }

    /// The definition, written independently of every kernel: one f64-free fma chain per element.
    fn reference(a: &Matrix, depth: usize, b: &Matrix, init: Option<&[f32]>) -> Vec<f32> {
        let mut out = vec![0f32; a.rows * b.stride];
        for r in 0..a.rows {
            for n in 0..b.stride {
                let mut c = init.map_or(0.0, |i| i[n]);
                for k in 0..depth {
                    c = a.row(r)[k].mul_add(b.row(k)[n], c);
                }
                out[r * b.stride + n] = c;
            }
        }
        out
    }

    #[test]
    fn every_kernel_computes_the_same_fma_chains() {
        let available: Vec<Available> =
            TrainKernel::ALL.into_iter().filter_map(TrainKernel::available).collect();
        for (rows, depth, width) in [(1, 1, 1), (7, 50, 64), (13, 64, 8), (256, 64, 64), (9, 3, 33)]
        {
            let a = filled(rows, depth, 1);
            let b = filled(depth, width, 2);
            let init: Vec<f32> = filled(1, width, 3).row(0).to_vec();
            let want = reference(&a, depth, &b, Some(&init));
            // aᵀ·b accumulated onto a non-zero c, with a second operand sharing the rows of `a`.
            let b2 = filled(rows, width, 5);
            let c0 = filled(depth.min(rows), width, 4);
            let mut want_at = c0.clone();
            for m in 0..c0.rows {
                for n in 0..c0.stride {
                    let mut v = c0.row(m)[n];
                    for k in 0..rows {
                        v = a.row(k)[m].mul_add(b2.row(k)[n], v);
                    }
                    want_at.row_mut(m)[n] = v;
                }
            }
            for &k in &available {
                let mut c = Matrix::zeros(rows, width);
                k.matmul(&a, depth, &b, Some(&init), &mut c);
                assert_eq!(
                    c.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    "{} matmul {rows}×{depth}×{width}",
                    k.0.name()
                );
                let mut c = c0.clone();
                k.matmul_at_acc(&a, &b2, &mut c);
                assert_eq!(
                    c.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    want_at.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    "{} matmul_at_acc {rows}×{depth}×{width}",
                    k.0.name()
                );
            }
        }
    }

    #[test]
    fn fused_and_unfused_differ_on_these_inputs() {
        // The test above can fail: its inputs round differently with and without fusion.
        let a = filled(4, 50, 1);
        let b = filled(50, 16, 2);
        let fused = reference(&a, 50, &b, None);
        let mut unfused = vec![0f32; 4 * 16];
        for r in 0..4 {
            for n in 0..16 {
                unfused[r * 16 + n] = (0..50).fold(0f32, |c, k| c + a.row(r)[k] * b.row(k)[n]);
            }
        }
        assert_ne!(fused, unfused);
    }

    #[test]
    fn names_round_trip_and_best_is_available() {
        for k in TrainKernel::ALL {
            assert_eq!(TrainKernel::by_name(k.name()), Some(k));
        }
        assert!(TrainKernel::best().is_available());
        assert!(TrainKernel::Scalar.probe(10).is_some());
    }
}
