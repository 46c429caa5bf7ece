//! The model being trained (`Model`): sampling a batch, the forward and backward passes of a chunk
//! over the latent taps and the layers, the step and the training loop.

use super::adam::{Adam, AdamStep, adam};
use super::latents::{
    CellGrad, GridState, LATENT_BUCKETS, LatentBuckets, LatentMode, LatentRange, LatentState,
    STATE_PER_LATENT, latent_bucket_edges,
};
use super::layers::{Dense, EvalLayer, eval_layers, hard_gelu, hard_gelu_grad};
use super::options::{Phase, Progress, TrainOptions};
use super::rng::Rng;
use super::sampler::{Drawn, ErrorSampler, REBUILD_EVERY};
use super::{CHUNK, INPUT_FRAC_BITS, SPAN};
use crate::gemm::{Available, Matrix, TrainKernel};
use crate::memhint::{huge_vec, prefetch};
use crate::profile::ModelConfig;
use crate::texset::TextureSet;
use nmat_core::internals::footprint;
use nmat_core::internals::triangle_q;
use nmat_core::{AddressMode, TermMode};
use rayon::prelude::*;

/// Bilinear taps (`add` = their weight) add `weight ×` each value to its feature; `Nearest4` taps
/// set it.
#[inline(always)]
pub(super) fn store_features(
    features: &mut [f32],
    values: impl Iterator<Item = f32>,
    add: Option<f32>,
) {
    match add {
        Some(w) => features.iter_mut().zip(values).for_each(|(f, v)| *f += w * v),
        None => features.iter_mut().zip(values).for_each(|(f, v)| *f = v),
    }
}

/// How a step runs its chunks.
#[derive(Clone, Copy)]
pub(super) struct ChunkMode {
    pub(super) kernel: Available,
    pub(super) latents: LatentMode,
    /// Whether gradients flow back to the latents (the joint phase).
    pub(super) train_latents: bool,
    /// [`TrainOptions::output_margin`].
    pub(super) output_margin: f32,
}

/// The error of output `y` against target `t` that the loss squares: with `margin` 0, `y − t`;
/// above 0, the error of `y` clamped to [0, 1] as every decoder clamps it (so past the end a
/// target sits at, an output is exact), plus how far `y` lies beyond the margin past either end
/// (so outputs stay near the range).
#[inline(always)]
pub(super) fn output_error(y: f32, t: f32, margin: f32) -> f32 {
    if margin > 0.0 {
        let inside = y.clamp(0.0, 1.0);
        inside - t + (y - y.clamp(-margin, 1.0 + margin))
    } else {
        y - t
    }
}

/// The model being trained.
pub struct Model<'a> {
    pub cfg: &'a ModelConfig,
    pub grids: Vec<GridState>,
    pub latents: Vec<f32>,
    pub layers: Vec<Dense>,
    pub address: AddressMode,
    pub(super) set: &'a TextureSet,
    pub(super) learned: Vec<usize>,
    pub(super) mip_cdf: Vec<f32>,
    /// The learned channels of every mip, texel after texel, mip after mip (`target_base`):
    /// one place per sample's read, in huge pages.
    pub(super) targets: Vec<f32>,
    pub(super) target_base: Vec<usize>,
    /// The most taps, and latents they read, of one sample (over the levels).
    pub(super) taps_per_sample: (usize, usize),
    /// The latent buckets of the grids.
    pub(super) buckets: LatentBuckets,
    /// Error-driven draws (`TrainOptions::error_share` above 0), else uniform ones.
    pub(super) sampler: Option<ErrorSampler>,
}

/// One chunk's gradients.
pub(super) struct Grads {
    /// `[outputs][inputs]` per layer.
    pub(super) w: Vec<Matrix>,
    pub(super) b: Vec<Vec<f32>>,
    /// The latent cells the chunk read, in tap order, cut into [`LATENT_BUCKETS`] ranges of
    /// latents; their gradients are in `latent_grads`.
    pub(super) latents: Vec<Vec<CellGrad>>,
    pub(super) latent_grads: Vec<f32>,
    pub(super) loss: f64,
    /// With error-driven draws: each sample's tile and squared error (mean over the learned
    /// channels), in sample order.
    pub(super) sample_errors: Vec<(u32, f32)>,
}

