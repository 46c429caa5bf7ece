//! The CPU trainer (docs/ENCODING.md): latents and MLP optimized jointly with Adam and a cosine
//! schedule under simulated quantization (uniform noise), then latents frozen at their quantized
//! values while the MLP is fine-tuned, then quantization-aware fine-tuning of the int8 weights
//! (straight-through estimator) so the integer decoder is the trained model.
//!
//! Forward and backward are written by hand (the NTC paper's own trainer was 10× faster than a
//! general framework): per sample, every matrix product is a sequence of `axpy`s over contiguous
//! rows that the compiler vectorizes. A step's batch is cut into fixed chunks processed in
//! parallel; their gradients are summed in chunk order, so the result is the same for any number
//! of threads.

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

/// Default optimizer steps: a 1024² four-map material trains in about 3 minutes on 2 cores
/// (docs/QUALITY.md).
pub const DEFAULT_STEPS: usize = 10_000;

#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub steps: usize,
    pub batch: usize,
    pub seed: u64,
    pub lr_mlp: f32,
    pub lr_latents: f32,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions { steps: DEFAULT_STEPS, batch: 2048, seed: 1, lr_mlp: 1e-2, lr_latents: 2e-2 }
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
    w: Vec<f32>,
    wt: Vec<f32>,
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
            let mut wt = vec![0f32; w.len()];
            for o in 0..l.outputs {
                for i in 0..l.inputs {
                    wt[i * l.outputs + o] = w[o * l.inputs + i];
                }
            }
            EvalLayer {
                inputs: l.inputs,
                outputs: l.outputs,
                hidden: l.hidden,
                w,
                wt,
                b: l.b.clone(),
            }
        })
        .collect()
}

fn hard_gelu(x: f32) -> f32 {
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        x
    } else {
        x * (x + 1.5) / 3.0
    }
}

fn hard_gelu_grad(x: f32) -> f32 {
    if x <= -1.5 {
        0.0
    } else if x >= 1.5 {
        1.0
    } else {
        (2.0 * x + 1.5) / 3.0
    }
}

