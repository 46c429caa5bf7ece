//! What several commands share: the error type, reading a .nmat file with its warnings, thread
//! and profile arguments, training and decoding with progress, and sizes for messages.

use crate::args::TrainArgs;
use nmat_cli::output;
use nmat_cli::progress::Progress;
use nmat_core::{Container, Material};
use nmat_encode::metrics::ChainQuality;
use nmat_encode::texset::TextureSet;
use nmat_encode::{
    Effort, EncodeError, EncodeOption, EncodeOptions, Encoded, PROFILES, Phase, Profile,
    TrainOptions, encode,
};
use std::path::Path;

pub type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// The flag that sets an encoder option: the encoder names its options as its API does, the
/// command's messages by its flags.
pub fn flag(option: EncodeOption) -> &'static str {
    match option {
        EncodeOption::MaxMemory => "--max-memory",
        EncodeOption::Resize => "--resize",
        EncodeOption::Map => "--map",
        EncodeOption::Quality => "--quality",
        EncodeOption::Bppc => "--bppc",
        EncodeOption::Steps => "--steps",
        EncodeOption::TargetPsnr => "--target-psnr",
        EncodeOption::MemoryFactor => "--memory-factor",
        EncodeOption::OutputMargin => "--output-margin",
        other => other.api_name(),
    }
}

/// An error as the command prints it: an encoder error with its options named by their flags.
pub fn message(e: &(dyn std::error::Error + 'static)) -> String {
    match e.downcast_ref::<EncodeError>() {
        Some(e) => e.naming_options(flag).to_string(),
        None => e.to_string(),
    }
}

/// Parses the file at `path`, and says (on stderr, once) which of its optional sections are
/// damaged and so ignored by every command.
pub fn parse<'a>(bytes: &'a [u8], path: &Path) -> Result<Material<'a>> {
    let m = Container::parse(bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    for warning in output::damaged_sections(path, &m) {
        eprintln!("{warning}");
    }
    Ok(m)
}

/// An error naming the files of `names` that already exist in `dir` (without `--force`, nothing
/// is replaced: the source maps may be there).
pub fn refuse_existing(dir: &Path, names: &[String]) -> Result<()> {
    let existing: Vec<&String> =
        names.iter().filter(|n| dir.join(n).symlink_metadata().is_ok()).collect();
    if let Some(first) = existing.first() {
        return Err(format!(
            "-o {}: {} of the files to write already exist ({}{}); nothing was written. \
             Pass --force to replace them, or choose another folder",
            dir.display(),
            existing.len(),
            first,
            if existing.len() > 1 { ", …" } else { "" }
        )
        .into());
    }
    Ok(())
}

