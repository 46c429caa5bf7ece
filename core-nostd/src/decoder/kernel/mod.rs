//! The integer layer kernels of a [`Decoder`](super::Decoder), one file per instruction set
//! (`scalar.rs`, `avx2.rs`, `avx512.rs`, `neon.rs`, `neon_dot.rs`), and the one place that
//! chooses among them.
//!
//! A kernel is a type implementing [`Layers`]: one integer layer of FORMAT.md §6.6 for one texel
//! or for a group of [`GROUP`] texels, bit-identical to the scalar twin
//! ([`PackedLayer::forward_scalar_from`]) whatever the inputs. Code that uses a kernel is written
//! once as a [`Job`], generic over the kernel, and handed to [`run`]: the only `match` on the
//! kernel that picks code, and the only caller of the SIMD entry points — `unsafe fn`s compiled
//! with `#[target_feature]` that run the whole job (gather and output conversion included, as the
//! job inlines into them) with the kernel's instruction set. A SIMD kernel value (`Avx2`, …) is
//! made only inside its entry point, so holding one proves the CPU check was done.
//!
//! The per-row requantization constants in the lane orders a SIMD kernel needs (its `Lanes`)
//! live in that kernel's file; [`Tables`] holds those of every kernel this target can run.

// The SIMD files use `core::arch` through pointers whose bounds follow from `PackedLayer`'s
// invariants; each `unsafe` block says why it is in bounds or why the CPU runs it.
#![allow(unsafe_code)]

extern crate alloc;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
#[cfg(target_arch = "aarch64")]
mod neon;
#[cfg(target_arch = "aarch64")]
mod neon_dot;
mod scalar;

use core::ops::Range;

use super::packed::PackedLayer;
use crate::limits::MAX_WIDTH;

/// Texels a span decodes together (the group kernels' width).
pub(super) const GROUP: usize = 4;

/// Which code computes the integer layers of a [`Decoder`](super::Decoder).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Portable Rust over the prepared layout; what the compiler makes of it on any target.
    Scalar,
    /// x86-64 AVX2: `vpmaddwd` over 8 output rows per instruction, vector requantization.
    Avx2,
    /// x86-64 AVX-512 with VNNI: `vpdpwssd` (multiply, add pairs, accumulate) over 16 rows.
    Avx512Vnni,
    /// AArch64 NEON (Advanced SIMD, part of every AArch64 CPU): `smlal`/`smlal2` widening
    /// multiply-accumulates over 4 rows per instruction, `srshl` rounding shifts and saturating
    /// narrows for requantization.
    Neon,
    /// AArch64 NEON with the dot-product extension (`dotprod`, Cortex-A55/A75 and later): `sdot`
    /// over the activations split into bytes, 8 products of a layer per instruction (twice
    /// `smlal`'s); requantization as [`Kernel::Neon`].
    NeonDot,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn best() -> Kernel {
        [Kernel::Avx512Vnni, Kernel::Avx2, Kernel::NeonDot, Kernel::Neon]
            .into_iter()
            .find(|k| k.is_available())
            .unwrap_or(Kernel::Scalar)
    }

    /// Every kernel this build knows, slowest first (those of other architectures included).
    pub const ALL: [Kernel; 5] =
        [Kernel::Scalar, Kernel::Neon, Kernel::NeonDot, Kernel::Avx2, Kernel::Avx512Vnni];

    /// Whether this CPU can run the kernel (with the `std` feature the CPU is asked; without it
    /// only what the build targets counts).
    pub fn is_available(self) -> bool {
        match self {
            Kernel::Scalar => true,
            Kernel::Avx2 => detect::avx2(),
            Kernel::Avx512Vnni => detect::avx512_vnni(),
            Kernel::Neon => detect::neon(),
            Kernel::NeonDot => detect::neon_dotprod(),
        }
    }

    /// Multiply-adds one round of [`Kernel::probe`] performs, counted as products of a layer
    /// (int8 weight × i16 activation): an `sdot` of [`Kernel::NeonDot`] makes 16 byte products,
    /// 8 of a layer's.
    pub fn probe_macs_per_round(self) -> u64 {
        match self {
            Kernel::Scalar => 8,
            Kernel::Avx2 => 128,
            Kernel::Avx512Vnni => 256,
            Kernel::Neon => 64,
            Kernel::NeonDot => 128,
        }
    }

    /// A register-only loop of this kernel's multiply-add instruction, for measuring the CPU's
    /// peak rate (the roofline of docs/PERFORMANCE.md): time `rounds` rounds and divide
    /// `rounds · probe_macs_per_round()` by the time. Returns a value depending on every product
    /// (print or `black_box` it), or `None` if this CPU lacks the kernel.
    pub fn probe(self, rounds: u64) -> Option<i64> {
        Some(run(Available::new(self)?, Probe(rounds)))
    }

    /// Short lowercase name for tables and logs.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512Vnni => "avx512-vnni",
            Kernel::Neon => "neon",
            Kernel::NeonDot => "neon-dotprod",
        }
    }
}

/// What the CPU (with `std`) or the build target (without) offers.
mod detect {
    #[cfg(all(target_arch = "x86_64", feature = "std"))]
    pub(super) fn avx2() -> bool {
        extern crate std;
        std::is_x86_feature_detected!("avx2")
    }

    #[cfg(all(target_arch = "x86_64", feature = "std"))]
    pub(super) fn avx512_vnni() -> bool {
        extern crate std;
        std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512vnni")
    }

    #[cfg(all(target_arch = "x86_64", not(feature = "std")))]
    pub(super) fn avx2() -> bool {
        cfg!(target_feature = "avx2")
    }