/// One corner of a latent cell as one sample of a chunk reads it: the cell's `channels` latents
/// (consecutive from `latent`) feed the sample's features `feature ..`, in that order.
#[derive(Clone, Copy)]
pub(super) struct Tap {
    pub(super) sample: u16,
    pub(super) feature: u16,
    pub(super) grid: u16,
    /// Bilinear taps add `weight ×` the latent's value to their feature; `Nearest4` taps set it.
    pub(super) add: bool,
    pub(super) latent: u32,
    pub(super) weight: f32,
    /// ∂feature/∂(unit latent).
    pub(super) coeff: f32,
}

/// A chunk's taps and, in the noisy mode, for every latent they read (tap after tap, channel
/// after channel) the uniform draw in [0, 1) that becomes ±½ quantization step.
#[derive(Default)]
pub(super) struct Taps {
    pub(super) list: Vec<Tap>,
    pub(super) noise: Vec<f32>,
}

impl<'a> Model<'a> {
    pub fn new(
        set: &'a TextureSet,
        cfg: &'a ModelConfig,
        address: AddressMode,
        opts: &TrainOptions,
    ) -> Model<'a> {
        let mut rng = Rng::new(opts.seed, 0xA11CE, 0);
        let mut grids = Vec::new();
        let mut base = 0;
        for g in &cfg.grids {
            let qmax = f64::from((1u32 << g.bits) - 1);
            let one = f64::from(1u32 << INPUT_FRAC_BITS);
            let step_q = (2.0 * SPAN * one / qmax).round() as i16;
            let offset_q = -((f64::from(step_q) * qmax / 2.0).round() as i16);
            grids.push(GridState {
                width: g.width,
                height: g.height,
                channels: g.channels,
                bits: g.bits,
                base,
                offset_q,
                step_q,
            });
            base += (g.width * g.height) as usize * g.channels;
        }
        // Latents start near the middle of their range, with a little randomness to break symmetry.
        let spread = opts.latent_init_spread.clamp(0.0, 1.0);
        let mut latents = huge_vec(base, 0f32);
        latents.iter_mut().for_each(|u| *u = 0.5 + spread * (rng.unit() - 0.5));
        let mut widths = vec![cfg.input_width()];
        widths.extend(&cfg.hidden);
        widths.push(cfg.outputs.max(1));
        let learned = set.learned_channels();
        let mip0 = &set.mips[0];
        let c_all = set.channel_count();
        let layers = widths
            .windows(2)
            .enumerate()
            .map(|(k, w)| {
                let hidden = k + 2 < widths.len();
                let a =
                    if hidden { (6.0 / w[0] as f32).sqrt() } else { (1.0 / w[0] as f32).sqrt() };
                let weights = (0..w[0] * w[1]).map(|_| a * (2.0 * rng.unit() - 1.0)).collect();
                let b = if hidden {
                    vec![0.0; w[1]]
                } else {
                    // Output biases start at each channel's mean.
                    (0..w[1])
                        .map(|o| {
                            let c = learned.get(o).copied().unwrap_or(0);
                            let n = mip0.data.len() / c_all;
                            (0..n).map(|i| mip0.data[i * c_all + c]).sum::<f32>() / n as f32
                        })
                        .collect()
                };
                Dense { inputs: w[0], outputs: w[1], hidden, w: weights, b }
            })
            .collect();
        // Mips drawn in proportion to their area plus a uniform share (NTC §6).
        let uniform = opts.mip_uniform_share.clamp(0.0, 1.0);
        let areas: Vec<f32> = set.mips.iter().map(|m| (m.width * m.height) as f32).collect();
        let total: f32 = areas.iter().sum();
        let n = areas.len() as f32;
        let mut acc = 0.0;
        let mip_cdf = areas
            .iter()
            .map(|a| {
                acc += (1.0 - uniform) * a / total + uniform / n;
                acc
            })
            .collect();
        let mut target_base = Vec::with_capacity(set.mips.len());
        let mut texels = 0;
        for m in &set.mips {
            target_base.push(texels * learned.len());
            texels += (m.width * m.height) as usize;
        }
        let mut targets = huge_vec(texels * learned.len(), 0f32);
        let mut at = targets.iter_mut();
        for m in &set.mips {
            for texel in m.data.chunks_exact(c_all) {
                learned.iter().zip(&mut at).for_each(|(&c, t)| *t = texel[c]);
            }
        }
        let taps_per_sample = cfg
            .levels
            .iter()
            .map(|level| {
                level
                    .iter()
                    .flat_map(|t| &t.grids)
                    .fold((0, 0), |(n, l), &g| (n + 4, l + 4 * cfg.grids[g].channels))
            })
            .fold((0, 0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        let buckets = LatentBuckets::new(latent_bucket_edges(&grids));
        let sampler = (opts.error_share > 0.0).then(|| {
            ErrorSampler::new(set.mips.iter().map(|m| (m.width, m.height)), opts.error_share)
        });
        Model {
            cfg,
            grids,
            latents,
            layers,
            address,
            set,
            learned,
            mip_cdf,
            targets,
            target_base,
            taps_per_sample,
            buckets,
            sampler,
        }
    }

    /// Draws a sample's texel: its mip, then the texel (uniformly, or by the error sampler).
    #[inline(always)]
    pub(super) fn draw(&self, rng: &mut Rng) -> Drawn {
        let r = rng.unit() * self.mip_cdf.last().copied().unwrap_or(1.0);
        let mip = self.mip_cdf.iter().position(|&c| r < c).unwrap_or(self.mip_cdf.len() - 1) as u32;
        if let Some(sampler) = &self.sampler {
            return sampler.draw(mip, rng);
        }
        let m = &self.set.mips[mip as usize];
        Drawn { at: (rng.below(m.width), rng.below(m.height), mip), tile: 0, weight: 1.0 }
    }

    /// Appends the taps of sample `s` at texel `(x, y, mip)` in the order its features read
    /// them, and asks for the latents they read (they are read a few samples later).
    #[inline(always)]
    pub(super) fn plan(&self, s: usize, (x, y, mip): (u32, u32, u32), taps: &mut Vec<Tap>) {
        let ms = &self.set.mips[mip as usize];
        let mip_size = (ms.width, ms.height);
        let level = &self.cfg.levels[usize::from(self.cfg.mip_to_level[mip as usize])];
        let mut feature = 0;
        for term in level {
            let add = term.mode != TermMode::Nearest4;
            let channels = self.grids[term.grids[0]].channels;
            for &gi in &term.grids {
                let g = &self.grids[gi];
                let fp = footprint((g.width, g.height), x, y, mip_size, self.address);
                let (fx, fy) = (fp.fx as f32, fp.fy as f32);
                let corners = [
                    (fp.x0, fp.y0, (256.0 - fx) * (256.0 - fy)),
                    (fp.x1, fp.y0, fx * (256.0 - fy)),
                    (fp.x0, fp.y1, (256.0 - fx) * fy),
                    (fp.x1, fp.y1, fx * fy),
                ];
                for (k, (cx, cy, w)) in corners.into_iter().enumerate() {
                    // Nearest4 reads every corner into its own features at full weight.
                    let (w, first) =
                        if add { (w / 65536.0, feature) } else { (1.0, feature + k * channels) };
                    if add && w == 0.0 {
                        continue;
                    }
                    prefetch(&self.latents, g.index(cx, cy, 0));
                    prefetch(&self.latents, g.index(cx, cy, channels - 1));
                    taps.push(Tap {
                        sample: s as u16,
                        feature: first as u16,
                        grid: gi as u16,
                        add,
                        latent: g.index(cx, cy, 0) as u32,
                        weight: w,
                        coeff: w * g.width_real(),
                    });
                }
            }
            feature += if add { channels } else { 4 * channels };
        }
    }

    /// Writes the latent features of `taps` (planned by [`Model::plan`]) into the rows of `x`;
    /// in the noisy mode `noise` starts with their draws.
    #[inline(always)]
    pub(super) fn evaluate(&self, taps: &[Tap], noise: &[f32], mode: LatentMode, x: &mut Matrix) {
        let mut draws = noise;
        for t in taps {
            let g = &self.grids[usize::from(t.grid)];
            let (q, low, width) = (g.qmax(), g.low(), g.width_real());
            let latents = &self.latents[t.latent as usize..][..g.channels];
            let features =
                &mut x.row_mut(usize::from(t.sample))[usize::from(t.feature)..][..g.channels];
            let add = t.add.then_some(t.weight);
            // Each channel on its own, in slices the compiler can run in SIMD lanes, written
            // straight into the features (a copy of a few floats would be a library call).
            match mode {
                LatentMode::Noisy => {
                    let (n, rest) = draws.split_at(g.channels);
                    draws = rest;
                    let values = latents
                        .iter()
                        .zip(n)
                        .map(|(&u, &n)| low + (u + (n - 0.5) / q).clamp(0.0, 1.0) * width);
                    store_features(features, values, add);
                }
                LatentMode::Quantized => {
                    let values = latents.iter().map(|&u| low + (u * q).round() / q * width);
                    store_features(features, values, add);
                }
            }
        }
    }

    /// The features after the latents: positional encoding and the mip level.
    #[inline(always)]
    pub(super) fn position_features(&self, (x, y, mip): (u32, u32, u32), row: &mut [f32]) {
        let f = INPUT_FRAC_BITS;
        let one = (1u32 << f) as f32;
        let mut at = self.cfg.input_width()
            - 4 * usize::from(self.cfg.pe_frequencies)
            - usize::from(self.cfg.lod_code != 0);
        for k in 0..self.cfg.pe_frequencies {
            for (t, p) in [(x, 0), (x, 1), (y, 0), (y, 1)] {
                row[at] = f32::from(triangle_q(t, k, p, f)) / one;
                at += 1;
            }
        }
        if self.cfg.lod_code != 0 {
            row[at] = mip as f32 * 2f32.powi(i32::from(self.cfg.lod_code) - 5);
        }
    }

    /// Where the learned channels of texel `(x, y, mip)` start in `targets`.
    pub(super) fn target_index(&self, (x, y, mip): (u32, u32, u32)) -> usize {
        let m = &self.set.mips[mip as usize];
        self.target_base[mip as usize] + (y * m.width + x) as usize * self.learned.len()
    }

    /// Draws `samples` texels (where, and the weight of each one's loss): their input features
    /// (one row each) and every latent's share in them (`taps`, in the order the random draws
    /// are made: texel, then its noise). A sample's latent features are computed `LAG` samples
    /// after its taps are planned, so the latents it reads are on their way to the cache
    /// meanwhile.
    #[inline(always)]
    pub(super) fn gather(
        &self,
        mode: LatentMode,
        rng: &mut Rng,
        samples: usize,
        taps: &mut Taps,
    ) -> (Vec<Drawn>, Matrix) {
        const LAG: usize = 8;
        assert!(samples <= CHUNK, "gather: {samples} samples do not fit a tap's sample index");
        let mut x = Matrix::zeros(samples, self.cfg.input_width());
        let mut draws = Vec::with_capacity(samples);
        // Where each sample's taps and noise draws start.
        let mut starts = Vec::with_capacity(samples + 1);
        let (per_taps, per_latents) = self.taps_per_sample;
        taps.list.clear();
        taps.list.reserve(samples * per_taps);
        taps.noise.clear();
        if mode == LatentMode::Noisy {
            taps.noise.reserve(samples * per_latents);
        }
        for s in 0..samples {
            let drawn = self.draw(rng);
            let d = drawn.at;
            starts.push((taps.list.len(), taps.noise.len()));
            self.plan(s, d, &mut taps.list);
            if mode == LatentMode::Noisy {
                for t in &taps.list[starts[s].0..] {
                    let channels = self.grids[usize::from(t.grid)].channels;
                    taps.noise.extend((0..channels).map(|_| rng.unit()));
                }
            }
            prefetch(&self.targets, self.target_index(d));
            self.position_features(d, x.row_mut(s));
            if s >= LAG {
                let ((t0, n0), (t1, _)) = (starts[s - LAG], starts[s - LAG + 1]);
                self.evaluate(&taps.list[t0..t1], &taps.noise[n0..], mode, &mut x);
            }
            draws.push(drawn);
        }
        let (t0, n0) = starts.get(samples.saturating_sub(LAG)).copied().unwrap_or((0, 0));
        self.evaluate(&taps.list[t0..], &taps.noise[n0..], mode, &mut x);
        (draws, x)
    }

    /// Forward over a chunk: the input of every layer (`x0` first) and every pre-activation.
    #[inline(always)]
    pub(super) fn forward(
        layers: &[EvalLayer],
        kernel: Available,
        x0: Matrix,
    ) -> (Vec<Matrix>, Vec<Matrix>) {
        let samples = x0.rows();
        let mut xs = vec![x0];
        let mut pres = Vec::with_capacity(layers.len());
        for (k, l) in layers.iter().enumerate() {
            let mut pre = Matrix::zeros(samples, l.outputs);
            kernel.matmul(&xs[k], l.inputs, &l.wt, Some(&l.b), &mut pre);
            if k + 1 < layers.len() {
                xs.push(if l.hidden { pre.map(hard_gelu) } else { pre.clone() });
            }
            pres.push(pre);
        }
        (xs, pres)
    }

    /// Forward and backward over one chunk of samples; returns the mean squared error (each
    /// sample's weighted by its draw's weight: an estimate of the uniform mean either way).
    #[inline(always)]
    pub(super) fn run_chunk(
        &self,
        layers: &[EvalLayer],
        how: ChunkMode,
        rng: &mut Rng,
        samples: usize,
        gr: &mut Grads,
    ) -> f64 {
        let ChunkMode { kernel, latents: mode, train_latents, output_margin } = how;
        let mut taps = Taps::default();
        let (draws, x0) = self.gather(mode, rng, samples, &mut taps);
        let (xs, pres) = Self::forward(layers, kernel, x0);
        let last = layers.len() - 1;
        let outputs = self.learned.len().max(1);
        let mut loss = 0.0f64;
        let mut g = Matrix::zeros(samples, layers[last].outputs);
        for (s, d) in draws.iter().enumerate() {
            let out = pres[last].row(s);
            let row = g.row_mut(s);
            let target = &self.targets[self.target_index(d.at)..][..self.learned.len()];
            let mut squared = 0f32;
            for (o, &t) in target.iter().enumerate() {
                let e = output_error(out[o], t, output_margin);
                squared += e * e;
                // The network's gradient weighted (unbiased); a weight of 1 changes no bit.
                row[o] = 2.0 * e / outputs as f32 * d.weight;
            }
            loss += f64::from(squared) * f64::from(d.weight);
            if self.sampler.is_some() {
                gr.sample_errors.push((d.tile, squared / outputs as f32));
            }
        }
        for k in (0..layers.len()).rev() {
            let l = &layers[k];
            if l.hidden {
                for (gv, &p) in g.as_mut_slice().iter_mut().zip(pres[k].as_slice()) {
                    *gv *= hard_gelu_grad(p);
                }
            }
            kernel.matmul_at_acc(&g, &xs[k], &mut gr.w[k]);
            for s in 0..samples {
                for (b, &gv) in gr.b[k].iter_mut().zip(g.row(s)) {
                    *b += gv;
                }
            }
            if k == 0 && !train_latents {
                break;
            }
            let mut gin = Matrix::zeros(samples, l.inputs);
            kernel.matmul(&g, l.outputs, &l.w, None, &mut gin);
            g = gin;
        }
        if train_latents {
            // A latent's gradient unweighted: a cell where the error is gets more updates, each
            // of the size a uniform draw's would have. One division a sample, not one a tap.
            let unweigh: Vec<f32> = draws.iter().map(|d| 1.0 / d.weight).collect();
            for t in &taps.list {
                let channels = self.grids[usize::from(t.grid)].channels;
                let grads = &g.row(usize::from(t.sample))[usize::from(t.feature)..][..channels];
                let at = gr.latent_grads.len();
                let unweigh = unweigh[usize::from(t.sample)];
                gr.latent_grads.extend(grads.iter().map(|&gf| gf * t.coeff * unweigh));
                if gr.latent_grads[at..].iter().any(|&gv| gv != 0.0) {
                    let cell =
                        CellGrad { latent: t.latent, at: at as u32, channels: channels as u32 };
                    gr.latents[self.buckets.of(t.latent)].push(cell);
                } else {
                    gr.latent_grads.truncate(at);
                }
            }
        }
        loss / (samples * outputs).max(1) as f64
    }

    /// Trains for `opts.steps` steps, reporting progress about 100 times.
    pub fn train(&mut self, opts: &TrainOptions, progress: &mut dyn FnMut(Progress)) {
        let steps = opts.steps.max(1);
        let joint_end = opts.joint_end();
        let mut adam_w: Vec<Adam> = self.layers.iter().map(|l| Adam::new(l.w.len())).collect();
        let mut adam_b: Vec<Adam> = self.layers.iter().map(|l| Adam::new(l.b.len())).collect();
        let mut latent_state = LatentState::new(self.latents.len());
        let mut running = None::<f64>;
        let chunks = opts.batch.div_ceil(CHUNK);
        // The kernel is chosen once (a kernel this CPU lacks falls back to the scalar one).
        let kernel = Available::or_scalar(opts.kernel());
        let (tap_count, latent_reads) = self.taps_per_sample;
        // Rate control: every `every` steps of the joint phase the latents' coded size is
        // measured and the pull toward the middle codes (`pull`, in units of the latents'
        // learning rate for a latent of typical gradient) moves by the relative error; the
        // typical gradient (`scale`, the mean of Adam's √v̂ over the latents) is measured then too.
        let centers: Vec<(usize, f32)> = self
            .grids
            .iter()
            .map(|g| (g.base, f32::from(1u8 << (g.bits - 1)) / g.qmax()))
            .collect();
        let every = (joint_end / 150).max(1);
        let mut pull = 0f32;
        let mut scale = 0f32;
        for step in 0..steps {
            if let Some(target) = opts.latent_bytes
                && step < joint_end
                && step % every == 0
                && step > 0
            {
                let now = self.coded_latent_bytes() as f64;
                let error = (now / target - 1.0) as f32;
                pull = (pull + RATE_GAIN * error).clamp(0.0, MAX_PULL);
                scale = latent_state.mean_step_scale(&self.grids, AdamStep::new(0.0, step as i32));
            }
            let phase = opts.phase(step);
            let layers = eval_layers(&self.layers, opts.int8_weights(step));
            let mode =
                if phase == Phase::Joint { LatentMode::Noisy } else { LatentMode::Quantized };
            let train_latents = opts.latents_train(step);
            let results: Vec<Grads> = (0..chunks)
                .into_par_iter()
                .map(|c| {
                    let mut rng = Rng::new(opts.seed, step as u64 + 1, c as u64);
                    let n = CHUNK.min(opts.batch - c * CHUNK);
                    let mut g = Grads {
                        w: self.layers.iter().map(|l| Matrix::zeros(l.outputs, l.inputs)).collect(),
                        b: self.layers.iter().map(|l| vec![0.0; l.outputs]).collect(),
                        // Room for twice an even share of the chunk's reads.
                        latents: (0..LATENT_BUCKETS)
                            .map(|_| {
                                let taps = if train_latents { n * tap_count } else { 0 };
                                Vec::with_capacity(2 * taps / LATENT_BUCKETS)
                            })
                            .collect(),
                        latent_grads: Vec::with_capacity(if train_latents {
                            n * latent_reads
                        } else {
                            0
                        }),
                        loss: 0.0,
                        sample_errors: Vec::new(),
                    };
                    let how = ChunkMode {
                        kernel,
                        latents: mode,
                        train_latents,
                        output_margin: opts.output_margin.unwrap_or(0.0),
                    };
                    g.loss = kernel.run(
                        #[inline(always)]
                        || self.run_chunk(&layers, how, &mut rng, n, &mut g),
                    );
                    g
                })
                .collect();
            // Sum in chunk order: the same floating-point result for any thread count.
            let inv = 1.0 / opts.batch as f32;
            let t = step as i32 + 1;
            let adam_mlp = AdamStep::new(opts.mlp_lr(step), t);
            let mut mse = 0.0;
            for k in 0..self.layers.len() {
                let layer = &mut self.layers[k];
                let mut gw = Matrix::zeros(layer.outputs, layer.inputs);
                let mut gb = vec![0f32; layer.outputs];
                for r in &results {
                    gw.as_mut_slice().iter_mut().zip(r.w[k].as_slice()).for_each(|(a, b)| *a += b);
                    gb.iter_mut().zip(&r.b[k]).for_each(|(a, b)| *a += b);
                }
                let gw: Vec<f32> = (0..layer.outputs)
                    .flat_map(|o| &gw.row(o)[..layer.inputs])
                    .map(|g| g * inv)
                    .collect();
                let gb: Vec<f32> = gb.iter().map(|g| g * inv).collect();
                adam_w[k].update(&mut layer.w, &gw, adam_mlp);
                adam_b[k].update(&mut layer.b, &gb, adam_mlp);
            }
            if train_latents {
                let adam_latents = AdamStep::new(opts.latent_lr(step), t);
                let shrink = pull * adam_latents.lr;
                let update =
                    LatentUpdate { inv, adam: adam_latents, shrink, scale, centers: &centers };
                let edges = &self.buckets.edges;
                latent_state.split(&mut self.latents, edges).into_par_iter().enumerate().for_each(
                    |(bucket, range)| {
                        kernel.run(
                            #[inline(always)]
                            || update.apply(&results, (bucket, edges[bucket]), range),
                        );
                    },
                );
            }
            for r in &results {
                mse += r.loss / chunks as f64;
            }
            if let Some(sampler) = &mut self.sampler {
                // In chunk order: the same table for any thread count.
                for r in &results {
                    sampler.record(&r.sample_errors);
                }
                if step % REBUILD_EVERY == REBUILD_EVERY - 1 {
                    sampler.rebuild();
                }
            }
            let avg = running.map_or(mse, |a: f64| 0.95 * a + 0.05 * mse);
            running = Some(avg);
            if step % (steps / 100).max(1) == 0 || step + 1 == steps {
                progress(Progress {
                    step: step + 1,
                    steps,
                    psnr: -10.0 * avg.max(1e-12).log10(),
                    phase,
                });
            }
        }
    }

    /// Largest |pre-activation| of each hidden layer over `samples` texels, with the final
    /// (fake-quantized) weights and quantized latents: sets the hidden Q-formats.
    pub fn activation_ranges(&self, samples: usize, seed: u64, kernel: TrainKernel) -> Vec<f32> {
        let kernel = Available::or_scalar(kernel);
        let layers = eval_layers(&self.layers, true);
        let mut rng = Rng::new(seed, u64::MAX, 7);
        let mut max = vec![0f32; layers.len()];
        let mut done = 0;
        let mut taps = Taps::default();
        while done < samples {
            let n = CHUNK.min(samples - done);
            let (_, x0) = self.gather(LatentMode::Quantized, &mut rng, n, &mut taps);
            let (_, pres) = Self::forward(&layers, kernel, x0);
            for (m, p) in max.iter_mut().zip(&pres) {
                *m = p.as_slice().iter().fold(*m, |m, v| m.max(v.abs()));
            }
            done += n;
        }
        max
    }

    /// The bytes the latents' codes take entropy-coded (docs/FORMAT.md §12.3), as they are now.
    pub fn coded_latent_bytes(&self) -> usize {
        let codes: Vec<Vec<u8>> = self.grids.iter().map(|g| self.codes(g)).collect();
        let shapes = self.grids.iter().map(|g| (g.width, g.height, g.channels, g.bits));
        super::latents::coded_bytes(shapes, &codes)
    }

    /// The stored code of every latent (round to the nearest level).
    pub fn codes(&self, g: &GridState) -> Vec<u8> {
        let n = (g.width * g.height) as usize * g.channels;
        self.latents[g.base..g.base + n]
            .iter()
            .map(|u| (u * g.qmax()).round().clamp(0.0, g.qmax()) as u8)
            .collect()
    }
}

/// How fast the rate control's pull follows the coded size's relative error (per measurement).
const RATE_GAIN: f32 = 0.5;

/// The strongest pull: each update may move a latent of typical gradient at most this many
/// learning rates toward its middle code (a target the latents cannot reach must not flatten
/// them all).
const MAX_PULL: f32 = 4.0;

/// One step's sparse Adam update of the latents: only those a sample read move.
pub(super) struct LatentUpdate<'c> {
    /// 1 / batch.
    pub(super) inv: f32,
    pub(super) adam: AdamStep,
    /// How far an updated latent of typical gradient moves toward its grid's middle code after
    /// its Adam step (a soft threshold: the rate control's pull; 0: none). A latent moves
    /// `shrink · scale / √v̂`: Adam's steps have the same size whatever the gradient, so the pull
    /// is scaled back by the gradient's size — latents the loss hardly feels go to the middle
    /// code first, those it needs keep their value (a proximal step with Adam's preconditioner).
    pub(super) shrink: f32,
    /// The typical √v̂ of the latents ([`LatentState::mean_step_scale`]).
    pub(super) scale: f32,
    /// Each grid's first latent and its middle code in unit scale, in order.
    pub(super) centers: &'c [(usize, f32)],
}

