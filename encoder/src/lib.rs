//! `nmat-encode`: turns a folder of material maps into a `.nmat` file (docs/ENCODING.md).
//!
//! ```no_run
//! use nmat_encode::{encode, texset, EncodeOptions};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let files = texset::collect_inputs(&["maps/brick".into()])?;
//! let roles = texset::assign_roles(&files, &[])?;
//! let set = texset::load(&roles, &Default::default())?;
//! let out = encode(&set, &EncodeOptions::default(), &mut |_| {})?;
//! std::fs::write("brick.nmat", out.file())?; // latents entropy-coded where that is smaller
//! # Ok(()) }
//! ```

pub mod demo;
mod error;
mod gemm;
pub mod input;
pub mod jpeg;
mod memhint;
pub mod metrics;
pub mod names;
mod polish;
mod profile;
mod refit;
mod role;
pub mod source_maps;
pub mod texset;
mod train;

pub use error::{EncodeError, EncodeOption};
pub use gemm::TrainKernel;
use profile::RATE_TOLERANCE;
pub use profile::{
    BITS_FIRST_MAX_BITS, ByteBudget, DEFAULT_PROFILE, MaterialShape, ModelConfig, PROFILES,
    Profile, configure, ntc_level_of,
};
pub use train::{DEFAULT_STEPS, Effort, Phase, Progress, TrainOptions};

use texset::TextureSet;

use nmat_core::{
    Activation, AddressMode, ChannelSpec, Container, GridSpec, LevelSpec, MaterialSpec, MlpSpec,
    TermSpec,
};

#[derive(Clone, Debug)]
pub struct EncodeOptions {
    pub profile: Profile,
    pub train: TrainOptions,
    pub address_mode: AddressMode,
    /// How the file stores its latents (default [`Storage::Packed`]).
    pub storage: Storage,
    /// A packed file's in-memory (fixed-rate) layout may be this many times the profile's
    /// nominal size, 1 to [`MAX_MEMORY_FACTOR`] (default [`DEFAULT_MEMORY_FACTOR`]): larger grids
    /// whose latents the trainer keeps to the nominal size once entropy-coded, so the file on
    /// disk has the nominal rate (docs/ENCODING.md, "Rate control"). Fixed-rate files ignore it
    /// (their layout is the nominal size). A polished file that lands more than 0.3 % under the
    /// nominal size is trained again at [`MAX_MEMORY_FACTOR`] and polished down to it, and kept
    /// where it decodes better (docs/ENCODING.md, "The regrown layout").
    pub memory_factor: f64,
    /// Train on the LOD feature of formats before 2.3 (`mip / 16`), so that readers of 2.0
    /// (fixed-rate files) and 2.2 (packed) decode the file; by default the feature is 2.3's
    /// `mip / 2`, which keeps the int8 network closer to the float one (docs/ENCODING.md).
    pub legacy_lod: bool,
    /// How a packed layout grows to its in-memory size where there are two ways
    /// (docs/ENCODING.md, "The layout trial"); default [`LayoutChoice::BitsFirst`].
    pub layout: LayoutChoice,
    /// Sweeps of the latent polish after training (`None`: the profile's,
    /// [`Profile::polish_sweeps`]): each moves every latent code by ±1 where the integer decoder
    /// then decodes the chain better, a packed file's coded size kept (docs/ENCODING.md, "The
    /// latent polish"). Each sweep costs about as much as decoding the finest mips 65 times.
    pub polish_sweeps: Option<u8>,
}

/// How a packed file's in-memory layout is grown past the nominal one, where a profile has two
/// ways (`ntc-0.2`, whose 2-bit latents can take a third bit: [`layouts`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LayoutChoice {
    /// Train each way for [`TRIAL_SHARE`] of the steps and keep the one whose file decodes with
    /// the higher whole-chain PSNR; then train it in full (the encode takes about 1.5× as long).
    Trial,
    /// The grids' resolution first (the layout where there is only one way).
    ResolutionFirst,
    /// One more bit per latent first, then the grids' resolution: the default, the way the trial
    /// kept on every development material with two ways since `ntc-0.2` reads its
    /// high-resolution grids twice.
    #[default]
    BitsFirst,
}

