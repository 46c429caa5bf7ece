//! Latent polish: once a network is trained and stored, each latent code is moved by ±1 where the
//! integer decoder then decodes the chain better, at the same coded size (docs/ENCODING.md, "The
//! latent polish").
//!
//! Training chooses the codes by rounding latents that learned with noise in place of rounding,
//! then freezes them while the network adapts; the file is judged through the integer decoder,
//! and its coded size is set by the range coder's contexts (FORMAT.md §12.2), which the training's
//! pull toward the middle code only approximates. The polish measures both exactly enough: the
//! error by decoding, the bits by the coder's own contexts.
//!
//! One grid channel's cells are tried in batches of every other cell on each axis (short of a
//! wrapped neighbour): no texel reads two cells of a batch (a texel reads 2×2 neighbouring cells),
//! so one decode of the mips that read the grid measures every cell of the batch, each texel's
//! change charged to the one cell of the batch it reads.

use crate::EncodeError;
use crate::metrics::decode_mip;
use crate::texset::TextureSet;
use nmat_core::internals::footprint;
use nmat_core::{Container, Material, MaterialSpec};

/// Cells of a batch are this far apart on each axis.
const SPACING: u32 = 2;

/// What a polish did: the chain's summed squared error (unit scale, learned channels) before and
/// after.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Polished {
    pub(crate) error_before: f64,
    pub(crate) error_after: f64,
}

/// How the polish weighs the coded size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Rate {
    /// A packed file: the moves that save bits pay for those that cost bits, so the coded size
    /// stays where training steered it.
    Neutral,
    /// A fixed-rate file: every move that decodes better.
    Free,
    /// A packed file above the size it must reach: each bit is worth `weight` × the chain's
    /// squared error per bit of the file (`bits`), so moves that save bits are kept where they
    /// decode a little worse, and moves that cost bits only where they buy more than that.
    Traded { weight: f64, bits: f64 },
}

/// Bits of each code of one grid channel given its left and upper neighbours' classes, as the
/// range coder's contexts see them (FORMAT.md §12.2), from the channel's own statistics: an
/// estimate of what the adaptive coder will spend, not its exact output.
struct RateModel {
    bits: u8,
    /// `[left class][up class][code]` → bits.
    cost: Vec<f64>,
}

/// A grid channel's codes: `codes[(y·width + x)·channels + channel]`.
#[derive(Clone, Copy)]
struct Plane<'a> {
    codes: &'a [u8],
    width: usize,
    height: usize,
    channels: usize,
    channel: usize,
}

impl<'a> Plane<'a> {
    fn of(
        codes: &'a [u8],
        (width, height, channels, channel): (usize, usize, usize, usize),
    ) -> Self {
        Plane { codes, width, height, channels, channel }
    }
    fn at(&self, x: usize, y: usize) -> u8 {
        self.codes[(y * self.width + x) * self.channels + self.channel]
    }
    fn left(&self, x: usize, y: usize) -> Option<u8> {
        (x > 0).then(|| self.at(x - 1, y))
    }
    fn up(&self, x: usize, y: usize) -> Option<u8> {
        (y > 0).then(|| self.at(x, y - 1))
    }
}

impl RateModel {
    fn new(plane: Plane<'_>, bits: u8) -> RateModel {
        let n = 1usize << bits;
        let mut model = RateModel { bits, cost: vec![0.0; 25 * n] };
        // Half a count of every code in every context: no code is free or impossible.
        let mut counts = vec![0.5f64; 25 * n];
        for y in 0..plane.height {
            for x in 0..plane.width {
                let context = model.context(plane.left(x, y), plane.up(x, y));
                counts[context * n + usize::from(plane.at(x, y))] += 1.0;
            }
        }
        for (costs, counts) in model.cost.chunks_mut(n).zip(counts.chunks(n)) {
            let total: f64 = counts.iter().sum();
            for (cost, &count) in costs.iter_mut().zip(counts) {
                *cost = -(count / total).log2();
            }
        }
        model
    }

    /// The coder's class of a neighbour: its two most significant bits, 4 where there is none.
    fn class(&self, v: Option<u8>) -> usize {
        match v {
            None => 4,
            Some(v) if self.bits > 2 => usize::from(v >> (self.bits - 2)),
            Some(v) => usize::from(v),
        }
    }

    fn context(&self, left: Option<u8>, up: Option<u8>) -> usize {
        self.class(left) * 5 + self.class(up)
    }

