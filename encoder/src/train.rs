//! The CPU trainer (docs/ENCODING.md): latents and MLP optimized jointly with Adam and a cosine
//! schedule under simulated quantization (uniform noise), then latents frozen at their quantized
//! values while the MLP is fine-tuned, then quantization-aware fine-tuning of the int8 weights
//! (straight-through estimator) so the integer decoder is the trained model.
//!
//! Forward and backward are written by hand (the NTC paper's own trainer was 10× faster than a
//! general framework): a chunk of samples goes through each layer as one matrix product on the
//! SIMD kernels of `gemm` (fixed fma chains: the same bits on every kernel). A step's batch is
//! cut into fixed chunks processed in parallel; their gradients are summed in chunk order, so the
//! result is the same for any number of threads and any kernel.

use crate::gemm::{Matrix, TrainKernel};
use crate::memhint::{huge_vec, prefetch};
use crate::profile::ModelConfig;
use crate::texset::TextureSet;
use nmat_core::latents::footprint;
use nmat_core::posenc::triangle_q;
use nmat_core::{Activation, AddressMode, LayerSpec, TermMode};
use rayon::prelude::*;

/// Fraction bits of the MLP input: latents span ±1.5, fusion chains of 4 grids ±6, within ±8.
pub const INPUT_FRAC_BITS: u8 = 12;
/// Fraction bits of the last layer: outputs are unit values, Q.13 holds ±4.
pub const OUTPUT_FRAC_BITS: u8 = 13;
/// Latents are dequantized onto [−SPAN, SPAN].
const SPAN: f64 = 1.5;
/// Samples per parallel work item (fixed: it, not the thread count, shapes the arithmetic).
const CHUNK: usize = 256;

/// Default optimizer steps: a 1024² four-map material trains in 1–3½ minutes on 2 cores
/// (docs/ENCODING.md, "Tuning").
pub const DEFAULT_STEPS: usize = 30_000;

/// Encode time traded for quality (`--effort`): a quarter of a command's default steps, or twice
/// them. `Max` doubles the steps at the same batch: at the default profile `ntc-0.5` that gained
/// 0.16–0.43 dB on the three development materials tried, for about twice the time; a larger batch
/// (what `Max` was before) lost up to 1.2 dB there (docs/ENCODING.md, "Speed").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Effort {
    /// A quarter of the steps: for previews and iteration.
    Fast,
    /// The default steps and batch.
    #[default]
    Default,
    /// Twice the steps, about twice the time.
    Max,
}

impl Effort {
    /// Steps and batch at this effort when `default_steps` and `default_batch` are the defaults.
    pub fn schedule(self, default_steps: usize, default_batch: usize) -> (usize, usize) {
        match self {
            Effort::Fast => ((default_steps / 4).max(1), default_batch),
            Effort::Default => (default_steps, default_batch),
            Effort::Max => (default_steps.saturating_mul(2), default_batch),
        }
    }
}

/// How an encode trains. Beyond steps and seed these are tuning knobs (`nmat-sweep` measures
/// them); the defaults are the tuned values.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub steps: usize,
    /// Texels per optimizer step.
    pub batch: usize,
    pub seed: u64,
    /// Peak learning rates of the MLP and the latents (cosine schedule down to 1 %).
    pub lr_mlp: f32,
    pub lr_latents: f32,
    /// Percent of the steps that train latents and MLP together; the last `qat_percent` train
    /// the MLP with fake-quantized int8 weights; the steps between, the MLP on frozen latents.
    pub joint_percent: u32,
    pub qat_percent: u32,
    /// Share of the samples drawn uniformly over the mips; the rest in proportion to their area.
    pub mip_uniform_share: f32,
    /// Latents start at the middle of their range ± half this (a unit range is 1).
    pub latent_init_spread: f32,
    /// Matrix-product kernel; `None` picks [`TrainKernel::best`]. The file does not depend on it.
    pub kernel: Option<TrainKernel>,
}