/// The share of the steps each layout of a [`LayoutChoice::Trial`] trains for: a quarter, what
/// `--effort fast` trains (on the development sets its ranking of the two ways agreed with full
/// trainings', docs/ENCODING.md, "The layout trial").
pub const TRIAL_SHARE: f64 = 0.25;

/// The default [`EncodeOptions::memory_factor`] (docs/ENCODING.md, "Rate control").
pub const DEFAULT_MEMORY_FACTOR: f64 = 1.5;
/// The largest [`EncodeOptions::memory_factor`].
pub const MAX_MEMORY_FACTOR: f64 = 2.0;

/// The largest [`TrainOptions::output_margin`]: a quarter of an output's range.
pub const MAX_OUTPUT_MARGIN: f32 = 0.25;

/// `Ok` where `margin` is a [`TrainOptions::output_margin`] the trainer takes: from 0 (plain
/// squared error) to [`MAX_OUTPUT_MARGIN`].
pub fn check_output_margin(margin: f32) -> Result<(), EncodeError> {
    if (0.0..=MAX_OUTPUT_MARGIN).contains(&margin) {
        return Ok(());
    }
    Err(EncodeError::BadOption {
        option: EncodeOption::OutputMargin,
        value: margin.to_string(),
        reason: "must be from 0 (plain squared error) to 0.25 of the output's range",
    })
}

/// Rate control is used only where the target coded size of the latents is at least this many
/// times what they code in when every latent sits on its grid's middle code.
const MIN_STEERING_ROOM: f64 = 4.0;

/// The coded size of `config`'s latents (docs/FORMAT.md §12.3) when every latent is its grid's
/// middle code (the rate control's pull draws them there).
fn floor_bytes(config: &ModelConfig) -> usize {
    let codes: Vec<Vec<u8>> = config
        .grids
        .iter()
        .map(|g| vec![1u8 << (g.bits - 1); (g.width * g.height) as usize * g.channels])
        .collect();
    let shapes = config.grids.iter().map(|g| (g.width, g.height, g.channels, g.bits));
    train::coded_bytes(shapes, &codes)
}

/// The model of a profile for a material and how its latents are steered while they train.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    pub config: ModelConfig,
    /// The coded size (bytes) the trainer keeps the latents to, for a packed file of the
    /// nominal size; `None` where the nominal model is trained unsteered (a fixed-rate file, a
    /// factor of 1, a material too small for the rate or whose grids would code near their
    /// floor).
    pub latent_bytes: Option<f64>,
}

/// The layouts of `profile` for a material of `shape` stored as `storage`, which an encode
/// chooses between ([`EncodeOptions::layout`]). Fixed-rate, the nominal-size model
/// ([`configure`]); packed, the same latent channels and network with grids solved for
/// `memory_factor` × the nominal size, and the coded size of latents that makes the packed file
/// nominal: the grids' resolution grown first, and for `ntc-0.2` a second layout, one more bit
/// per latent first ([`BITS_FIRST_MAX_BITS`]), where the two differ.
pub fn layouts(
    profile: Profile,
    shape: &MaterialShape,
    storage: Storage,
    memory_factor: f64,
) -> Result<Vec<Layout>, EncodeError> {
    if !(1.0..=MAX_MEMORY_FACTOR).contains(&memory_factor) {
        return Err(EncodeError::BadOption {
            option: EncodeOption::MemoryFactor,
            value: memory_factor.to_string(),
            reason: "must be from 1 (the nominal layout) to 2",
        });
    }
    let nominal = configure(profile, shape);
    let bytes = nominal_bytes(profile, shape);
    // A material too small for the rate (its smallest model is above it) has no latent bytes to
    // steer: it keeps the nominal model.
    let too_small = nominal.byte_budget(shape).total() as f64 > bytes * (1.0 + RATE_TOLERANCE);
    let unsteered = |config: ModelConfig| vec![Layout { config, latent_bytes: None }];
    if storage == Storage::FixedRate || memory_factor == 1.0 || too_small {
        return Ok(unsteered(nominal));
    }
    let target_size = bytes * memory_factor;
    let grown = profile::configure_like(profile, shape, target_size, &nominal);
    let bits_first = profile::configure_bits_first(profile, shape, target_size, &nominal)
        .filter(|cfg| *cfg != grown);
    let steered = |config: ModelConfig| {
        let budget = config.byte_budget(shape);
        // All but the latents are stored as they are; a packed section starts with an 8-byte
        // header (docs/FORMAT.md §12.1).
        let target = bytes - (budget.total() - budget.latents + 8) as f64;
        // Latents that all sit on their middle code still cost what the coder needs to learn
        // that; where that is a large share of the target (small grids), steering would crush
        // them.
        (target >= MIN_STEERING_ROOM * floor_bytes(&config) as f64)
            .then_some(Layout { config, latent_bytes: Some(target) })
    };
    let Some(first) = steered(grown) else { return Ok(unsteered(nominal)) };
    Ok([Some(first), bits_first.and_then(steered)].into_iter().flatten().collect())
}

