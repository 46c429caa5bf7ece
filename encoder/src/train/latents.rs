//! The latent grids as parameters: their place and quantizer (`GridState`), their Adam state, and
//! the fixed buckets in which a step's sparse latent updates run side by side.

use super::INPUT_FRAC_BITS;
use super::adam::AdamStep;
use crate::memhint::huge_vec;

/// A latent grid's place in the flat parameter vector and its exact quantizer.
#[derive(Clone, Debug)]
pub struct GridState {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub bits: u8,
    pub base: usize,
    pub offset_q: i16,
    pub step_q: i16,
}

impl GridState {
    pub(super) fn qmax(&self) -> f32 {
        ((1u32 << self.bits) - 1) as f32
    }
    /// Real value of unit parameter `u` (code = u · qmax): exactly what the decoder dequantizes.
    pub(super) fn low(&self) -> f32 {
        f32::from(self.offset_q) / (1 << INPUT_FRAC_BITS) as f32
    }
    pub(super) fn width_real(&self) -> f32 {
        f32::from(self.step_q) * self.qmax() / (1 << INPUT_FRAC_BITS) as f32
    }
    pub(super) fn index(&self, x: u32, y: u32, c: usize) -> usize {
        self.base + ((y * self.width + x) as usize) * self.channels + c
    }
}

/// The coded size in bytes (docs/FORMAT.md §12.3, what `nmat_core::pack` writes) of grids of
/// these shapes — (width, height, channels, bits) — holding `codes`, one list per grid.
pub(crate) fn coded_bytes(
    shapes: impl Iterator<Item = (u32, u32, usize, u8)>,
    codes: &[Vec<u8>],
) -> usize {
    let grids: Vec<(u32, u32, u32, u32, &[u8])> = shapes
        .zip(codes)
        .map(|((w, h, c, b), codes)| (w, h, c as u32, u32::from(b), codes.as_slice()))
        .collect();
    nmat_core::internals::coded_latents_len(&grids)
}

/// How latents enter the forward pass.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum LatentMode {
    Noisy,
    Quantized,
}

/// The latents' optimizer state: per latent cell (cells are whole, consecutive runs of latents)
/// its Adam moments and this step's summed gradient side by side — the `c` latents of the cell at
/// latent `first` own `state[3 first .. 3 (first + c)]`, first `m`, then `v`, then the sums — so
/// the random reads of one cell touch a line or two, not one per array; and, at its first latent,
/// whether this step touched the cell yet — a byte, zero between steps, so the flags of a bucket
/// stay in the cache.
pub(super) struct LatentState {
    pub(super) state: Vec<f32>,
    pub(super) touched: Vec<bool>,
}

/// Values of [`LatentState::state`] per latent.
pub(super) const STATE_PER_LATENT: usize = 3;

impl LatentState {
    pub(super) fn new(n: usize) -> LatentState {
        LatentState { state: huge_vec(STATE_PER_LATENT * n, 0.0), touched: vec![false; n] }
    }

    /// The mean of Adam's √v̂ (`v / step.c2`) over the latents of `grids` that have had a
    /// gradient: the size of a typical latent's gradient. Summed in latent order (the same
    /// value for any thread count).
    pub(super) fn mean_step_scale(&self, grids: &[GridState], step: AdamStep) -> f32 {
        let (mut sum, mut n) = (0f64, 0usize);
        for g in grids {
            let c = g.channels;
            for cell in 0..(g.width * g.height) as usize {
                let first = g.base + cell * c;
                let v = &self.state[STATE_PER_LATENT * first + c..STATE_PER_LATENT * first + 2 * c];
                for &v in v.iter().filter(|&&v| v > 0.0) {
                    sum += f64::from((v / step.c2).sqrt());
                    n += 1;
                }
            }
        }
        if n > 0 { (sum / n as f64) as f32 } else { 0.0 }
    }