impl TrainOptions {
    /// The kernel that runs: the one asked for, else the fastest this CPU has.
    pub fn kernel(&self) -> TrainKernel {
        self.kernel.unwrap_or_else(TrainKernel::best)
    }

    /// The phase of step `step` (from 0).
    pub fn phase(&self, step: usize) -> Phase {
        let steps = self.steps.max(1);
        if step < self.joint_end() {
            Phase::Joint
        } else if step < steps * 100usize.saturating_sub(self.qat_percent as usize) / 100 {
            Phase::FrozenLatents
        } else {
            Phase::QuantizationAware
        }
    }

    /// The first step after the joint phase.
    fn joint_end(&self) -> usize {
        self.steps.max(1) * (self.joint_percent as usize).min(100) / 100
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            steps: DEFAULT_STEPS,
            batch: 2048,
            seed: 1,
            lr_mlp: 1e-2,
            lr_latents: 4e-2,
            joint_percent: 90,
            qat_percent: 3,
            mip_uniform_share: 0.1,
            latent_init_spread: 0.05,
            kernel: None,
        }
    }
}

/// Reported during training.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub step: usize,
    pub steps: usize,
    /// PSNR of the running training loss (unit scale, all learned channels), dB.
    pub psnr: f64,
    pub phase: Phase,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Latents and MLP, latents under uniform quantization noise.
    Joint,
    /// Latents frozen at their quantized values; MLP only.
    FrozenLatents,
    /// MLP with fake-quantized int8 weights.
    QuantizationAware,
}

/// Floating-point operations (2 per multiply-add) of the MLP's matrix products per training
/// sample in `phase`: forward, weight gradients, and input gradients of every layer but the
/// first — of the first too while latents train. What `nmat bench-train` counts as work.
pub fn mlp_flops_per_sample(cfg: &ModelConfig, phase: Phase) -> u64 {
    let mut widths = vec![cfg.input_width()];
    widths.extend(&cfg.hidden);
    widths.push(cfg.outputs.max(1));
    let products: Vec<u64> = widths.windows(2).map(|w| (w[0] * w[1]) as u64).collect();
    let all: u64 = products.iter().sum();
    let input_grads = if phase == Phase::Joint { all } else { all - products[0] };
    2 * (2 * all + input_grads)
}

/// SplitMix64, seeded per (seed, step, chunk) so work can be split freely.
struct Rng(u64);

impl Rng {
    fn new(a: u64, b: u64, c: u64) -> Rng {
        let mut r =
            Rng(a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ c.wrapping_mul(0xD1B5_4A32_D192_ED03));
        r.next();
        r
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn below(&mut self, n: u32) -> u32 {
        (((self.next() >> 32) * u64::from(n)) >> 32) as u32
    }
}

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
    fn qmax(&self) -> f32 {
        ((1u32 << self.bits) - 1) as f32
    }
    /// Real value of unit parameter `u` (code = u · qmax): exactly what the decoder dequantizes.
    fn low(&self) -> f32 {
        f32::from(self.offset_q) / (1 << INPUT_FRAC_BITS) as f32
    }
    fn width_real(&self) -> f32 {
        f32::from(self.step_q) * self.qmax() / (1 << INPUT_FRAC_BITS) as f32
    }
    fn index(&self, x: u32, y: u32, c: usize) -> usize {
        self.base + ((y * self.width + x) as usize) * self.channels + c
    }
}

#[derive(Clone, Debug)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub hidden: bool,
    /// Row-major `[outputs][inputs]`.
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

/// Weights as the forward pass uses them (possibly fake-quantized), in both layouts.
struct EvalLayer {
    inputs: usize,
    outputs: usize,
    hidden: bool,
    /// `[inputs][outputs]`: the forward product `x · wᵀ`.
    wt: Matrix,
    /// `[outputs][inputs]`: the backward product `g · w`.
    w: Matrix,
    /// Padded to the columns of `wt`.
    b: Vec<f32>,
}