/// How a file stores its latents, or its JPEG streams' index (docs/FORMAT.md §12).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Storage {
    /// Latents entropy-coded, JPEG streams without their index, where that is smaller (it is
    /// for trained latents and for every JPEG material): the smaller file, unpacked once when it
    /// is opened.
    #[default]
    Packed,
    /// Fixed-rate, as decoders hold it in memory: the larger file, parsed in place (zero-copy,
    /// e.g. memory-mapped), readable by format 2.0 readers.
    FixedRate,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        EncodeOptions {
            profile: Profile::by_name(DEFAULT_PROFILE).unwrap_or(PROFILES[0]),
            train: TrainOptions::default(),
            address_mode: AddressMode::Wrap,
            storage: Storage::default(),
            memory_factor: DEFAULT_MEMORY_FACTOR,
            legacy_lod: false,
            layout: LayoutChoice::default(),
            polish_sweeps: None,
        }
    }
}

/// The result of an encode.
#[derive(Clone)]
pub struct Encoded {
    /// The fixed-rate file: what decoders hold in memory, and what `Container::parse` reads.
    pub bytes: Vec<u8>,
    /// The same file with its latents entropy-coded, when [`Storage::Packed`] was asked for and
    /// it is smaller.
    pub packed: Option<Vec<u8>>,
    pub config: ModelConfig,
    /// Whole-chain quality of the integer decoder against the source mip chain; its `bppc` is
    /// the rate of [`Encoded::file`].
    pub quality: metrics::ChainQuality,
    /// The layout trial's measurements, where the encode ran one.
    pub trial: Option<LayoutTrial>,
}

/// The packed form of a fixed-rate file (docs/FORMAT.md §12) when `storage` asks for it and it
/// is smaller; `None` otherwise.
pub fn packed_form(fixed: &[u8], storage: Storage) -> Result<Option<Vec<u8>>, EncodeError> {
    Ok(match storage {
        Storage::Packed => Some(nmat_core::pack(fixed)?).filter(|p| p.len() < fixed.len()),
        Storage::FixedRate => None,
    })
}

impl Encoded {
    /// The file to write: packed if there is a packed form, else fixed-rate.
    pub fn file(&self) -> &[u8] {
        self.packed.as_deref().unwrap_or(&self.bytes)
    }

    /// `spec` written and measured as `storage` stores it, with this encode's layout and trial.
    fn rewritten(
        &self,
        spec: &MaterialSpec,
        set: &TextureSet,
        storage: Storage,
    ) -> Result<Encoded, EncodeError> {
        let bytes = spec.to_bytes()?;
        let (packed, quality) = as_stored(&bytes, set, storage)?;
        Ok(Encoded { bytes, packed, quality, config: self.config.clone(), trial: self.trial })
    }
}

/// The size in bytes of a file at `profile`'s nominal rate (disk rate of a packed file).
fn nominal_bytes(profile: Profile, shape: &MaterialShape) -> f64 {
    shape.budget_bits(profile.bppc()) / 8.0
}

