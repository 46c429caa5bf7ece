//! What an encode asks of the trainer: steps, batch, seed and the tuned knobs (`TrainOptions`),
//! effort, the phases of the schedule and the learning-rate curve, and the work a step does.

use crate::gemm::TrainKernel;
use crate::profile::ModelConfig;

/// Default optimizer steps: a 1024² four-map material trains in 1–3½ minutes on 2 cores
/// (docs/ENCODING.md, "Tuning").
pub const DEFAULT_STEPS: usize = 30_000;

/// Encode time traded for quality (`--effort`): a quarter of a command's default steps, or twice
/// them. `Max` doubles the steps at the same batch, for about twice the time (`nmat` also trains
/// its network on int8 weights throughout, [`TrainOptions::int8_percent`]): −0.64 … +0.53 dB on
/// four development materials, three better; a larger batch (what `Max` was before) lost up to
/// 1.2 dB (docs/ENCODING.md, "Speed").
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
    /// The MLP's learning rate when the quantization-aware phase starts, as a share of
    /// `lr_mlp`: the phase runs its own cosine from there down to 1 % of it, so its length and
    /// its rate are separate knobs. (A phase of 3 % on the main schedule's tail left the int8
    /// network 1–2.5 dB below the float one on clean materials at high rates; docs/ENCODING.md.)
    pub qat_lr: f32,
    /// The latents' learning rate in the quantization-aware phase, as a share of `lr_latents`
    /// (a cosine of its own from there): the latents are read rounded and learn through the
    /// rounding (straight-through), so they can make up for the int8 weights' error. 0: the
    /// latents stay frozen.
    pub qat_lr_latents: f32,
    /// Percent of the steps, counted from the end, whose forward pass runs the int8
    /// (fake-quantized) weights, gradients passing straight through to the float ones; the
    /// quantization-aware phase always does (0, the default: that phase alone). 100: the whole
    /// run. A float network trained long drifts to weights that int8 rounds badly: on
    /// `stk-eggkart` at `ntc-0.2` and 60 000 steps the training PSNR fell about 2 dB when the
    /// weights became int8 (0.3 dB at 30 000), and the file lost 0.75 dB to the 30 000-step
    /// one; with int8 weights throughout it gained 0.20 dB (docs/ENCODING.md, "Long runs and the
    /// int8 weights"). `nmat` uses 100 for `--effort max` and any `--steps` above a command's
    /// default.
    pub int8_percent: u32,
    /// Share of the samples drawn uniformly over the mips; the rest in proportion to their area.
    pub mip_uniform_share: f32,
    /// Share of each mip's draws that pick an 8×8-texel tile in proportion to the running error
    /// there, the rest uniformly; losses are weighted back to the uniform mean (0: uniform
    /// draws; docs/ENCODING.md, "The trainer").
    pub error_share: f32,
    /// Latents start at the middle of their range ± half this (a unit range is 1).
    pub latent_init_spread: f32,
    /// How far past its unit range an output may go without cost where its target sits at that
    /// end (0: plain squared error). Every decoder clamps the outputs to [0, 1], so a texel at
    /// an end of its range (pure white or black, a 0/1 mask, zero padding) decodes exactly once
    /// the network's output passes the end, instead of noisily around it; beyond the margin the
    /// excess is penalized (with no bound at all, a material lost quality: docs/ENCODING.md,
    /// "Outputs past the ends of their range"). `None`: the profile's
    /// ([`Profile::output_margin`](crate::Profile::output_margin)) where `encode` trains, else 0.
    pub output_margin: Option<f32>,
    /// Matrix-product kernel; `None` picks [`TrainKernel::best`]. The file does not depend on it.
    pub kernel: Option<TrainKernel>,
    /// Steer the latents' coded size (docs/FORMAT.md §12) toward this many bytes while they
    /// train: a pull toward each grid's middle code, as strong as it must be (`None`: no pull).
    pub latent_bytes: Option<f64>,
}

impl TrainOptions {
    /// The kernel that runs: the one asked for, else the fastest this CPU has.
    pub fn kernel(&self) -> TrainKernel {
        self.kernel.unwrap_or_else(TrainKernel::best)
    }

    /// The phase of step `step` (from 0).
    pub fn phase(&self, step: usize) -> Phase {
        if step < self.joint_end() {
            Phase::Joint
        } else if step < self.qat_start() {
            Phase::FrozenLatents
        } else {
            Phase::QuantizationAware
        }
    }