/// Per-row int8 scale: max |w| / 127, but never so small that the row's bias (in accumulator
/// units, `bias / (scale · 2^−in_frac)`) leaves the decoder's bias bound, nor below `min_scale`
/// (the decoder's shift range). A row whose weights died during training but whose bias carries
/// the output is the case the bias term exists for.
pub fn row_scale(row: &[f32], bias: f32, in_frac_bits: u8, min_scale: f32) -> f32 {
    let max = row.iter().fold(0f32, |m, w| m.max(w.abs()));
    let bias_limit = f64::from(i32::MAX) - row.len() as f64 * 127.0 * 32768.0;
    let for_bias = (f64::from(bias.abs()) * f64::from(1u32 << in_frac_bits) / bias_limit) as f32;
    (max / 127.0).max(for_bias * 1.01).max(min_scale)
}

fn eval_layers(layers: &[Dense], fake_quant: bool) -> Vec<EvalLayer> {
    layers
        .iter()
        .map(|l| {
            let mut w = l.w.clone();
            if fake_quant {
                for (row, &b) in w.chunks_mut(l.inputs).zip(&l.b) {
                    // The hidden Q-formats are chosen after training: bound by the finest.
                    let s = row_scale(row, b, nmat_core::limits::MAX_FRAC_BITS, 1e-12);
                    row.iter_mut().for_each(|v| *v = (*v / s).round().clamp(-127.0, 127.0) * s);
                }
            }
            let mut wt = Matrix::zeros(l.inputs, l.outputs);
            let mut wo = Matrix::zeros(l.outputs, l.inputs);
            for (o, row) in w.chunks(l.inputs).enumerate() {
                wo.row_mut(o)[..l.inputs].copy_from_slice(row);
                for (i, &v) in row.iter().enumerate() {
                    wt.row_mut(i)[o] = v;
                }
            }
            let mut b = vec![0f32; wt.stride()];
            b[..l.outputs].copy_from_slice(&l.b);
            EvalLayer { inputs: l.inputs, outputs: l.outputs, hidden: l.hidden, wt, w: wo, b }
        })
        .collect()
}

// Both activations compute the middle piece unconditionally, so a loop over a chunk can select
// instead of branch.
fn hard_gelu(x: f32) -> f32 {
    let mid = x * (x + 1.5) / 3.0;
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        x
    } else {
        mid
    }
}

fn hard_gelu_grad(x: f32) -> f32 {
    let mid = (2.0 * x + 1.5) / 3.0;
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        1.0
    } else {
        mid
    }
}

/// Bilinear taps (`add` = their weight) add `weight ×` each value to its feature; `Nearest4` taps
/// set it.
#[inline(always)]
fn store_features(features: &mut [f32], values: impl Iterator<Item = f32>, add: Option<f32>) {
    match add {
        Some(w) => features.iter_mut().zip(values).for_each(|(f, v)| *f += w * v),
        None => features.iter_mut().zip(values).for_each(|(f, v)| *f = v),
    }
}

/// How latents enter the forward pass.
#[derive(Clone, Copy, PartialEq)]
enum LatentMode {
    Noisy,
    Quantized,
}

/// How a step runs its chunks.
#[derive(Clone, Copy)]
struct ChunkMode {
    kernel: TrainKernel,
    latents: LatentMode,
    /// Whether gradients flow back to the latents (the joint phase).
    train_latents: bool,
}