    /// The state cut at `edges` (see [`split_at_edges`]), with `latents` cut the same way.
    pub(super) fn split<'s>(
        &'s mut self,
        latents: &'s mut [f32],
        edges: &[usize],
    ) -> Vec<LatentRange<'s>> {
        let state_edges: Vec<usize> = edges.iter().map(|&e| STATE_PER_LATENT * e).collect();
        split_at_edges(latents, edges)
            .into_iter()
            .zip(split_at_edges(&mut self.state, &state_edges))
            .zip(split_at_edges(&mut self.touched, edges))
            .map(|((latents, state), touched)| LatentRange { state, touched, latents })
            .collect()
    }
}

/// One bucket's latents and their state.
pub(super) struct LatentRange<'s> {
    pub(super) state: &'s mut [f32],
    pub(super) touched: &'s mut [bool],
    pub(super) latents: &'s mut [f32],
}

/// One tap's gradients: of latents `latent ..` (`channels` of them, one cell), at `at` in its
/// chunk's `latent_grads`. A cell whose gradients are all zero is not recorded (it stays
/// untouched).
#[derive(Clone, Copy)]
pub(super) struct CellGrad {
    pub(super) latent: u32,
    pub(super) at: u32,
    pub(super) channels: u32,
}

/// The latents are updated in this many ranges side by side (a fixed number: every latent's
/// gradient is summed in chunk order, then tap order, whatever the thread count).
pub(super) const LATENT_BUCKETS: usize = 16;

/// Where each bucket of latents starts (and, last, the end of the latents): near even shares,
/// on cell boundaries, so a cell's latents share a bucket.
pub(super) fn latent_bucket_edges(grids: &[GridState]) -> Vec<usize> {
    let total = grids.iter().map(|g| (g.width * g.height) as usize * g.channels).sum::<usize>();
    let mut edges: Vec<usize> = (0..LATENT_BUCKETS)
        .map(|k| {
            let even = total * k / LATENT_BUCKETS;
            let g = grids.iter().rev().find(|g| g.base <= even).expect("latent_bucket_edges: grid");
            (g.base + (even - g.base).next_multiple_of(g.channels.max(1))).min(total)
        })
        .collect();
    edges.push(total);
    edges
}

/// `slice` cut at `edges` (ascending, from 0 to its length).
pub(super) fn split_at_edges<'s, T>(mut slice: &'s mut [T], edges: &[usize]) -> Vec<&'s mut [T]> {
    let mut parts = Vec::with_capacity(edges.len());
    for w in edges.windows(2) {
        let (head, tail) = std::mem::take(&mut slice).split_at_mut(w[1] - w[0]);
        parts.push(head);
        slice = tail;
    }
    parts
}

/// Finds a latent's bucket without a search: the bucket of every block of
/// 2^[`LatentBuckets::BLOCK_BITS`] latents' first latent, then the edges that fall inside it.
pub(super) struct LatentBuckets {
    /// [`latent_bucket_edges`].
    pub(super) edges: Vec<usize>,
    pub(super) by_block: Vec<u8>,
}

impl LatentBuckets {
    pub(super) const BLOCK_BITS: u32 = 6;

    pub(super) fn new(edges: Vec<usize>) -> LatentBuckets {
        const { assert!(LATENT_BUCKETS <= 256, "LatentBuckets: a bucket index is a u8") };
        let total = edges.last().copied().unwrap_or(0);
        let by_block = (0..total.div_ceil(1 << Self::BLOCK_BITS))
            .map(|b| (edges.partition_point(|&e| e <= b << Self::BLOCK_BITS) - 1) as u8)
            .collect();
        LatentBuckets { edges, by_block }
    }

    /// The bucket of latent `latent`.
    pub(super) fn of(&self, latent: u32) -> usize {
        let mut k = usize::from(self.by_block[(latent >> Self::BLOCK_BITS) as usize]);
        while self.edges[k + 1] <= latent as usize {
            k += 1;
        }
        k
    }
}
