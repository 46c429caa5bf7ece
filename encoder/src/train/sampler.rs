//! Error-driven draws of texels (`TrainOptions::error_share`): every mip is cut into tiles, each
//! tile keeps a running mean of the squared error of the samples drawn in it, and a share of each
//! mip's draws picks its tile in proportion to that error (the rest in proportion to the tile's
//! area, as uniform draws do). A texel's loss is weighted by its probability under uniform draws
//! over its probability here, so the network's gradient is an unbiased estimate of the same
//! mean squared error; a latent's gradient is taken unweighted, so a cell where the error is
//! gets more updates, not smaller ones (docs/ENCODING.md, "The trainer").

use super::rng::Rng;

/// Tiles are `2^shift` texels on a side: 8 at least, more where a mip would have more than
/// [`MAX_TILES`] of them (the cumulative table is `f32`; its steps must stay well above its
/// rounding).
const MIN_SHIFT: u32 = 3;
const MAX_TILES: u64 = 1 << 16;
/// How far a tile's running error moves toward each new sample's.
const ERROR_RATE: f32 = 0.1;
/// The table the draws read is rebuilt from the running errors every this many steps.
pub(super) const REBUILD_EVERY: usize = 4;

/// One mip's tiles.
struct MipTiles {
    width: u32,
    height: u32,
    shift: u32,
    across: u32,
    /// Index of its first tile in [`ErrorSampler::error`].
    first: usize,
    count: usize,
}

impl MipTiles {
    /// The area (texels) of each tile, in tile order.
    fn areas(&self) -> impl Iterator<Item = f32> + '_ {
        let side = 1u32 << self.shift;
        let rows =
            (0..self.height).step_by(side as usize).map(move |y0| side.min(self.height - y0));
        rows.flat_map(move |h| {
            (0..self.width)
                .step_by(side as usize)
                .map(move |x0| (side.min(self.width - x0) * h) as f32)
        })
    }

    /// Corner and size (in texels) of tile `i` of this mip.
    fn tile(&self, i: usize) -> (u32, u32, u32, u32) {
        let i = i as u32;
        let (x0, y0) = ((i % self.across) << self.shift, (i / self.across) << self.shift);
        let side = 1u32 << self.shift;
        (x0, y0, side.min(self.width - x0), side.min(self.height - y0))
    }
}

/// A texel drawn for a sample: where, the tile it fell in, and the weight of its loss.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Drawn {
    pub(super) at: (u32, u32, u32),
    pub(super) tile: u32,
    pub(super) weight: f32,
}

/// The tiles of every mip, their running errors and the table draws read.
pub(super) struct ErrorSampler {
    share: f32,
    mips: Vec<MipTiles>,
    /// Running mean squared error per texel of each tile (unit scale, over the learned
    /// channels); 1 (far above any trained error) until the tile is first drawn.
    error: Vec<f32>,
    /// Per mip, the cumulative probability of its tiles (not normalized).
    cdf: Vec<f32>,
}

impl ErrorSampler {
    /// A sampler for mips of `sizes` (width, height) whose draws follow the error with `share`
    /// (0 < share ≤ 1); all tiles start alike, so the first draws are uniform.
    pub(super) fn new(sizes: impl Iterator<Item = (u32, u32)>, share: f32) -> ErrorSampler {
        let mut mips = Vec::new();
        let mut first = 0;
        for (width, height) in sizes {
            let texels = u64::from(width) * u64::from(height);
            let mut shift = MIN_SHIFT;
            while (texels >> (2 * shift)) > MAX_TILES {
                shift += 1;
            }
            let across = width.div_ceil(1 << shift);
            let count = (across * height.div_ceil(1 << shift)) as usize;
            mips.push(MipTiles { width, height, shift, across, first, count });
            first += count;
        }
        let mut sampler = ErrorSampler {
            share: share.clamp(0.0, 1.0),
            mips,
            error: vec![1.0; first],
            cdf: vec![0.0; first],
        };
        sampler.rebuild();
        sampler
    }

    /// Rebuilds the table from the running errors: a tile's probability within its mip is
    /// `(1 − share)·area/texels + share·error·area/Σ(error·area)`.
    pub(super) fn rebuild(&mut self) {
        for mip in &self.mips {
            let texels = (mip.width * mip.height) as f32;
            let errors = &self.error[mip.first..][..mip.count];
            let total: f32 = errors.iter().zip(mip.areas()).map(|(&e, a)| e * a).sum();
            let mut acc = 0f32;
            let cdf = &mut self.cdf[mip.first..][..mip.count];
            for ((c, &e), a) in cdf.iter_mut().zip(errors).zip(mip.areas()) {
                acc += (1.0 - self.share) * a / texels + self.share * e * a / total.max(1e-30);
                *c = acc;
            }
        }
    }