    fn bits_of(&self, v: u8, left: Option<u8>, up: Option<u8>) -> f64 {
        self.cost[(self.context(left, up) << self.bits) + usize::from(v)]
    }

    /// The bits of the whole plane.
    #[cfg(test)]
    fn total(&self, plane: Plane<'_>) -> f64 {
        let mut sum = 0.0;
        for y in 0..plane.height {
            for x in 0..plane.width {
                sum += self.bits_of(plane.at(x, y), plane.left(x, y), plane.up(x, y));
            }
        }
        sum
    }

    /// The change of the plane's bits when cell (x, y) goes from `old` to `new` (its own code,
    /// and the contexts of its right and lower neighbours).
    fn delta(&self, plane: Plane<'_>, (x, y): (usize, usize), old: u8, new: u8) -> f64 {
        let (left, up) = (plane.left(x, y), plane.up(x, y));
        let mut d = self.bits_of(new, left, up) - self.bits_of(old, left, up);
        if x + 1 < plane.width {
            let (r, up) = (plane.at(x + 1, y), plane.up(x + 1, y));
            d += self.bits_of(r, Some(new), up) - self.bits_of(r, Some(old), up);
        }
        if y + 1 < plane.height {
            let (b, left) = (plane.at(x, y + 1), plane.left(x, y + 1));
            d += self.bits_of(b, left, Some(new)) - self.bits_of(b, left, Some(old));
        }
        d
    }
}

/// Whether cell `i` of an axis of `n` cells is in the batch of phase `p`: every [`SPACING`]th
/// cell, short of the last `n % SPACING` (which a wrapped footprint could pair with cell 0).
/// Two cells of a batch are then never neighbours, so no texel's 2×2 cells hold two.
fn in_batch(n: u32, i: u32, p: u32) -> bool {
    i % SPACING == p && i < n - n % SPACING
}

/// Per texel of `mip`: the squared error over the learned channels (unit scale).
fn texel_errors(decoded: &[f32], set: &TextureSet, mip: usize, learned: &[usize]) -> Vec<f32> {
    let c = set.channel_count();
    decoded
        .chunks(c)
        .zip(set.mips[mip].data.chunks(c))
        .map(|(d, s)| learned.iter().map(|&k| (d[k] - s[k]) * (d[k] - s[k])).sum())
        .collect()
}