/// The model being trained.
pub struct Model<'a> {
    pub cfg: &'a ModelConfig,
    pub grids: Vec<GridState>,
    pub latents: Vec<f32>,
    pub layers: Vec<Dense>,
    pub address: AddressMode,
    set: &'a TextureSet,
    learned: Vec<usize>,
    mip_cdf: Vec<f32>,
    /// The learned channels of every mip, texel after texel, mip after mip (`target_base`):
    /// one place per sample's read, in huge pages.
    targets: Vec<f32>,
    target_base: Vec<usize>,
    /// The most taps, and latents they read, of one sample (over the levels).
    taps_per_sample: (usize, usize),
    /// The latent buckets of the grids.
    buckets: LatentBuckets,
}

/// Adam state for a flat parameter vector.
struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
}

/// One step's Adam constants: learning rate and the bias corrections 1 − β^t.
#[derive(Clone, Copy)]
struct AdamStep {
    lr: f32,
    c1: f32,
    c2: f32,
}

const B1: f32 = 0.9;
const B2: f32 = 0.999;

impl AdamStep {
    fn new(lr: f32, t: i32) -> AdamStep {
        AdamStep { lr, c1: 1.0 - B1.powi(t), c2: 1.0 - B2.powi(t) }
    }
}

impl Adam {
    fn new(n: usize) -> Adam {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    /// Updates `params` with `grads` (one each, in order).
    fn update(&mut self, params: &mut [f32], grads: &[f32], step: AdamStep) {
        adam_block(&mut self.m, &mut self.v, params, grads, step);
    }
}

/// [`adam`] over slices of equal length; a plain loop the compiler vectorizes (division and
/// square root are exact in every lane, so the results are those of [`adam`]).
fn adam_block(m: &mut [f32], v: &mut [f32], p: &mut [f32], g: &[f32], step: AdamStep) {
    let n = p.len();
    assert!(m.len() == n && v.len() == n && g.len() == n, "adam_block: lengths");
    for i in 0..n {
        adam(&mut m[i], &mut v[i], &mut p[i], g[i], step);
    }
}

/// One Adam update of parameter `p` with gradient `g` and moments `m`, `v`.
#[inline(always)]
fn adam(m: &mut f32, v: &mut f32, p: &mut f32, g: f32, step: AdamStep) {
    *m = B1 * *m + (1.0 - B1) * g;
    *v = B2 * *v + (1.0 - B2) * g * g;
    let mh = *m / step.c1;
    let vh = *v / step.c2;
    *p -= step.lr * mh / (vh.sqrt() + 1e-8);
}

/// The latents' optimizer state: per latent cell (cells are whole, consecutive runs of latents)
/// its Adam moments and this step's summed gradient side by side — the `c` latents of the cell at
/// latent `first` own `state[3 first .. 3 (first + c)]`, first `m`, then `v`, then the sums — so
/// the random reads of one cell touch a line or two, not one per array; and, at its first latent,
/// whether this step touched the cell yet — a byte, zero between steps, so the flags of a bucket
/// stay in the cache.
struct LatentState {
    state: Vec<f32>,
    touched: Vec<bool>,
}

/// Values of [`LatentState::state`] per latent.
const STATE_PER_LATENT: usize = 3;

impl LatentState {
    fn new(n: usize) -> LatentState {
        LatentState { state: huge_vec(STATE_PER_LATENT * n, 0.0), touched: vec![false; n] }
    }