/// The most worker threads `--threads` accepts: 4 × this machine's cores (more only adds
/// switching; a typo such as 10000 would otherwise start 10000 threads).
fn max_threads() -> usize {
    4 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `n` if it is a sane thread count, else an error naming `--threads`.
pub fn check_threads(n: usize) -> Result<usize> {
    let max = max_threads();
    if n == 0 || n > max {
        return Err(format!(
            "--threads {n}: must be between 1 and {max} (4 × the {} cores of this machine)",
            max / 4
        )
        .into());
    }
    Ok(n)
}

/// `--threads` of the commands that run on rayon's global pool: its size, when given.
pub fn threads(n: Option<usize>) -> Result<()> {
    if let Some(n) = n {
        let n = check_threads(n)?;
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
    }
    Ok(())
}

/// The trainer's options from `--steps`/`--effort`/`--seed`, `default_steps` being the
/// command's own default.
pub fn train_options(t: &TrainArgs, default_steps: usize) -> Result<TrainOptions> {
    let defaults = TrainOptions::default();
    let (steps, batch) = match t.steps {
        Some(steps) => (steps, defaults.batch),
        None => Effort::from(t.effort).schedule(default_steps, defaults.batch),
    };
    if steps == 0 {
        return Err(Box::new(EncodeError::BadOption {
            option: EncodeOption::Steps,
            value: "0".into(),
            reason: "must be at least 1",
        }));
    }
    // A run longer than the command's default trains on int8 weights throughout: a long float
    // run drifts to weights int8 rounds badly (`TrainOptions::int8_percent`).
    let int8_percent = if steps > default_steps { 100 } else { defaults.int8_percent };
    Ok(TrainOptions { steps, batch, seed: t.seed, int8_percent, ..defaults })
}

/// The profile `--profile` names, or an error listing them.
pub fn profile_named(name: &str) -> Result<Profile> {
    Profile::by_name(name).ok_or_else(|| {
        let names: Vec<&str> = PROFILES.iter().map(|p| p.name()).collect();
        format!("--profile {name}: unknown; choose one of {}", names.join(", ")).into()
    })
}

/// Trains with a progress bar (ETA and live PSNR of the training loss).
pub fn encode_with_progress(set: &TextureSet, options: &EncodeOptions) -> Result<Encoded> {
    let steps = options.train.steps as u64;
    let mut progress = Progress::new(options.profile.name(), steps, "steps");
    let encoded = encode(set, options, &mut |p| {
        // A layout trial adds its steps to the count.
        progress.set_total(p.steps as u64);
        progress.set(p.step as u64, &|| match p.phase {
            Phase::Polish => format!("polishing the latents: {:.2} dB over the chain", p.psnr),
            phase => format!("train PSNR {:.2} dB ({phase:?})", p.psnr),
        });
    })?;
    progress.finish();
    Ok(encoded)
}

/// Runs `work` with a progress callback over the texels a decode evaluates; progress is shown
/// (with the cost printed first) when the decode is long: more than [`LONG_DECODE_TEXELS`].
pub fn with_decode_progress<T>(
    label: &str,
    cost: nmat_core::DecodeCost,
    work: impl FnOnce(&mut dyn FnMut(u64)) -> T,
) -> T {
    if cost.texels < LONG_DECODE_TEXELS {
        return work(&mut |_| {});
    }
    eprintln!(
        "decoding {:.1} M texels ({:.1} G multiply-adds of the network)",
        cost.texels as f64 / 1e6,
        cost.macs as f64 / 1e9
    );
    let mut bar = Progress::new(label, cost.texels, "texels");
    let result = work(&mut |texels| bar.inc(texels));
    bar.finish();
    result
}

/// Whole-chain quality of `m` against `set`, with progress when the decode is long.
pub fn chain_quality_shown(m: &Material<'_>, set: &TextureSet) -> ChainQuality {
    chain_quality_shown_keeping(m, set, &mut |_, _| {})
}

/// [`chain_quality_shown`], handing each mip's decode to `keep` (`metrics::chain_quality_keeping`).
pub fn chain_quality_shown_keeping(
    m: &Material<'_>,
    set: &TextureSet,
    keep: &mut dyn FnMut(usize, Vec<f32>),
) -> ChainQuality {
    let cost = output::cost_of_mips(m, 0..m.mip_count());
    with_decode_progress("eval", cost, |progress| {
        nmat_encode::metrics::chain_quality_keeping(m, set, progress, keep)
    })
}

const MIB: f64 = (1u64 << 20) as f64;

/// `bytes` in MiB, for the budget messages of every command.
pub fn mib(bytes: u64) -> f64 {
    bytes as f64 / MIB
}

/// Decodes of at least this many texels show a progress bar (one 2048² mip chain is 5.6 M).
const LONG_DECODE_TEXELS: u64 = 4 << 20;

/// Multiply-adds of one texel decode with `outputs` rows in the last layer (0 for a JPEG
/// material: no network).
pub fn macs(m: &Material<'_>, outputs: usize) -> usize {
    let Some(n) = m.neural() else { return 0 };
    let layers = n.mlp().layers();
    let last = layers.len().saturating_sub(1);
    layers
        .iter()
        .enumerate()
        .map(|(i, l)| l.inputs() * if i == last { outputs } else { l.outputs() })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::args::EffortArg;

    #[test]
    fn runs_longer_than_the_default_train_on_int8_weights_throughout() {
        let int8 = |steps: Option<usize>, effort: EffortArg, default_steps: usize| {
            let t = TrainArgs { steps, effort, seed: 1, threads: None };
            train_options(&t, default_steps).map(|o| (o.steps, o.int8_percent)).unwrap()
        };
        let base = TrainOptions::default().int8_percent;
        assert_eq!(int8(None, EffortArg::Default, 30_000), (30_000, base));
        assert_eq!(int8(None, EffortArg::Fast, 30_000), (7_500, base));
        assert_eq!(int8(None, EffortArg::Max, 30_000), (60_000, 100));
        assert_eq!(int8(Some(30_000), EffortArg::Default, 30_000), (30_000, base));
        assert_eq!(int8(Some(30_001), EffortArg::Default, 30_000), (30_001, 100));
        // The demo's own default decides for the demo.
        assert_eq!(int8(Some(5), EffortArg::Default, 3_000), (5, base));
        assert_eq!(int8(None, EffortArg::Max, 3_000), (6_000, 100));
    }
}