/// Polishes `spec`'s latents in place: one sweep over every grid, channel and direction.
pub(crate) fn polish(
    spec: &mut MaterialSpec,
    set: &TextureSet,
    rate: Rate,
) -> Result<Polished, EncodeError> {
    let learned = set.learned_channels();
    let mut err: Vec<Vec<f32>> = {
        let bytes = spec.to_bytes()?;
        let m = Container::parse(&bytes)?;
        (0..set.mips.len())
            .map(|mip| texel_errors(&decode_mip(&m, mip as u32), set, mip, &learned))
            .collect()
    };
    let total = |err: &[Vec<f32>]| err.iter().flatten().map(|&e| f64::from(e)).sum::<f64>();
    let error_before = total(&err);
    // Squared error a bit is worth, where the rate is traded.
    let price = match rate {
        Rate::Traded { weight, bits } => weight * error_before / bits,
        Rate::Neutral | Rate::Free => 0.0,
    };
    // Bits saved so far and not yet spent (≤ 0 where the rate is neutral).
    let mut balance = 0.0;
    for g in 0..spec.grids.len() {
        let grid = &spec.grids[g];
        let (gw, gh) = (u32::from(grid.width), u32::from(grid.height));
        let (channels, top) = (usize::from(grid.channels), (1u8 << grid.bits) - 1);
        let code_bits = grid.bits;
        let mips: Vec<usize> = (0..set.mips.len())
            .filter(|&m| {
                let level = usize::from(spec.mip_to_level[m]);
                spec.levels[level].terms.iter().any(|t| t.grids.contains(&(g as u8)))
            })
            .collect();
        if mips.is_empty() {
            continue;
        }
        for channel in 0..channels {
            let shape = (gw as usize, gh as usize, channels, channel);
            let model = RateModel::new(Plane::of(&spec.grids[g].codes, shape), code_bits);
            for step in [1i8, -1] {
                for phase in 0..SPACING * SPACING {
                    let (px, py) = (phase % SPACING, phase / SPACING);
                    // The batch: its cells moved by `step` where the code allows it.
                    let mut moved = vec![false; (gw * gh) as usize];
                    let codes = &mut spec.grids[g].codes;
                    for cy in (0..gh).filter(|&y| in_batch(gh, y, py)) {
                        for cx in (0..gw).filter(|&x| in_batch(gw, x, px)) {
                            let cell = (cy * gw + cx) as usize;
                            let code = &mut codes[cell * channels + channel];
                            if let Some(new) = code.checked_add_signed(step).filter(|&v| v <= top) {
                                *code = new;
                                moved[cell] = true;
                            }
                        }
                    }
                    if !moved.contains(&true) {
                        continue;
                    }
                    let bytes = spec.to_bytes()?;
                    let m = Container::parse(&bytes)?;
                    // Each moved cell's change of squared error, and of bits.
                    let mut gain = vec![0f64; moved.len()];
                    let mut cost = vec![0f64; moved.len()];
                    let codes = &spec.grids[g].codes;
                    for cell in (0..moved.len()).filter(|&c| moved[c]) {
                        let new = codes[cell * channels + channel];
                        let old = new.wrapping_add_signed(-step);
                        let at = (cell % gw as usize, cell / gw as usize);
                        cost[cell] = model.delta(Plane::of(codes, shape), at, old, new);
                    }
                    let measured = measure(&m, set, &mips, (gw, gh), &moved, &learned);
                    for (mip, now, owner) in &measured {
                        for (t, &c) in owner.iter().enumerate() {
                            if c != u32::MAX {
                                gain[c as usize] += f64::from(now[t]) - f64::from(err[*mip][t]);
                            }
                        }
                    }
                    let keep = choose(&moved, &gain, &cost, (rate, price), &mut balance);
                    let codes = &mut spec.grids[g].codes;
                    for (cell, (&kept, &was_moved)) in keep.iter().zip(&moved).enumerate() {
                        if was_moved && !kept {
                            let code = &mut codes[cell * channels + channel];
                            *code = code.wrapping_add_signed(-step);
                        }
                    }
                    for (mip, now, owner) in measured {
                        for (t, &c) in owner.iter().enumerate() {
                            if c != u32::MAX && keep[c as usize] {
                                err[mip][t] = now[t];
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(Polished { error_before, error_after: total(&err) })
}

/// A mip's decode after a batch's move: its texels' squared errors, and for each texel the moved
/// cell it reads (`u32::MAX`: none).
type Measured = (usize, Vec<f32>, Vec<u32>);

/// Decodes the `mips` of `m` that read the grid of `size` cells whose `moved` cells were moved.
fn measure(
    m: &Material<'_>,
    set: &TextureSet,
    mips: &[usize],
    (gw, gh): (u32, u32),
    moved: &[bool],
    learned: &[usize],
) -> Vec<Measured> {
    mips.iter()
        .map(|&mip| {
            let (w, h) = (set.mips[mip].width, set.mips[mip].height);
            let now = texel_errors(&decode_mip(m, mip as u32), set, mip, learned);
            let mut owner = vec![u32::MAX; now.len()];
            for y in 0..h {
                for x in 0..w {
                    let f = footprint((gw, gh), x, y, (w, h), m.address_mode());
                    let cell = [(f.x0, f.y0), (f.x1, f.y0), (f.x0, f.y1), (f.x1, f.y1)]
                        .into_iter()
                        .map(|(cx, cy)| cy * gw + cx)
                        .find(|&c| moved[c as usize]);
                    if let Some(c) = cell {
                        owner[(y * w + x) as usize] = c;
                    }
                }
            }
            (mip, now, owner)
        })
        .collect()
}

/// Which moved cells to keep, from each one's change of squared error (`gain`, negative = better)
/// and of bits (`cost`). Every move that decodes better where the rate is free; where it is
/// neutral, those that also save bits, then those that cost bits, the most error removed per bit
/// first, as long as the bits saved so far (`balance`, carried from batch to batch) pay for them;
/// where it is traded, every move whose change of error plus its bits at `price` is negative.
fn choose(
    moved: &[bool],
    gain: &[f64],
    cost: &[f64],
    (rate, price): (Rate, f64),
    balance: &mut f64,
) -> Vec<bool> {
    let mut keep = vec![false; moved.len()];
    let better = (0..moved.len()).filter(|&c| moved[c] && gain[c] < 0.0);
    match rate {
        Rate::Free => better.for_each(|c| keep[c] = true),
        Rate::Traded { .. } => {
            for c in (0..moved.len()).filter(|&c| moved[c]) {
                keep[c] = gain[c] + price * cost[c] < 0.0;
            }
        }
        Rate::Neutral => {
            let mut costly = Vec::new();
            for c in better {
                if cost[c] <= 0.0 {
                    keep[c] = true;
                    *balance += cost[c];
                } else {
                    costly.push(c);
                }
            }
            costly.sort_by(|&a, &b| (gain[a] / cost[a]).total_cmp(&(gain[b] / cost[b])));
            for c in costly {
                if *balance + cost[c] <= 0.0 {
                    keep[c] = true;
                    *balance += cost[c];
                }
            }
        }
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Storage, demo, metrics};
    use nmat_core::AddressMode;
    use nmat_core::internals::coded_latents_len;

    /// A 3-bit plane of smooth regions with noise in one corner, `w × h`, 2 channels.
    fn plane_codes(w: usize, h: usize) -> Vec<u8> {
        let mut state = 7u32;
        let mut codes = Vec::new();
        for y in 0..h {
            for x in 0..w {
                for c in 0..2 {
                    state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                    let smooth = ((x / 5 + y / 7 + c) % 3) as u8 + 2;
                    let noisy = x < w / 3 && y < h / 3;
                    codes.push(if noisy { ((state >> 16) % 8) as u8 } else { smooth });
                }
            }
        }
        codes
    }

    #[test]
    fn the_rate_model_estimates_what_the_coder_spends() {
        // Its estimate of each channel's bits against the range coder's output for the same
        // grid: within 10 % (the coder adapts; the model has the channel's final statistics).
        let (w, h) = (160, 120);
        let codes = plane_codes(w, h);
        let estimate: f64 = (0..2)
            .map(|c| {
                let plane = Plane::of(&codes, (w, h, 2, c));
                RateModel::new(plane, 3).total(plane)
            })
            .sum();
        let coded = 8.0 * coded_latents_len(&[(w as u32, h as u32, 2, 3, &codes)]) as f64;
        eprintln!("estimate {estimate:.0} bits, coder {coded:.0}");
        assert!((estimate / coded - 1.0).abs() < 0.10, "{estimate} against {coded}");
    }

    #[test]
    fn a_move_s_bits_are_the_plane_s_change() {
        // `delta` (the cell and its right and lower neighbours' contexts) equals the whole
        // plane's bits after the move minus before, under the same model, for every cell.
        let (w, h) = (9, 7);
        let mut codes = plane_codes(w, h);
        let model = RateModel::new(Plane::of(&codes, (w, h, 2, 1)), 3);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) * 2 + 1;
                let old = codes[i];
                let new = if old == 7 { 6 } else { old + 1 };
                let before = model.total(Plane::of(&codes, (w, h, 2, 1)));
                codes[i] = new;
                let after = model.total(Plane::of(&codes, (w, h, 2, 1)));
                let d = model.delta(Plane::of(&codes, (w, h, 2, 1)), (x, y), old, new);
                codes[i] = old;
                assert!(
                    (d - (after - before)).abs() < 1e-9,
                    "({x}, {y}): {d} against {}",
                    after - before
                );
            }
        }
    }

    #[test]
    fn no_texel_reads_two_cells_of_a_batch() {
        // For grids and mips of many sizes, both address modes and every phase: the 2×2 cells
        // a texel reads hold at most one cell of the batch.
        for (gw, w) in [(4, 16), (5, 16), (7, 13), (89, 512), (22, 128), (3, 3), (10, 4)] {
            for mode in [AddressMode::Wrap, AddressMode::Clamp] {
                for phase in 0..SPACING * SPACING {
                    let (px, py) = (phase % SPACING, phase / SPACING);
                    for y in 0..w {
                        for x in 0..w {
                            let f = footprint((gw, gw), x, y, (w, w), mode);
                            let mut cells =
                                vec![(f.x0, f.y0), (f.x1, f.y0), (f.x0, f.y1), (f.x1, f.y1)];
                            cells.sort_unstable();
                            cells.dedup();
                            let hits = cells
                                .iter()
                                .filter(|&&(cx, cy)| in_batch(gw, cx, px) && in_batch(gw, cy, py))
                                .count();
                            assert!(hits <= 1, "grid {gw}, mip {w}, {mode:?}, texel ({x}, {y})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_polish_decodes_better_at_the_same_size() {
        // A trained material (of a grid of 8×8 cells: few moves): one sweep lowers its chain
        // error, and its packed file stays within 1 % of its size; without a rate to keep, it
        // lowers the error at least as much.
        let set = demo::bricks(32);
        let (spec, encoded) = crate::refit::tests::trained_spec(&set, 1000, 2);
        let mut neutral = spec.clone();
        let done = polish(&mut neutral, &set, Rate::Neutral).unwrap();
        let bytes = neutral.to_bytes().unwrap();
        let (packed, quality) = crate::as_stored(&bytes, &set, Storage::Packed).unwrap();
        let size = |p: &Option<Vec<u8>>, fixed: &[u8]| p.as_ref().map_or(fixed.len(), Vec::len);
        let grown = size(&packed, &bytes) as f64 / size(&encoded.packed, &encoded.bytes) as f64;
        eprintln!(
            "{:.3} → {:.3} dB, size ×{grown:.4}, error {:.4} → {:.4}",
            encoded.quality.psnr, quality.psnr, done.error_before, done.error_after
        );
        assert!(done.error_after < 0.995 * done.error_before, "{done:?}");
        assert!(quality.psnr > encoded.quality.psnr);
        assert!(grown < 1.01, "the packed file grew ×{grown}");
        // The error the polish reports is the decoder's.
        let measured = metrics::chain_quality(&Container::parse(&bytes).unwrap(), &set);
        let samples: f64 = set.mips.iter().map(|m| f64::from(m.width * m.height)).sum::<f64>()
            * set.channel_count() as f64;
        let reported = metrics::psnr(done.error_after / samples);
        assert!((reported - measured.psnr).abs() < 1e-3, "{reported} against {}", measured.psnr);
        let mut free = spec;
        let unbound = polish(&mut free, &set, Rate::Free).unwrap();
        assert!(unbound.error_after <= done.error_after * 1.001, "{unbound:?} against {done:?}");
    }

    #[test]
    fn a_traded_rate_keeps_the_moves_worth_their_bits() {
        // Error changes (negative: better) and bit changes of four moved cells and one unmoved
        // one, at 0.5 error per bit: a move that saves 4 bits for 1.0 more error (−1.0 in all)
        // is kept, one that saves 1 bit for 1.0 more error (+0.5) is not; a move that buys 2.0
        // less error for 2 bits (−1.0) is kept, one that buys 0.5 for 2 bits (+0.5) is not.
        let moved = [true, true, true, true, false];
        let gain = [1.0, 1.0, -2.0, -0.5, -9.0];
        let cost = [-4.0, -1.0, 2.0, 2.0, -9.0];
        let mut balance = 0.0;
        let traded = Rate::Traded { weight: 1.0, bits: 1.0 };
        let keep = choose(&moved, &gain, &cost, (traded, 0.5), &mut balance);
        assert_eq!(keep, [true, false, true, false, false]);
        // Rate-neutral, the same moves: only the better ones that the saved bits pay for (none
        // saves bits, so none that costs bits).
        let keep = choose(&moved, &gain, &cost, (Rate::Neutral, 0.0), &mut balance);
        assert_eq!(keep, [false, false, false, false, false]);
    }

    #[test]
    fn a_traded_polish_cuts_the_coded_size() {
        // A trained material: one sweep at a heavy weight of a bit codes its latents in
        // fewer bytes (the range coder's own count) than the trained codes and than a
        // rate-neutral sweep, its error at most 10 % higher.
        let set = demo::bricks(128);
        let (spec, encoded) = crate::refit::tests::trained_spec(&set, 300, 2);
        let coded = |spec: &MaterialSpec| {
            let grids: Vec<_> = spec
                .grids
                .iter()
                .map(|g| {
                    let (w, h) = (u32::from(g.width), u32::from(g.height));
                    (w, h, u32::from(g.channels), u32::from(g.bits), &g.codes[..])
                })
                .collect();
            coded_latents_len(&grids)
        };
        let before = coded(&spec);
        let bits = 8.0 * encoded.file().len() as f64;
        let mut traded = spec.clone();
        let done = polish(&mut traded, &set, Rate::Traded { weight: 2.0, bits }).unwrap();
        let mut neutral = spec;
        polish(&mut neutral, &set, Rate::Neutral).unwrap();
        let (cut, kept) = (coded(&traded), coded(&neutral));
        let ratio = done.error_after / done.error_before;
        eprintln!("{before} → traded {cut}, neutral {kept} bytes; error ×{ratio:.4}");
        assert!(cut < before && cut < kept, "{before} → traded {cut}, neutral {kept}");
        assert!(ratio < 1.1, "{done:?}");
    }
}