    /// The state cut at `edges` (see [`split_at_edges`]), with `latents` cut the same way.
    fn split<'s>(&'s mut self, latents: &'s mut [f32], edges: &[usize]) -> Vec<LatentRange<'s>> {
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
struct LatentRange<'s> {
    state: &'s mut [f32],
    touched: &'s mut [bool],
    latents: &'s mut [f32],
}

/// One chunk's gradients.
struct Grads {
    /// `[outputs][inputs]` per layer.
    w: Vec<Matrix>,
    b: Vec<Vec<f32>>,
    /// The latent cells the chunk read, in tap order, cut into [`LATENT_BUCKETS`] ranges of
    /// latents; their gradients are in `latent_grads`.
    latents: Vec<Vec<CellGrad>>,
    latent_grads: Vec<f32>,
    loss: f64,
}

/// One tap's gradients: of latents `latent ..` (`channels` of them, one cell), at `at` in its
/// chunk's `latent_grads`. A cell whose gradients are all zero is not recorded (it stays
/// untouched).
#[derive(Clone, Copy)]
struct CellGrad {
    latent: u32,
    at: u32,
    channels: u32,
}

/// The latents are updated in this many ranges side by side (a fixed number: every latent's
/// gradient is summed in chunk order, then tap order, whatever the thread count).
const LATENT_BUCKETS: usize = 16;

/// Where each bucket of latents starts (and, last, the end of the latents): near even shares,
/// on cell boundaries, so a cell's latents share a bucket.
fn latent_bucket_edges(grids: &[GridState]) -> Vec<usize> {
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
fn split_at_edges<'s, T>(mut slice: &'s mut [T], edges: &[usize]) -> Vec<&'s mut [T]> {
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
struct LatentBuckets {
    /// [`latent_bucket_edges`].
    edges: Vec<usize>,
    by_block: Vec<u8>,
}

impl LatentBuckets {
    const BLOCK_BITS: u32 = 6;

    fn new(edges: Vec<usize>) -> LatentBuckets {
        const { assert!(LATENT_BUCKETS <= 256, "LatentBuckets: a bucket index is a u8") };
        let total = edges.last().copied().unwrap_or(0);
        let by_block = (0..total.div_ceil(1 << Self::BLOCK_BITS))
            .map(|b| (edges.partition_point(|&e| e <= b << Self::BLOCK_BITS) - 1) as u8)
            .collect();
        LatentBuckets { edges, by_block }
    }