impl LatentUpdate<'_> {
    /// Sums the gradients of `bucket` over `results` (in chunk order) and updates the latent
    /// cells it touched; `range` is that bucket's, which starts at latent `base`. Inlined into
    /// [`Available::run`], so its loops run in the kernel's SIMD lanes.
    #[inline(always)]
    pub(super) fn apply(
        &self,
        results: &[Grads],
        (bucket, base): (usize, usize),
        range: LatentRange,
    ) {
        // Cells are read in random order: ask for them far enough ahead to cover a miss to
        // memory (an entry costs a few cycles, an update a few tens).
        const AHEAD: usize = 16;
        const S: usize = STATE_PER_LATENT;
        let LatentRange { state, touched, latents } = range;
        // The touched cells: first latent (from `base`) and channels.
        let mut cells = Vec::new();
        for r in results {
            let entries = &r.latents[bucket];
            for (j, e) in entries.iter().enumerate() {
                if let Some(next) = entries.get(j + AHEAD) {
                    let (first, channels) = (next.latent as usize - base, next.channels as usize);
                    prefetch(touched, first);
                    prefetch(state, S * first + 2 * channels);
                    prefetch(state, S * (first + channels) - 1);
                }
                let (first, channels) = (e.latent as usize - base, e.channels as usize);
                let sum = &mut state[S * first + 2 * channels..S * (first + channels)];
                let add = &r.latent_grads[e.at as usize..][..channels];
                if !touched[first] {
                    touched[first] = true;
                    sum.copy_from_slice(add);
                    cells.push((first, channels));
                } else {
                    sum.iter_mut().zip(add).for_each(|(s, &g)| *s += g);
                }
            }
        }
        for (k, &(first, channels)) in cells.iter().enumerate() {
            if let Some(&(next, c)) = cells.get(k + AHEAD) {
                prefetch(state, S * next);
                prefetch(state, S * next + c);
                prefetch(state, S * (next + c) - 1);
                prefetch(latents, next);
                prefetch(latents, next + c - 1);
            }
            touched[first] = false;
            // The mean gradient, Adam and the clamp to the unit range, one latent at a time in
            // one loop the compiler runs in SIMD lanes.
            let (m, rest) = state[S * first..S * (first + channels)].split_at_mut(channels);
            let (v, grad) = rest.split_at_mut(channels);
            let cell = m.iter_mut().zip(v.iter_mut()).zip(&*grad);
            let cell_latents = &mut latents[first..first + channels];
            for (p, ((m, v), &g)) in cell_latents.iter_mut().zip(cell) {
                adam(m, v, p, g * self.inv, self.adam);
                *p = p.clamp(0.0, 1.0);
            }
            if self.shrink > 0.0 {
                let grid = self.centers.partition_point(|&(start, _)| start <= base + first);
                let center = self.centers[grid.saturating_sub(1)].1;
                for (p, &v) in cell_latents.iter_mut().zip(v.iter()) {
                    let shrink = self.shrink * self.scale / ((v / self.adam.c2).sqrt() + 1e-8);
                    let d = *p - center;
                    *p = center + d.signum() * (d.abs() - shrink).max(0.0);
                }
            }
        }
    }
}