    #[cfg(all(target_arch = "x86_64", not(feature = "std")))]
    pub(super) fn avx512_vnni() -> bool {
        cfg!(all(
            target_feature = "avx512f",
            target_feature = "avx512bw",
            target_feature = "avx512vnni"
        ))
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub(super) fn avx2() -> bool {
        false
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub(super) fn avx512_vnni() -> bool {
        false
    }

    /// NEON is part of the AArch64 base architecture (every AArch64 Rust target enables it); the
    /// kernel is compiled in exactly when the target has it.
    pub(super) fn neon() -> bool {
        cfg!(all(target_arch = "aarch64", target_feature = "neon"))
    }

    #[cfg(all(target_arch = "aarch64", feature = "std"))]
    pub(super) fn neon_dotprod() -> bool {
        extern crate std;
        neon() && std::arch::is_aarch64_feature_detected!("dotprod")
    }

    #[cfg(not(all(target_arch = "aarch64", feature = "std")))]
    pub(super) fn neon_dotprod() -> bool {
        cfg!(all(target_arch = "aarch64", target_feature = "neon", target_feature = "dotprod"))
    }
}

/// A kernel this CPU was found to run: made only by [`Available::new`], after
/// [`Kernel::is_available`] said yes. [`run`] relies on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Available(Kernel);

impl Available {
    pub(super) fn new(kernel: Kernel) -> Option<Available> {
        kernel.is_available().then_some(Available(kernel))
    }

    /// [`Kernel::best`], which is available by definition.
    pub(super) fn best() -> Available {
        Available::new(Kernel::best()).unwrap_or(Available(Kernel::Scalar))
    }

    pub(super) fn kernel(self) -> Kernel {
        self.0
    }
}

/// One integer layer in one instruction set (see the module documentation).
pub(super) trait Layers: Copy {
    /// Which kernel this is (the dispatch test asks it).
    #[cfg_attr(not(test), allow(dead_code))]
    const KERNEL: Kernel;

    /// One integer layer: `y[o]` for every row of the 8-row blocks selected in `blocks` (bit b:
    /// rows 8b..8b + 8; a kernel may compute more rows, never fewer).
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32);

    /// [`Layers::forward`] for a group of texels, with texel `t`'s accumulators starting at
    /// `init[t]` (per row; the bias for a plain layer; a row shorter than the layer's padded
    /// width counts as the bias) and only input pairs `pairs` summed (a range within the
    /// layer's; [`PackedLayer::forward_scalar_from`] per texel). The first `count` texels are
    /// wanted; a kernel may compute all of them.
    #[allow(clippy::too_many_arguments)]
    fn forward_group(
        self,
        l: &PackedLayer,
        xs: &[[i16; MAX_WIDTH]; GROUP],
        init: [&[i32]; GROUP],
        pairs: Range<usize>,
        ys: &mut [[i16; MAX_WIDTH]; GROUP],
        blocks: u32,
        count: usize,
    );

    /// Whether [`Layers::forward_group`] saves the work of the pairs before `pairs.start`, and
    /// [`Layers::sums`] is fast enough that a span reuses the sums over inputs that stay the same
    /// for several texels (measured on x86-64: docs/PERFORMANCE.md, "Nearest features summed
    /// once per cell").
    const SKIPS_PAIRS: bool;

    /// Per row, the sum over input pairs `pairs` of `x` (no bias, wrapping like the
    /// accumulators) into the first `out_pad` entries of `sums` ([`PackedLayer::pair_sums`]).
    #[inline(always)]
    fn sums(
        self,
        l: &PackedLayer,
        x: &[i16; MAX_WIDTH],
        pairs: Range<usize>,
        sums: &mut [i32; MAX_WIDTH],
    ) {
        l.pair_sums(x, pairs, sums);
    }

    /// `rounds` rounds of independent chains of the kernel's multiply-add instruction on
    /// registers only ([`Kernel::probe`]).
    fn probe(self, rounds: u64) -> i64;
}

/// Work written once for every kernel; [`run`] calls it with the kernel of a decoder. `run`
/// must be `#[inline(always)]`: it is then compiled inside the kernel's `#[target_feature]`
/// entry point, and what it inlines (the gather, the output conversion) gets the kernel's
/// instruction set too.
pub(super) trait Job {
    type Output;
    fn run<K: Layers>(self, kernel: K) -> Self::Output;
}

/// Runs `job` with `kernel`: the one place a kernel is chosen.
pub(super) fn run<J: Job>(kernel: Available, job: J) -> J::Output {
    match kernel.0 {
        // Each arm: an `Available` holds a kernel only after `Kernel::is_available` said this
        // CPU runs its instruction set (`Available::new`).
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX2 (see above).
        Kernel::Avx2 => unsafe { avx2::run(job) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX-512 F, BW and VNNI (see above).
        Kernel::Avx512Vnni => unsafe { avx512::run(job) },
        #[cfg(target_arch = "aarch64")]
        // SAFETY: the CPU has NEON (see above).
        Kernel::Neon => unsafe { neon::run(job) },
        #[cfg(target_arch = "aarch64")]
        // SAFETY: the CPU has NEON and the dot-product extension (see above).
        Kernel::NeonDot => unsafe { neon_dot::run(job) },
        _ => job.run(scalar::Scalar),
    }
}

/// The arguments of [`Kernel::probe`].
struct Probe(u64);

impl Job for Probe {
    type Output = i64;
    #[inline(always)]
    fn run<K: Layers>(self, kernel: K) -> i64 {
        kernel.probe(self.0)
    }
}

#[cfg(test)]
mod tests;