    /// The bucket of latent `latent`.
    fn of(&self, latent: u32) -> usize {
        let mut k = usize::from(self.by_block[(latent >> Self::BLOCK_BITS) as usize]);
        while self.edges[k + 1] <= latent as usize {
            k += 1;
        }
        k
    }
}

/// One step's sparse Adam update of the latents: only those a sample read move.
struct LatentUpdate {
    /// 1 / batch.
    inv: f32,
    adam: AdamStep,
}

impl LatentUpdate {
    /// Sums the gradients of `bucket` over `results` (in chunk order) and updates the latent
    /// cells it touched; `range` is that bucket's, which starts at latent `base`. Inlined into
    /// [`TrainKernel::run`], so its loops run in the kernel's SIMD lanes.
    #[inline(always)]
    fn apply(&self, results: &[Grads], (bucket, base): (usize, usize), range: LatentRange) {
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
            let cell = m.iter_mut().zip(v).zip(&*grad);
            for (p, ((m, v), &g)) in latents[first..first + channels].iter_mut().zip(cell) {
                adam(m, v, p, g * self.inv, self.adam);
                *p = p.clamp(0.0, 1.0);
            }
        }
    }
}

/// One corner of a latent cell as one sample of a chunk reads it: the cell's `channels` latents
/// (consecutive from `latent`) feed the sample's features `feature ..`, in that order.
#[derive(Clone, Copy)]
struct Tap {
    sample: u16,
    feature: u16,
    grid: u16,
    /// Bilinear taps add `weight ×` the latent's value to their feature; `Nearest4` taps set it.
    add: bool,
    latent: u32,
    weight: f32,
    /// ∂feature/∂(unit latent).
    coeff: f32,
}

/// A chunk's taps and, in the noisy mode, for every latent they read (tap after tap, channel
/// after channel) the uniform draw in [0, 1) that becomes ±½ quantization step.
#[derive(Default)]
struct Taps {
    list: Vec<Tap>,
    noise: Vec<f32>,
}

fn cosine(lr: f32, t: usize, total: usize) -> f32 {
    let x = (t as f32 / total.max(1) as f32).min(1.0);
    0.01 * lr + 0.99 * lr * 0.5 * (1.0 + (std::f32::consts::PI * x).cos())
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
        }
    }

    #[inline(always)]
    fn draw(&self, rng: &mut Rng) -> (u32, u32, u32) {
        let r = rng.unit() * self.mip_cdf.last().copied().unwrap_or(1.0);
        let mip = self.mip_cdf.iter().position(|&c| r < c).unwrap_or(self.mip_cdf.len() - 1) as u32;
        let m = &self.set.mips[mip as usize];
        (rng.below(m.width), rng.below(m.height), mip)
    }

    /// Appends the taps of sample `s` at texel `(x, y, mip)` in the order its features read
    /// them, and asks for the latents they read (they are read a few samples later).
    #[inline(always)]
    fn plan(&self, s: usize, (x, y, mip): (u32, u32, u32), taps: &mut Vec<Tap>) {
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
    fn evaluate(&self, taps: &[Tap], noise: &[f32], mode: LatentMode, x: &mut Matrix) {
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
    fn position_features(&self, (x, y, mip): (u32, u32, u32), row: &mut [f32]) {
        let f = INPUT_FRAC_BITS;
        let one = (1u32 << f) as f32;
        let mut at = self.cfg.input_width()
            - 4 * usize::from(self.cfg.pe_frequencies)
            - usize::from(self.cfg.lod_input);
        for k in 0..self.cfg.pe_frequencies {
            for (t, p) in [(x, 0), (x, 1), (y, 0), (y, 1)] {
                row[at] = f32::from(triangle_q(t, k, p, f)) / one;
                at += 1;
            }
        }
        if self.cfg.lod_input {
            row[at] = mip as f32 / 16.0;
        }
    }

    /// Where the learned channels of texel `(x, y, mip)` start in `targets`.
    fn target_index(&self, (x, y, mip): (u32, u32, u32)) -> usize {
        let m = &self.set.mips[mip as usize];
        self.target_base[mip as usize] + (y * m.width + x) as usize * self.learned.len()
    }

    /// Draws `samples` texels: their input features (one row each) and every latent's share in
    /// them (`taps`, in the order the random draws are made: texel, then its noise). A sample's
    /// latent features are computed `LAG` samples after its taps are planned, so the latents it
    /// reads are on their way to the cache meanwhile.
    #[inline(always)]
    fn gather(
        &self,
        mode: LatentMode,
        rng: &mut Rng,
        samples: usize,
        taps: &mut Taps,
    ) -> (Vec<(u32, u32, u32)>, Matrix) {
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
            let d = self.draw(rng);
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
            draws.push(d);
        }
        let (t0, n0) = starts.get(samples.saturating_sub(LAG)).copied().unwrap_or((0, 0));
        self.evaluate(&taps.list[t0..], &taps.noise[n0..], mode, &mut x);
        (draws, x)
    }

    /// Forward over a chunk: the input of every layer (`x0` first) and every pre-activation.
    #[inline(always)]
    fn forward(
        layers: &[EvalLayer],
        kernel: TrainKernel,
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

    /// Forward and backward over one chunk of samples; returns the mean squared error.
    #[inline(always)]
    fn run_chunk(
        &self,
        layers: &[EvalLayer],
        how: ChunkMode,
        rng: &mut Rng,
        samples: usize,
        gr: &mut Grads,
    ) -> f64 {
        let ChunkMode { kernel, latents: mode, train_latents } = how;
        let mut taps = Taps::default();
        let (draws, x0) = self.gather(mode, rng, samples, &mut taps);
        let (xs, pres) = Self::forward(layers, kernel, x0);
        let last = layers.len() - 1;
        let outputs = self.learned.len().max(1);
        let mut loss = 0.0f64;
        let mut g = Matrix::zeros(samples, layers[last].outputs);
        for (s, &d) in draws.iter().enumerate() {
            let out = pres[last].row(s);
            let row = g.row_mut(s);
            let target = &self.targets[self.target_index(d)..][..self.learned.len()];
            for (o, &t) in target.iter().enumerate() {
                let e = out[o] - t;
                loss += f64::from(e * e);
                row[o] = 2.0 * e / outputs as f32;
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
            for t in &taps.list {
                let channels = self.grids[usize::from(t.grid)].channels;
                let grads = &g.row(usize::from(t.sample))[usize::from(t.feature)..][..channels];
                let at = gr.latent_grads.len();
                gr.latent_grads.extend(grads.iter().map(|&gf| gf * t.coeff));
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
        let kernel = opts.kernel();
        let (tap_count, latent_reads) = self.taps_per_sample;
        for step in 0..steps {
            let phase = opts.phase(step);
            let layers = eval_layers(&self.layers, phase == Phase::QuantizationAware);
            let mode =
                if phase == Phase::Joint { LatentMode::Noisy } else { LatentMode::Quantized };
            let train_latents = phase == Phase::Joint;
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
                    };
                    let how = ChunkMode { kernel, latents: mode, train_latents };
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
            let adam_mlp = AdamStep::new(cosine(opts.lr_mlp, step, steps), t);
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
                let adam_latents = AdamStep::new(cosine(opts.lr_latents, step, joint_end), t);
                let update = LatentUpdate { inv, adam: adam_latents };
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

    /// The stored code of every latent (round to the nearest level).
    pub fn codes(&self, g: &GridState) -> Vec<u8> {
        let n = (g.width * g.height) as usize * g.channels;
        self.latents[g.base..g.base + n]
            .iter()
            .map(|u| (u * g.qmax()).round().clamp(0.0, g.qmax()) as u8)
            .collect()
    }
}

/// Hidden-layer output format: the most fraction bits whose i16 range (±2^(15−f)) holds the
/// observed activations with 25 % headroom.
pub fn frac_bits_for(max_abs: f32) -> u8 {
    let need = f64::from(max_abs.max(1e-3)) * 1.25;
    ((15.0 - need.log2()).floor() as i32).clamp(1, 14) as u8
}

/// Exports one trained layer to the file's two arithmetics. `out_rows` maps file rows to trained
/// rows (`None` = a constant channel: zero weights, zero scale).
pub fn export_layer(
    l: &Dense,
    in_frac: u8,
    out_frac: u8,
    out_rows: &[Option<usize>],
    activation: Activation,
) -> LayerSpec {
    let n = l.inputs;
    // The decoder needs its requantization shift ≤ 62: scale ≥ 2^(−32 + in − out), with margin.
    let min_scale = 2f32.powi(-30 + i32::from(in_frac) - i32::from(out_frac));
    let in_lsb = 1.0 / f64::from(1u32 << in_frac);
    let bias_limit = f64::from(i32::MAX) - n as f64 * 127.0 * 32768.0;
    let (mut weights_i8, mut scales, mut bias) = (Vec::new(), Vec::new(), Vec::new());
    for row in out_rows {
        match row {
            Some(o) => {
                let w = &l.w[o * n..(o + 1) * n];
                let s = row_scale(w, l.b[*o], in_frac, min_scale);
                weights_i8.extend(w.iter().map(|v| (v / s).round().clamp(-127.0, 127.0) as i8));
                let b = (f64::from(l.b[*o]) / (f64::from(s) * in_lsb)).round();
                bias.push(b.clamp(-bias_limit, bias_limit) as i32);
                scales.push(s);
            }
            None => {
                weights_i8.extend(std::iter::repeat_n(0i8, n));
                scales.push(0.0);
                bias.push(0);
            }
        }
    }
    LayerSpec {
        inputs: n as u16,
        outputs: out_rows.len() as u16,
        out_frac_bits: out_frac,
        activation,
        weights_i8,
        scales,
        bias,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_carried_by_its_bias_survives_export() {
        // Dead weights, a live bias: the int8 scale must still express the bias.
        for (w, b) in [(1e-12f32, 0.7f32), (0.0, -3.0), (0.5, 0.25), (1e-6, 5.0)] {
            let layer = Dense { inputs: 64, outputs: 1, hidden: true, w: vec![w; 64], b: vec![b] };
            for in_frac in [10u8, 12, 14] {
                let spec = export_layer(&layer, in_frac, 12, &[Some(0)], Activation::HardGelu);
                let lsb = 1.0 / f64::from(1u32 << in_frac);
                let real_bias = f64::from(spec.bias[0]) * f64::from(spec.scales[0]) * lsb;
                assert!(
                    (real_bias - f64::from(b)).abs() < 1e-3 * f64::from(b.abs()).max(1.0),
                    "w {w} b {b}: {real_bias}"
                );
                let limit = f64::from(i32::MAX) - 64.0 * 127.0 * 32768.0;
                assert!(f64::from(spec.bias[0]).abs() <= limit);
            }
        }
    }
    fn grid(width: u32, height: u32, channels: usize, base: usize) -> GridState {
        GridState { width, height, channels, bits: 2, base, offset_q: 0, step_q: 1 }
    }

    #[test]
    fn latent_buckets_hold_whole_cells_and_cover_every_latent() {
        // Grids of 9, 5 and 9 channels, small enough to check every latent; the last pair has
        // fewer latents than buckets.
        for sizes in [vec![(17, 13, 9), (9, 7, 5), (1, 1, 9)], vec![(1, 1, 9), (1, 1, 5)]] {
            let mut grids = Vec::new();
            let mut base = 0;
            for (w, h, c) in sizes {
                grids.push(grid(w, h, c, base));
                base += (w * h) as usize * c;
            }
            let buckets = LatentBuckets::new(latent_bucket_edges(&grids));
            let edges = &buckets.edges;
            assert_eq!(edges.len(), LATENT_BUCKETS + 1);
            assert_eq!((edges[0], edges[LATENT_BUCKETS]), (0, base));
            assert!(edges.windows(2).all(|w| w[0] <= w[1]), "{edges:?}");
            for &e in &edges[..LATENT_BUCKETS] {
                let g = grids.iter().rev().find(|g| g.base <= e).unwrap();
                assert_eq!((e - g.base) % g.channels, 0, "edge {e} splits a cell: {edges:?}");
            }
            for latent in 0..base {
                let k = buckets.of(latent as u32);
                assert!(edges[k] <= latent && latent < edges[k + 1], "{latent} in {k}: {edges:?}");
            }
            let mut values: Vec<usize> = (0..base).collect();
            let parts = split_at_edges(&mut values, edges);
            for (k, part) in parts.iter().enumerate() {
                assert_eq!(part.first().copied(), (edges[k] < edges[k + 1]).then_some(edges[k]));
                assert_eq!(part.len(), edges[k + 1] - edges[k]);
            }
        }
    }

    #[test]
    fn effort_trades_a_quarter_or_twice_the_steps() {
        assert_eq!(Effort::Fast.schedule(30_000, 2048), (7_500, 2048));
        assert_eq!(Effort::Fast.schedule(3, 2048), (1, 2048));
        assert_eq!(Effort::Default.schedule(30_000, 2048), (30_000, 2048));
        assert_eq!(Effort::Max.schedule(30_000, 2048), (60_000, 2048));
        assert_eq!(Effort::Max.schedule(usize::MAX, 2048), (usize::MAX, 2048));
    }

    #[test]
    fn huge_vectors_hold_their_values() {
        // Large enough to span several 2 MiB blocks, whatever the allocation's alignment.
        let n = (5 << 20) + 3;
        let v = huge_vec(n, 0.25f32);
        assert_eq!(v.len(), n);
        assert!(v.iter().all(|&x| x == 0.25));
    }
}