    /// Draws a texel of `mip`: its tile from the table, then a uniform texel of the tile.
    #[inline(always)]
    pub(super) fn draw(&self, mip: u32, rng: &mut Rng) -> Drawn {
        let tiles = &self.mips[mip as usize];
        let cdf = &self.cdf[tiles.first..][..tiles.count];
        let top = cdf.last().copied().unwrap_or(1.0);
        let r = rng.unit() * top;
        let i = cdf.partition_point(|&c| c <= r).min(cdf.len() - 1);
        let p = (cdf[i] - if i > 0 { cdf[i - 1] } else { 0.0 }) / top;
        let (x0, y0, w, h) = tiles.tile(i);
        let (x, y) = (x0 + rng.below(w), y0 + rng.below(h));
        let uniform = (w * h) as f32 / (tiles.width * tiles.height) as f32;
        Drawn { at: (x, y, mip), tile: (tiles.first + i) as u32, weight: uniform / p.max(1e-12) }
    }

    /// Moves each drawn tile's running error toward its sample's (in the order given).
    pub(super) fn record(&mut self, samples: &[(u32, f32)]) {
        for &(tile, error) in samples {
            let e = &mut self.error[tile as usize];
            *e += ERROR_RATE * (error - *e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_follow_the_error_and_their_weights_undo_it() {
        // A 40×24 mip (5×3 tiles of 8, all full) whose corner tile 0 has 50 times the error of
        // the others, half the draws following the error: tile 0 gets 0.5/15 + 0.5·50/64 of them
        // (it holds 50/64 of the error) instead of 1/15, and the weighted mean of any function
        // of the texel is its mean over the mip (here x + 3y: 19.5 + 3·11.5).
        let mut sampler = ErrorSampler::new([(40, 24)].into_iter(), 0.5);
        let errors: Vec<(u32, f32)> =
            (0..15).map(|t| (t, if t == 0 { 50.0 } else { 1.0 })).collect();
        for _ in 0..200 {
            sampler.record(&errors);
        }
        sampler.rebuild();
        let mut rng = Rng::new(3, 1, 4);
        let n = 400_000;
        let (mut in_hot, mut weighted, mut weights) = (0usize, 0f64, 0f64);
        for _ in 0..n {
            let d = sampler.draw(0, &mut rng);
            let (x, y, mip) = d.at;
            assert!(x < 40 && y < 24 && mip == 0);
            assert_eq!(d.tile, (y / 8) * 5 + x / 8, "tile of {:?}", d.at);
            in_hot += usize::from(d.tile == 0);
            weighted += f64::from(d.weight) * f64::from(x + 3 * y);
            weights += f64::from(d.weight);
        }
        let expected = 0.5 / 15.0 + 0.5 * 50.0 / 64.0;
        let share = in_hot as f64 / n as f64;
        assert!((share - expected).abs() < 0.01, "hot tile drawn {share}, expected {expected}");
        let mean = weighted / n as f64;
        assert!((mean - (19.5 + 3.0 * 11.5)).abs() < 0.3, "weighted mean {mean}");
        assert!((weights / n as f64 - 1.0).abs() < 0.01, "mean weight {}", weights / n as f64);
    }

    #[test]
    fn partial_tiles_and_large_mips_are_drawn_whole() {
        // 13×5: tiles of 8×5 and 5×5; every texel is reachable and the weights of a fresh
        // sampler are 1 (all tiles alike: uniform draws).
        let sampler = ErrorSampler::new([(13, 5)].into_iter(), 0.3);
        let mut rng = Rng::new(1, 2, 3);
        let mut seen = [false; 13 * 5];
        for _ in 0..20_000 {
            let d = sampler.draw(0, &mut rng);
            let (x, y, _) = d.at;
            seen[(y * 13 + x) as usize] = true;
            assert!((d.weight - 1.0).abs() < 1e-5, "weight {} at {:?}", d.weight, d.at);
        }
        assert!(seen.iter().all(|&s| s), "some texels never drawn");
        // 4096² has 2^18 tiles of 8: its tiles grow to 16 (2^16 of them).
        let big = ErrorSampler::new([(4096, 4096)].into_iter(), 0.2);
        assert_eq!((big.mips[0].shift, big.mips[0].count), (4, 1 << 16));
    }
}