/// Trains a model for `set` and writes it. Deterministic: the same set, options and seed give the
/// same bytes, whatever the number of threads. Where the profile has two layouts ([`layouts`])
/// and [`EncodeOptions::layout`] is a trial, `progress` counts the trials' steps too.
pub fn encode(
    set: &TextureSet,
    options: &EncodeOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<Encoded, EncodeError> {
    if let Some(margin) = options.train.output_margin {
        check_output_margin(margin)?;
    }
    let shape = shape_of(set);
    let mut candidates = layouts(options.profile, &shape, options.storage, options.memory_factor)?;
    let trial_steps = ((options.train.steps as f64 * TRIAL_SHARE).round() as usize).max(1);
    let trials = if candidates.len() > 1 && options.layout == LayoutChoice::Trial { 2 } else { 0 };
    let total = options.train.steps + trials * trial_steps;
    // Steps counted over the trials and the training: `done` steps before this one.
    let mut counted =
        |done: usize, p: Progress| progress(Progress { step: done + p.step, steps: total, ..p });
    let mut trial = None;
    let bits_first = candidates.len() > 1
        && match options.layout {
            LayoutChoice::ResolutionFirst => false,
            LayoutChoice::BitsFirst => true,
            LayoutChoice::Trial => {
                let mut psnr = [0.0; 2];
                for (k, (db, layout)) in psnr.iter_mut().zip(&candidates).enumerate() {
                    let o = TrainOptions { steps: trial_steps, ..options.train.clone() };
                    let done = k * trial_steps;
                    *db = trained(set, options, layout, (&o, 0), &mut |p| counted(done, p))?
                        .quality
                        .psnr;
                }
                let t = LayoutTrial { resolution_first_db: psnr[0], bits_first_db: psnr[1] };
                trial = Some(t);
                t.chosen() == LayoutChoice::BitsFirst
            }
        };
    // Where the profile grows only one way at this factor, a larger one grows the way asked for.
    let grow_bits_first = if candidates.len() > 1 {
        bits_first
    } else {
        options.layout != LayoutChoice::ResolutionFirst
    };
    let layout = candidates.swap_remove(usize::from(bits_first));
    let done = trials * trial_steps;
    let polish = options.polish_sweeps.unwrap_or(options.profile.polish_sweeps());
    let train = (&options.train, polish);
    let encoded = trained(set, options, &layout, train, &mut |p| counted(done, p))?;
    let done = total;
    let total = total + options.train.steps;
    let mut counted = |p: Progress| progress(Progress { step: done + p.step, steps: total, ..p });
    let regrown = match underfilled(set, options, (&layout, grow_bits_first), &encoded, polish) {
        Some(larger) => regrown(set, options, &larger, &mut counted)?,
        None => None,
    };
    let encoded = match regrown {
        Some(larger) if larger.quality.psnr > encoded.quality.psnr => larger,
        _ => encoded,
    };
    Ok(Encoded { trial, ..encoded })
}

/// How far under the profile's nominal size a packed file may land before the encode trains a
/// larger layout for it ([`regrown`]).
const UNDERFILL: f64 = 0.003;

/// Sweeps of the polish that brings a [`regrown`] layout down to the nominal size.
const REGROWN_SWEEPS: u8 = 6;

/// The larger layout to train again where `encoded` (trained on `layout`, packed, polished) came
/// out more than [`UNDERFILL`] under the profile's nominal size: the latents coded under their
/// target on their own, so the layout, not the rate control, held the file back. The layout of
/// [`MAX_MEMORY_FACTOR`] grown the same way (`bits_first`: one more bit first where there are
/// two ways), trained without the rate control's pull (a pull strong enough to matter holds the
/// whole network back: docs/ENCODING.md, "Rate control"). `None` where the file is fixed-rate,
/// not polished, already at the largest factor or not under.
fn underfilled(
    set: &TextureSet,
    options: &EncodeOptions,
    (layout, bits_first): (&Layout, bool),
    encoded: &Encoded,
    polish: u8,
) -> Option<Layout> {
    let shape = shape_of(set);
    let nominal = nominal_bytes(options.profile, &shape);
    let under = (encoded.file().len() as f64) < nominal * (1.0 - UNDERFILL);
    if options.storage != Storage::Packed
        || polish == 0
        || options.memory_factor >= MAX_MEMORY_FACTOR
        || layout.latent_bytes.is_none()
        || !under
    {
        return None;
    }
    let mut larger = layouts(options.profile, &shape, options.storage, MAX_MEMORY_FACTOR).ok()?;
    let layout = larger.swap_remove(usize::from(bits_first).min(larger.len() - 1));
    Some(Layout { latent_bytes: None, ..layout })
}

/// `layout` (from [`underfilled`]) trained without the rate control's pull, its output layer
/// refitted, its latents polished down to the profile's nominal size with the rate traded
/// ([`rate_polished`]) and its output biases calibrated; `None` where the polish could not
/// bring it within [`POLISH_GROWTH`] of the nominal size.
fn regrown(
    set: &TextureSet,
    options: &EncodeOptions,
    layout: &Layout,
    progress: &mut dyn FnMut(Progress),
) -> Result<Option<Encoded>, EncodeError> {
    let (spec, encoded) = stored(set, options, layout, &options.train, progress)?;
    let (spec, encoded) = refitted(spec, encoded, set, options)?;
    let steps = options.train.steps;
    let mut report = |psnr| progress(Progress { step: steps, steps, psnr, phase: Phase::Polish });
    let nominal = nominal_bytes(options.profile, &shape_of(set));
    match rate_polished(spec, encoded, set, options, nominal, &mut report)? {
        Some((spec, encoded)) => Ok(Some(calibrated(spec, encoded, set, options)?)),
        None => Ok(None),
    }
}

/// The weight of a bit in the first sweep of [`rate_polished`] for a file 14 % above its size
/// (as a share of the chain's squared error per bit): on `stk-eggkart` at `ntc-0.2` one sweep at
/// this weight cut the packed size by 14–17 % (docs/ENCODING.md, "The regrown layout").
const TRADE_WEIGHT: f64 = 0.66;

/// `encoded` (of `spec`, packed) polished for [`REGROWN_SWEEPS`] sweeps with the rate traded
/// ([`polish::Rate::Traded`]) while the file is above `nominal` bytes, each sweep's weight of a
/// bit in proportion to how far above (from 2 % to 3× [`TRADE_WEIGHT`]), and rate-neutral
/// ([`polish::Rate::Neutral`]) once it is not. The sweep that decodes best within
/// [`POLISH_GROWTH`] of `nominal`, if any.
fn rate_polished(
    mut spec: MaterialSpec,
    mut encoded: Encoded,
    set: &TextureSet,
    options: &EncodeOptions,
    nominal: f64,
    report: &mut dyn FnMut(f64),
) -> Result<Option<(MaterialSpec, Encoded)>, EncodeError> {
    let mut best: Option<(MaterialSpec, Encoded)> = None;
    for _ in 0..REGROWN_SWEEPS {
        report(encoded.quality.psnr);
        let size = encoded.file().len() as f64;
        let excess = size / nominal - 1.0;
        let rate = if excess > 0.0 {
            let weight = TRADE_WEIGHT * (excess / 0.14).clamp(0.02, 3.0);
            polish::Rate::Traded { weight, bits: size * 8.0 }
        } else {
            polish::Rate::Neutral
        };
        polish::polish(&mut spec, set, rate)?;
        encoded = encoded.rewritten(&spec, set, options.storage)?;
        let fits = encoded.file().len() as f64 <= nominal * (1.0 + POLISH_GROWTH);
        if fits && best.as_ref().is_none_or(|(_, b)| b.quality.psnr < encoded.quality.psnr) {
            best = Some((spec.clone(), encoded.clone()));
        }
    }
    Ok(best)
}

/// What a layout trial measured ([`LayoutChoice::Trial`]): each way's whole-chain PSNR (integer
/// decoder, stored file) after [`TRIAL_SHARE`] of the steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayoutTrial {
    pub resolution_first_db: f64,
    pub bits_first_db: f64,
}