    /// The first step after the joint phase.
    pub(super) fn joint_end(&self) -> usize {
        self.steps.max(1) * (self.joint_percent as usize).min(100) / 100
    }

    /// The first step of the last `percent` of the steps (`steps` for 0).
    fn last_percent_start(&self, percent: u32) -> usize {
        self.steps.max(1) * 100usize.saturating_sub(percent as usize) / 100
    }

    /// The first step of the quantization-aware phase (`steps` if there is none).
    pub(super) fn qat_start(&self) -> usize {
        self.last_percent_start(self.qat_percent).max(self.joint_end())
    }

    /// Whether step `step` runs the int8 (fake-quantized) weights: in the quantization-aware
    /// phase, and in the last `int8_percent` of the steps.
    pub fn int8_weights(&self, step: usize) -> bool {
        step >= self.last_percent_start(self.int8_percent).min(self.qat_start())
    }

    /// The MLP's learning rate at `step`: a cosine over all steps from `lr_mlp`, and in the
    /// quantization-aware phase a cosine of its own from `qat_lr · lr_mlp`.
    pub fn mlp_lr(&self, step: usize) -> f32 {
        let steps = self.steps.max(1);
        let start = self.qat_start();
        if step >= start {
            cosine(self.lr_mlp * self.qat_lr, step - start, steps - start)
        } else {
            cosine(self.lr_mlp, step, steps)
        }
    }
}

impl TrainOptions {
    /// Whether the latents train at `step`: in the joint phase, and in the quantization-aware
    /// phase when `qat_lr_latents` is above 0.
    pub fn latents_train(&self, step: usize) -> bool {
        match self.phase(step) {
            Phase::Joint => true,
            Phase::FrozenLatents | Phase::Polish => false,
            Phase::QuantizationAware => self.qat_lr_latents > 0.0,
        }
    }

    /// The latents' learning rate at `step`: a cosine over the joint phase, and in the
    /// quantization-aware phase one of its own from `qat_lr_latents · lr_latents`.
    pub fn latent_lr(&self, step: usize) -> f32 {
        let start = self.qat_start();
        if step >= start {
            cosine(self.lr_latents * self.qat_lr_latents, step - start, self.steps.max(1) - start)
        } else {
            cosine(self.lr_latents, step, self.joint_end())
        }
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
            qat_percent: 10,
            qat_lr: 0.03,
            qat_lr_latents: 0.0,
            int8_percent: 0,
            mip_uniform_share: 0.1,
            error_share: 0.2,
            latent_init_spread: 0.05,
            output_margin: None,
            kernel: None,
            latent_bytes: None,
        }
    }
}

/// Reported during training.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub step: usize,
    pub steps: usize,
    /// PSNR of the running training loss (unit scale, all learned channels), dB; in
    /// [`Phase::Polish`], of the file's decode over the chain before the sweep.
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
    /// After training, a sweep of the latent polish (docs/ENCODING.md, "The latent polish"):
    /// reported at the start of each, with every step done.
    Polish,
}

/// Floating-point operations (2 per multiply-add) of the MLP's matrix products per training
/// sample: forward, weight gradients, and input gradients of every layer but the first — of the
/// first too when `latents_train` (at a step `s`, [`TrainOptions::latents_train`]`(s)`: the joint
/// phase, and the quantization-aware one when `qat_lr_latents` > 0). What `nmat bench-train`
/// counts as work.
pub fn mlp_flops_per_sample(cfg: &ModelConfig, latents_train: bool) -> u64 {
    let mut widths = vec![cfg.input_width()];
    widths.extend(&cfg.hidden);
    widths.push(cfg.outputs.max(1));
    let products: Vec<u64> = widths.windows(2).map(|w| (w[0] * w[1]) as u64).collect();
    let all: u64 = products.iter().sum();
    let input_grads = if latents_train { all } else { all - products[0] };
    2 * (2 * all + input_grads)
}

pub(super) fn cosine(lr: f32, t: usize, total: usize) -> f32 {
    let x = (t as f32 / total.max(1) as f32).min(1.0);
    0.01 * lr + 0.99 * lr * 0.5 * (1.0 + (std::f32::consts::PI * x).cos())
}
