//! The portable kernel: the scalar twin of `PackedLayer` (`packed.rs`), which every SIMD kernel
//! is tested against, run texel by texel.

use core::ops::Range;

use super::{GROUP, Kernel, Layers};
use crate::decoder::packed::PackedLayer;
use crate::limits::MAX_WIDTH;

/// The portable kernel (runs anywhere; no instruction set to check).
#[derive(Clone, Copy, Debug)]
pub(super) struct Scalar;

impl Layers for Scalar {
    const KERNEL: Kernel = Kernel::Scalar;
    const SKIPS_PAIRS: bool = true;

    #[inline(always)]
    fn forward(self, l: &PackedLayer, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        l.forward_scalar_from(x, l.bias(), 0..l.in_pairs(), y, blocks);
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
        count: usize,
    ) {
        for ((x, y), init) in xs.iter().zip(ys.iter_mut()).zip(init).take(count) {
            l.forward_scalar_from(x, init, pairs.clone(), y, blocks);
        }
    }

    /// 8 independent scalar i32 multiply-add chains (what the scalar kernel's inner loop is).
    fn probe(self, rounds: u64) -> i64 {
        let mut acc = [0i32; 8];
        let mut x = 3i32;
        for _ in 0..rounds {
            for (k, a) in acc.iter_mut().enumerate() {
                *a = a.wrapping_add((k as i32 + 1).wrapping_mul(x));
            }
            // Opaque to the optimizer, which would otherwise sum the series in closed form.
            x = core::hint::black_box(x.wrapping_add(1));
        }
        acc.iter().map(|&a| i64::from(a)).sum()
    }
}