impl LayoutTrial {
    /// The way the encode kept: bits first where its trial decoded strictly better.
    pub fn chosen(&self) -> LayoutChoice {
        if self.bits_first_db > self.resolution_first_db {
            LayoutChoice::BitsFirst
        } else {
            LayoutChoice::ResolutionFirst
        }
    }
}

/// `layout` trained for `set` with `train` (an output margin left open: the profile's), its latents
/// steered to the layout's coded size (no trial), its output layer refitted, its latents polished
/// (`polish` sweeps) and its output biases calibrated on the chain.
fn trained(
    set: &TextureSet,
    options: &EncodeOptions,
    layout: &Layout,
    (train, polish): (&TrainOptions, u8),
    progress: &mut dyn FnMut(Progress),
) -> Result<Encoded, EncodeError> {
    let (spec, encoded) = stored(set, options, layout, train, progress)?;
    let (spec, encoded) = refitted(spec, encoded, set, options)?;
    let mut report = |psnr| {
        let steps = train.steps;
        progress(Progress { step: steps, steps, psnr, phase: Phase::Polish });
    };
    let (spec, encoded) = polished(spec, encoded, set, options, polish, &mut report)?;
    calibrated(spec, encoded, set, options)
}

/// [`trained`] as training leaves it: the spec and its file, before the output layer is refitted.
fn stored(
    set: &TextureSet,
    options: &EncodeOptions,
    layout: &Layout,
    train: &TrainOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<(MaterialSpec, Encoded), EncodeError> {
    let mut config = layout.config.clone();
    if options.legacy_lod && config.lod_code != 0 {
        config.lod_code = 1;
    }
    // A margin the caller left open is the profile's.
    let output_margin = Some(train.output_margin.unwrap_or(options.profile.output_margin()));
    let train_options =
        TrainOptions { latent_bytes: layout.latent_bytes, output_margin, ..train.clone() };
    let mut model = train::Model::new(set, &config, options.address_mode, &train_options);
    model.train(&train_options, progress);
    let spec = to_spec(set, &model, options)?;
    let bytes = spec.to_bytes()?;
    let (packed, quality) = as_stored(&bytes, set, options.storage)?;
    Ok((spec, Encoded { bytes, packed, config, quality, trial: None }))
}

/// `encoded` (of `spec`) with its output layer refitted by least squares on the integer
/// decoder's hidden activations over the whole chain ([`refit`]), if that decodes better.
/// Training fits that layer to float activations and to texels drawn at random; the file is
/// judged on every texel through the integer decoder (docs/ENCODING.md, "The output layer
/// refit").
fn refitted(
    mut spec: MaterialSpec,
    encoded: Encoded,
    set: &TextureSet,
    options: &EncodeOptions,
) -> Result<(MaterialSpec, Encoded), EncodeError> {
    let mut mlp = spec.mlp.clone();
    let changed = refit::refit_output_layer(&mut mlp, &Container::parse(&encoded.bytes)?, set);
    if !changed {
        return Ok((spec, encoded));
    }
    let trained = core::mem::replace(&mut spec.mlp, mlp);
    if let Ok(bytes) = spec.to_bytes() {
        let (packed, quality) = as_stored(&bytes, set, options.storage)?;
        if quality.psnr > encoded.quality.psnr {
            return Ok((spec, Encoded { bytes, packed, quality, ..encoded }));
        }
    }
    spec.mlp = trained;
    Ok((spec, encoded))
}

/// `encoded` (of `spec`) after up to `sweeps` sweeps of the latent polish ([`polish`]), each
/// kept only if the file then decodes better and, packed, grows by at most [`POLISH_GROWTH`]
/// (the polish keeps the coded size by an estimate of the coder's contexts, not by the coder).
fn polished(
    mut spec: MaterialSpec,
    mut encoded: Encoded,
    set: &TextureSet,
    options: &EncodeOptions,
    sweeps: u8,
    report: &mut dyn FnMut(f64),
) -> Result<(MaterialSpec, Encoded), EncodeError> {
    let rate = match options.storage {
        Storage::Packed => polish::Rate::Neutral,
        Storage::FixedRate => polish::Rate::Free,
    };
    for _ in 0..sweeps {
        report(encoded.quality.psnr);
        let mut next = spec.clone();
        let done = polish::polish(&mut next, set, rate)?;
        if done.error_after >= done.error_before {
            break;
        }
        let candidate = encoded.rewritten(&next, set, options.storage)?;
        let grown = candidate.file().len() as f64 / encoded.file().len() as f64;
        if candidate.quality.psnr <= encoded.quality.psnr || grown > 1.0 + POLISH_GROWTH {
            break;
        }
        spec = next;
        encoded = candidate;
    }
    Ok((spec, encoded))
}

/// How much a polish sweep may grow a packed file (its coded size is kept by an estimate).
const POLISH_GROWTH: f64 = 0.01;

/// Rounds of [`calibrated`]: each moves the biases by the mean errors left, while that decodes
/// better (outputs clamped at an end of their range leave part of a move for the next round).
const CALIBRATION_ROUNDS: usize = 3;

/// `encoded` (of `spec`) with its output layer's biases moved by each channel's mean error over
/// the chain, as long as that decodes better. A network can end its training with a constant
/// offset on a channel: `stk-eggkart` at `ntc-0.2`, seed 2, came out with +2.6 and −1.7 levels
/// on two normal channels at every mip, and calibrated decodes 1.57 dB better
/// (docs/ENCODING.md, "Output biases calibrated on the chain").
fn calibrated(
    mut spec: MaterialSpec,
    mut encoded: Encoded,
    set: &TextureSet,
    options: &EncodeOptions,
) -> Result<Encoded, EncodeError> {
    for _ in 0..CALIBRATION_ROUNDS {
        if !move_output_biases(&mut spec.mlp, &encoded.quality.mean_error) {
            break;
        }
        let Ok(bytes) = spec.to_bytes() else { break };
        let (packed, quality) = as_stored(&bytes, set, options.storage)?;
        if quality.psnr <= encoded.quality.psnr {
            break;
        }
        encoded = Encoded { bytes, packed, quality, ..encoded };
    }
    Ok(encoded)
}

/// Moves the output layer's bias of each channel by `-mean_error` (unit scale; an output is
/// `(Σ w·x + bias) · scale · 2^−in_frac` before the clamp, FORMAT.md §6.6). Whether any moved.
fn move_output_biases(mlp: &mut MlpSpec, mean_error: &[f64]) -> bool {
    let in_frac = match mlp.layers.len() {
        0 | 1 => mlp.input_frac_bits,
        n => mlp.layers[n - 2].out_frac_bits,
    };
    let Some(layer) = mlp.layers.last_mut() else { return false };
    let lsb = 2f64.powi(-i32::from(in_frac));
    let limit = train::bias_limit(usize::from(layer.inputs));
    let mut moved = false;
    let rows = layer.bias.iter_mut().zip(&layer.scales).zip(mean_error);
    for ((bias, &scale), &error) in rows {
        if scale > 0.0 {
            let step = (-error / (f64::from(scale) * lsb)).round();
            let new = (f64::from(*bias) + step).clamp(-limit, limit);
            moved |= new as i32 != *bias;
            *bias = new as i32;
        }
    }
    moved
}

/// A fixed-rate file as it will be stored: its packed form where `storage` asks for one and it
/// is smaller, and the quality of its decode against `set`, at the rate of the stored file.
pub(crate) fn as_stored(
    fixed: &[u8],
    set: &TextureSet,
    storage: Storage,
) -> Result<(Option<Vec<u8>>, metrics::ChainQuality), EncodeError> {
    let material = Container::parse(fixed)?;
    let mut quality = metrics::chain_quality(&material, set);
    let packed = packed_form(fixed, storage)?;
    if let Some(p) = &packed {
        quality.bppc = material.bppc_of(p.len());
    }
    Ok((packed, quality))
}

/// What the rate solver needs to know of `set` (its file carries a SOURCE_MAPS section).
pub fn shape_of(set: &TextureSet) -> MaterialShape {
    MaterialShape {
        width: set.width,
        height: set.height,
        mip_count: set.mips.len() as u32,
        channels: set.channel_count(),
        learned: set.learned_channels().len(),
        optional_bytes: source_maps::encode(&set.maps).len(),
    }
}

fn to_spec(
    set: &TextureSet,
    model: &train::Model<'_>,
    options: &EncodeOptions,
) -> Result<MaterialSpec, EncodeError> {
    let cfg = model.cfg;
    let ranges = model.activation_ranges(8192, options.train.seed, options.train.kernel());
    let mut frac = train::INPUT_FRAC_BITS;
    let mut layers = Vec::new();
    let last = model.layers.len() - 1;
    for (k, l) in model.layers.iter().enumerate() {
        let (out_frac, activation, rows): (u8, Activation, Vec<Option<usize>>) = if k == last {
            let mut next = 0;
            let rows = set
                .channels
                .iter()
                .map(|c| {
                    c.constant.is_none().then(|| {
                        next += 1;
                        next - 1
                    })
                })
                .collect();
            (train::OUTPUT_FRAC_BITS, Activation::None, rows)
        } else {
            (
                train::frac_bits_for(ranges[k]),
                Activation::HardGelu,
                (0..l.outputs).map(Some).collect(),
            )
        };
        layers.push(train::export_layer(l, frac, out_frac, &rows, activation));
        frac = out_frac;
    }
    let channels = channel_specs(set);
    let grids = model
        .grids
        .iter()
        .map(|g| GridSpec {
            width: g.width as u16,
            height: g.height as u16,
            channels: g.channels as u8,
            bits: g.bits,
            quantization: vec![(g.offset_q, g.step_q); g.channels],
            codes: model.codes(g),
        })
        .collect();
    let levels = cfg
        .levels
        .iter()
        .map(|terms| LevelSpec {
            terms: terms
                .iter()
                .map(|t| TermSpec {
                    mode: t.mode,
                    grids: t.grids.iter().map(|&g| g as u8).collect(),
                })
                .collect(),
        })
        .collect();
    Ok(MaterialSpec {
        width: set.width,
        height: set.height,
        mip_count: set.mips.len() as u8,
        address_mode: options.address_mode,
        channels,
        mip_to_level: cfg.mip_to_level.clone(),
        grids,
        levels,
        mlp: MlpSpec {
            input_frac_bits: train::INPUT_FRAC_BITS,
            pe_frequencies: cfg.pe_frequencies,
            lod_input: cfg.lod_code,
            layers,
        },
        optional_sections: vec![(source_maps::SECTION_KIND, source_maps::encode(&set.maps))],
    })
}

/// The material's channels as written: each with its role's meaning, colour space and nominal
/// range, a constant channel as the one-value range it stands for (both codecs).
pub(crate) fn channel_specs(set: &TextureSet) -> Vec<ChannelSpec> {
    set.channels
        .iter()
        .map(|c| {
            let (lo, hi) = c.role.nominal_range(c.component);
            let (range_min, range_max) = match c.constant {
                Some(u) => {
                    let v = lo + u * (hi - lo);
                    (v, v)
                }
                None => (lo, hi),
            };
            ChannelSpec {
                name: c.name.clone(),
                semantic: c.role.semantic(),
                component: c.component,
                color_space: c.role.color_space(),
                range_min,
                range_max,
            }
        })
        .collect()
}

/// What the workspace's other crates share with the encoder beyond its API (the training
/// benchmark of `nmat bench-train`): not part of the API, hidden from the documentation.
#[doc(hidden)]
pub mod internals {
    pub use crate::train::{Model, mlp_flops_per_sample};
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_packed_polished_file_under_its_size_is_regrown() {
        // A file of a given size (its bytes are not read) trained on the default layout.
        let set = demo::bricks(512);
        let profile = Profile::by_name("ntc-0.2").unwrap();
        let options = EncodeOptions { profile, ..EncodeOptions::default() };
        let shape = shape_of(&set);
        let mut first = layouts(options.profile, &shape, options.storage, 1.5).unwrap();
        let layout = first.swap_remove(0);
        assert!(layout.latent_bytes.is_some(), "the default layout is steered");
        let nominal = nominal_bytes(options.profile, &shape);
        let file = |share: f64| Encoded {
            bytes: vec![0; (nominal * share) as usize],
            packed: None,
            config: layout.config.clone(),
            quality: metrics::ChainQuality::default(),
            trial: None,
        };
        let under = file(0.99);
        // Under by 1 %: the layout of the largest factor, grown bits first, without a pull.
        let larger = underfilled(&set, &options, (&layout, true), &under, 2).unwrap();
        let expected = layouts(options.profile, &shape, options.storage, MAX_MEMORY_FACTOR)
            .unwrap()
            .pop()
            .unwrap();
        assert_eq!(larger, Layout { latent_bytes: None, ..expected });
        assert!(
            larger.config.byte_budget(&shape).total() > layout.config.byte_budget(&shape).total()
        );
        // Resolution first where asked (at this size the two ways differ).
        let resolution = underfilled(&set, &options, (&layout, false), &under, 2).unwrap();
        let first_way = layouts(options.profile, &shape, options.storage, MAX_MEMORY_FACTOR)
            .unwrap()
            .swap_remove(0);
        assert_eq!(resolution.config, first_way.config);
        assert_ne!(resolution.config, larger.config);
        // Not where the file is at its size, or not polished, fixed-rate, at the largest factor.
        assert_eq!(underfilled(&set, &options, (&layout, true), &file(0.999), 2), None);
        assert_eq!(underfilled(&set, &options, (&layout, true), &under, 0), None);
        let fixed = EncodeOptions { storage: Storage::FixedRate, ..options.clone() };
        assert_eq!(underfilled(&set, &fixed, (&layout, true), &under, 2), None);
        let largest = EncodeOptions { memory_factor: MAX_MEMORY_FACTOR, ..options };
        assert_eq!(underfilled(&set, &largest, (&layout, true), &under, 2), None);
    }
}