#[inline]
fn axpy(y: &mut [f32], a: f32, x: &[f32]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

/// How latents enter the forward pass.
#[derive(Clone, Copy, PartialEq)]
enum LatentMode {
    Noisy,
    Quantized,
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
}

/// Adam state for a flat parameter vector.
struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Adam {
    fn new(n: usize) -> Adam {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    fn update(&mut self, i: usize, p: &mut f32, g: f32, lr: f32, t: i32) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        let m = &mut self.m[i];
        let v = &mut self.v[i];
        *m = B1 * *m + (1.0 - B1) * g;
        *v = B2 * *v + (1.0 - B2) * g * g;
        let mh = *m / (1.0 - B1.powi(t));
        let vh = *v / (1.0 - B2.powi(t));
        *p -= lr * mh / (vh.sqrt() + 1e-8);
    }
}

/// One chunk's gradients.
struct Grads {
    w: Vec<Vec<f32>>,
    b: Vec<Vec<f32>>,
    latents: Vec<(u32, f32)>,
    loss: f64,
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
        seed: u64,
    ) -> Model<'a> {
        let mut rng = Rng::new(seed, 0xA11CE, 0);
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
        let latents = (0..base).map(|_| 0.5 + 0.2 * (rng.unit() - 0.5)).collect();
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
        let areas: Vec<f32> = set.mips.iter().map(|m| (m.width * m.height) as f32).collect();
        let total: f32 = areas.iter().sum();
        let n = areas.len() as f32;
        let mut acc = 0.0;
        let mip_cdf = areas
            .iter()
            .map(|a| {
                acc += 0.7 * a / total + 0.3 / n;
                acc
            })
            .collect();
        Model { cfg, grids, latents, layers, address, set, learned, mip_cdf }
    }

    fn draw(&self, rng: &mut Rng) -> (u32, u32, u32) {
        let r = rng.unit() * self.mip_cdf.last().copied().unwrap_or(1.0);
        let mip = self.mip_cdf.iter().position(|&c| r < c).unwrap_or(self.mip_cdf.len() - 1) as u32;
        let m = &self.set.mips[mip as usize];
        (rng.below(m.width), rng.below(m.height), mip)
    }

    /// Input features of a texel; `taps` receives (feature, latent index, ∂feature/∂u).
    fn features(
        &self,
        (x, y, mip): (u32, u32, u32),
        mode: LatentMode,
        rng: &mut Rng,
        out: &mut Vec<f32>,
        taps: &mut Vec<(u16, u32, f32)>,
    ) {
        out.clear();
        taps.clear();
        let ms = &self.set.mips[mip as usize];
        let mip_size = (ms.width, ms.height);
        let level = &self.cfg.levels[usize::from(self.cfg.mip_to_level[mip as usize])];
        let latents = &self.latents;
        let value = |g: &GridState, idx: usize, rng: &mut Rng| {
            let q = g.qmax();
            let u = latents[idx];
            let u = match mode {
                LatentMode::Noisy => (u + (rng.unit() - 0.5) / q).clamp(0.0, 1.0),
                LatentMode::Quantized => (u * q).round() / q,
            };
            g.low() + u * g.width_real()
        };
        for term in level {
            match term.mode {
                TermMode::Nearest4 => {
                    let g = &self.grids[term.grids[0]];
                    let fp = footprint((g.width, g.height), x, y, mip_size, self.address);
                    for (cx, cy) in [(fp.x0, fp.y0), (fp.x1, fp.y0), (fp.x0, fp.y1), (fp.x1, fp.y1)]
                    {
                        for c in 0..g.channels {
                            let idx = g.index(cx, cy, c);
                            taps.push((out.len() as u16, idx as u32, g.width_real()));
                            out.push(value(g, idx, rng));
                        }
                    }
                }
                _ => {
                    let channels = self.grids[term.grids[0]].channels;
                    let start = out.len();
                    out.resize(start + channels, 0.0);
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
                        for (cx, cy, w) in corners {
                            if w == 0.0 {
                                continue;
                            }
                            let w = w / 65536.0;
                            for c in 0..channels {
                                let idx = g.index(cx, cy, c);
                                taps.push(((start + c) as u16, idx as u32, w * g.width_real()));
                                out[start + c] += w * value(g, idx, rng);
                            }
                        }
                    }
                }
            }
        }
        let f = INPUT_FRAC_BITS;
        let one = (1u32 << f) as f32;
        for k in 0..self.cfg.pe_frequencies {
            for (t, p) in [(x, 0), (x, 1), (y, 0), (y, 1)] {
                out.push(f32::from(triangle_q(t, k, p, f)) / one);
            }
        }
        if self.cfg.lod_input {
            out.push(mip as f32 / 16.0);
        }
    }

    fn target(&self, (x, y, mip): (u32, u32, u32), c: usize) -> f32 {
        let m = &self.set.mips[mip as usize];
        m.data[(y * m.width + x) as usize * self.set.channel_count() + c]
    }

    /// Forward (and backward, if `grads`) over one chunk of samples.
    fn run_chunk(
        &self,
        layers: &[EvalLayer],
        mode: LatentMode,
        rng: &mut Rng,
        samples: usize,
        train_latents: bool,
        mut grads: Option<&mut Grads>,
    ) -> f64 {
        let mut feats = Vec::new();
        let mut taps = Vec::new();
        let mut acts: Vec<Vec<f32>> = layers.iter().map(|l| vec![0.0; l.inputs]).collect();
        let mut pres: Vec<Vec<f32>> = layers.iter().map(|l| vec![0.0; l.outputs]).collect();
        let mut loss = 0.0f64;
        let outputs = self.learned.len().max(1);
        for _ in 0..samples {
            let s = self.draw(rng);
            self.features(s, mode, rng, &mut feats, &mut taps);
            acts[0].copy_from_slice(&feats);
            for (k, l) in layers.iter().enumerate() {
                let pre = &mut pres[k];
                pre.copy_from_slice(&l.b);
                for (i, &xi) in acts[k].iter().enumerate() {
                    if xi != 0.0 {
                        axpy(pre, xi, &l.wt[i * l.outputs..(i + 1) * l.outputs]);
                    }
                }
                if k + 1 < layers.len() {
                    let (head, tail) = acts.split_at_mut(k + 1);
                    let _ = head;
                    for (a, &p) in tail[0].iter_mut().zip(pre.iter()) {
                        *a = if l.hidden { hard_gelu(p) } else { p };
                    }
                }
            }
            let out = &pres[layers.len() - 1];
            let mut g: Vec<f32> = Vec::with_capacity(outputs);
            for (o, &c) in self.learned.iter().enumerate() {
                let d = out[o] - self.target(s, c);
                loss += f64::from(d * d);
                g.push(2.0 * d / outputs as f32);
            }
            if self.learned.is_empty() {
                g.push(0.0);
            }
            let Some(gr) = grads.as_deref_mut() else { continue };
            for k in (0..layers.len()).rev() {
                let l = &layers[k];
                if l.hidden {
                    for (gv, &p) in g.iter_mut().zip(&pres[k]) {
                        *gv *= hard_gelu_grad(p);
                    }
                }
                let x = &acts[k];
                for (o, &go) in g.iter().enumerate() {
                    if go != 0.0 {
                        gr.b[k][o] += go;
                        axpy(&mut gr.w[k][o * l.inputs..(o + 1) * l.inputs], go, x);
                    }
                }
                if k == 0 && !train_latents {
                    break;
                }
                let mut gin = vec![0f32; l.inputs];
                for (o, &go) in g.iter().enumerate() {
                    if go != 0.0 {
                        axpy(&mut gin, go, &l.w[o * l.inputs..(o + 1) * l.inputs]);
                    }
                }
                g = gin;
            }
            if train_latents {
                for &(f, idx, coeff) in &taps {
                    let gv = g[usize::from(f)] * coeff;
                    if gv != 0.0 {
                        gr.latents.push((idx, gv));
                    }
                }
            }
        }
        loss / (samples * outputs).max(1) as f64
    }

    /// Trains for `opts.steps` steps, reporting progress about 100 times.
    pub fn train(&mut self, opts: &TrainOptions, progress: &mut dyn FnMut(Progress)) {
        let steps = opts.steps.max(1);
        let joint_end = steps * 80 / 100;
        let frozen_end = steps * 95 / 100;
        let mut adam_w: Vec<Adam> = self.layers.iter().map(|l| Adam::new(l.w.len())).collect();
        let mut adam_b: Vec<Adam> = self.layers.iter().map(|l| Adam::new(l.b.len())).collect();
        let mut adam_lat = Adam::new(self.latents.len());
        let mut touched_at = vec![usize::MAX; self.latents.len()];
        let mut latent_grad = vec![0f32; self.latents.len()];
        let mut running = None::<f64>;
        let chunks = opts.batch.div_ceil(CHUNK);
        for step in 0..steps {
            let phase = if step < joint_end {
                Phase::Joint
            } else if step < frozen_end {
                Phase::FrozenLatents
            } else {
                Phase::QuantizationAware
            };
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
                        w: self.layers.iter().map(|l| vec![0.0; l.w.len()]).collect(),
                        b: self.layers.iter().map(|l| vec![0.0; l.b.len()]).collect(),
                        latents: Vec::new(),
                        loss: 0.0,
                    };
                    g.loss =
                        self.run_chunk(&layers, mode, &mut rng, n, train_latents, Some(&mut g));
                    g
                })
                .collect();
            // Sum in chunk order: the same floating-point result for any thread count.
            let inv = 1.0 / opts.batch as f32;
            let t = step as i32 + 1;
            let lr = cosine(opts.lr_mlp, step, steps);
            let mut mse = 0.0;
            for k in 0..self.layers.len() {
                let mut gw = vec![0f32; self.layers[k].w.len()];
                let mut gb = vec![0f32; self.layers[k].b.len()];
                for r in &results {
                    axpy(&mut gw, 1.0, &r.w[k]);
                    axpy(&mut gb, 1.0, &r.b[k]);
                }
                let layer = &mut self.layers[k];
                for (i, (p, g)) in layer.w.iter_mut().zip(&gw).enumerate() {
                    adam_w[k].update(i, p, g * inv, lr, t);
                }
                for (i, (p, g)) in layer.b.iter_mut().zip(&gb).enumerate() {
                    adam_b[k].update(i, p, g * inv, lr, t);
                }
            }
            if train_latents {
                let lr_lat = cosine(opts.lr_latents, step, joint_end);
                let mut touched = Vec::new();
                for r in &results {
                    for &(idx, g) in &r.latents {
                        let i = idx as usize;
                        if touched_at[i] != step {
                            touched_at[i] = step;
                            latent_grad[i] = 0.0;
                            touched.push(i);
                        }
                        latent_grad[i] += g;
                    }
                }
                for i in touched {
                    let p = &mut self.latents[i];
                    adam_lat.update(i, p, latent_grad[i] * inv, lr_lat, t);
                    *p = p.clamp(0.0, 1.0);
                }
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
    pub fn activation_ranges(&self, samples: usize, seed: u64) -> Vec<f32> {
        let layers = eval_layers(&self.layers, true);
        let mut rng = Rng::new(seed, u64::MAX, 7);
        let mut feats = Vec::new();
        let mut taps = Vec::new();
        let mut max = vec![0f32; layers.len()];
        for _ in 0..samples {
            let s = self.draw(&mut rng);
            self.features(s, LatentMode::Quantized, &mut rng, &mut feats, &mut taps);
            let mut x = feats.clone();
            for (k, l) in layers.iter().enumerate() {
                let mut pre = l.b.clone();
                for (i, &xi) in x.iter().enumerate() {
                    axpy(&mut pre, xi, &l.wt[i * l.outputs..(i + 1) * l.outputs]);
                }
                max[k] = pre.iter().fold(max[k], |m, v| m.max(v.abs()));
                x = pre.into_iter().map(|p| if l.hidden { hard_gelu(p) } else { p }).collect();
            }
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
}
