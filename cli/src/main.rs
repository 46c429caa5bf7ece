//! `nmat`: encode material maps into a `.nmat` file and back, inspect and evaluate it, or run the
//! whole chain on a bundled procedural material (`nmat demo`). See docs/ENCODING.md.

mod bench;
#[cfg(feature = "gpu")]
mod bench_gpu;
mod bench_train;
mod walk;

use clap::{Args, Parser, Subcommand, ValueEnum};
use nmat_cli::input::read_nmat;
use nmat_cli::output;
use nmat_cli::progress::Progress;
use nmat_core::{AddressMode, Container, Material};
use nmat_encode::metrics::ChainQuality;
use nmat_encode::names;
use nmat_encode::texset::{self, LoadOptions, Role};
use nmat_encode::{
    Effort, EncodeError, EncodeOptions, Encoded, PROFILES, Profile, TextureSet, TrainKernel,
    TrainOptions, encode,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "nmat",
    version,
    about = "Neural material textures: encode, decode, inspect, evaluate"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Compress a folder (or list) of material maps into one .nmat file.
    Encode(EncodeArgs),
    /// Write the maps of a .nmat file back as images.
    Decode(DecodeArgs),
    /// Transcode a .nmat file to GPU block-compressed textures (BC1/BC4/BC5/BC7, whole mip
    /// chain) in KTX2 or DDS files, for engines that sample BC textures with unchanged shaders.
    Transcode(TranscodeArgs),
    /// Turn a baseline JPEG file into a .nmat material (one map, mip 0 only) without re-encoding
    /// it: an index of its MCUs and their DC values makes every texel decodable on its own
    /// (docs/FORMAT.md §11). Progressive or arithmetic-coded files are refused.
    Index {
        /// The JPEG file (gray or YCbCr; 4:4:4, 4:2:2, 4:4:0 or 4:2:0).
        input: PathBuf,
        /// The .nmat file to write.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        memory: MemoryArg,
    },
    /// Print what a .nmat file holds.
    Info { input: PathBuf },
    /// Compare a .nmat file with the source maps: PSNR per map and mip, SSIM, BPPC.
    Eval {
        input: PathBuf,
        /// Folder with the reference maps.
        #[arg(long = "ref")]
        reference: PathBuf,
        /// Compare even when the reference maps do not match the material's channels by role
        /// (by default that is refused: the numbers would compare different maps).
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        memory: MemoryArg,
    },
    /// The speed–accuracy table of docs/PERFORMANCE.md for one or more .nmat files: every decode
    /// mode (kernels, float, channel subsets, filters, random access, threads) over one region of
    /// mip 0, with the CPU's roofline, BC1/BC4 and PNG decoding measured in the same run, and the
    /// GPU when built with `--features gpu`.
    Bench {
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Folder with the source maps: adds PSNR and PNG decode time.
        #[arg(long = "ref")]
        reference: Option<PathBuf>,
        /// Side of the square region of mip 0 each mode decodes.
        #[arg(long, default_value_t = 256)]
        region: u32,
        /// Timed runs per row (the median is reported).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Measure the GPU decoder instead (docs/GPU.md): kernels timed with GPU timestamps
        /// against the adapter's measured integer peak, for a region, the whole chain, random
        /// requests and channel subsets. Needs the `gpu` feature.
        #[arg(long)]
        gpu: bool,
        /// With --ref: measure even when the reference maps do not match the material's
        /// channels by role.
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        memory: MemoryArg,
    },
    /// The trainer's throughput (docs/PERFORMANCE.md): steps/s, samples/s, GFLOP/s and share of
    /// the CPU's f32 FMA peak for every matrix-product kernel and thread count, on one material.
    BenchTrain(BenchTrainArgs),
    /// A headless walk down a textured corridor at 1920×1080 with the tile cache: per frame the
    /// tiles marked, decoded and kept, the texels decoded, and the milliseconds of marking,
    /// decoding and resolving, against decoding every lookup directly (docs/PERFORMANCE.md,
    /// "Tile cache"). The materials cover floor, walls, ceiling and end wall in turn.
    Walk {
        /// One to four .nmat files with at least 3 channels (channels 0–2 are shown).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Frame size in pixels, WIDTHxHEIGHT.
        #[arg(long, default_value = "1920x1080", value_parser = parse_size)]
        size: (u32, u32),
        /// Frames of the camera path (the same path, sampled more or less densely).
        #[arg(long, default_value_t = 60)]
        frames: u32,
        /// Thread counts to measure, comma-separated.
        #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
        threads: Vec<usize>,
        /// Tiles the cache holds (16×16 texels each).
        #[arg(long, default_value_t = 16384)]
        tiles: usize,
        /// Every how many frames to also decode every lookup directly, without the cache, and
        /// compare (0: never).
        #[arg(long, default_value_t = 10)]
        direct_every: u32,
        /// Only the walk with mips (trilinear) or without (bilinear at mip 0); default both.
        #[arg(long)]
        mips: Option<bool>,
        /// Write one row per frame and setting to this CSV file.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Write the last frame of the walk with mips (channels 0–2) to this PNG file.
        #[arg(long)]
        image: Option<PathBuf>,
        /// Also walk with the GPU's tile cache (wgpu), against `nmat_sample` without it (neural
        /// materials). Needs the `gpu` feature: cargo build --release -p nmat --features gpu
        #[arg(long)]
        gpu: bool,
        #[command(flatten)]
        memory: MemoryArg,
    },
    /// Encode, decode and evaluate a bundled procedural material, and print a report.
    Demo {
        /// Where to write demo.nmat and the decoded maps.
        #[arg(short, long, default_value = "target/nmat-demo")]
        out: PathBuf,
        #[command(flatten)]
        train: TrainArgs,
        #[arg(long, default_value = nmat_encode::DEFAULT_PROFILE)]
        profile: String,
    },
}

#[derive(Args)]
struct BenchTrainArgs {
    /// Folders and/or map files (default: the bundled procedural material at 1024²).
    inputs: Vec<PathBuf>,
    #[arg(long, default_value = nmat_encode::DEFAULT_PROFILE)]
    profile: String,
    /// Optimizer steps per timed run.
    #[arg(long, default_value_t = 100)]
    steps: usize,
    /// Thread counts to measure, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
    threads: Vec<usize>,
    /// Kernels to measure, comma-separated (scalar, avx2, avx512), or `all` this CPU runs.
    #[arg(long, value_delimiter = ',', default_values_t = ["all".to_string()])]
    kernel: Vec<String>,
    /// Timed runs per row (the median is reported).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Percent of the steps in the joint and the quantization-aware phase, as `JOINT,QAT`
    /// (default: the encoder's; `80,5` is the phase mix of the trainer before the SIMD work).
    #[arg(long, value_delimiter = ',', value_name = "JOINT,QAT")]
    phases: Option<Vec<u32>>,
    #[command(flatten)]
    memory: MemoryArg,
}

/// `--max-memory` of the commands whose memory grows with a number given to them or read from a
/// file's header.
#[derive(Args)]
struct MemoryArg {
    /// Memory this command may use, e.g. 8G or 512M (MiB without a unit); work that would need
    /// more is refused before it starts [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    max_memory: Option<u64>,
}

impl MemoryArg {
    fn bytes(&self) -> u64 {
        self.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY)
    }
}

#[derive(Args)]
struct TrainArgs {
    /// Optimizer steps (more: better quality, longer encode) [default: 30000 for encode, 3000
    /// for demo].
    #[arg(long, conflicts_with = "effort")]
    steps: Option<usize>,
    /// Encode time for quality: fast = ¼ of the default steps (0.4–0.9 dB lower); max = twice
    /// the steps, about twice the time (+0.16–0.43 dB at the default profile ntc-0.5 on the
    /// materials measured; docs/ENCODING.md).
    #[arg(long, value_enum, default_value_t = EffortArg::Default)]
    effort: EffortArg,
    /// Seed of every random choice: same inputs, seed and steps give the same file.
    #[arg(long, default_value_t = TrainOptions::default().seed)]
    seed: u64,
    /// Worker threads (default: all cores). The file does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum EffortArg {
    Fast,
    Default,
    Max,
}

impl From<EffortArg> for Effort {
    fn from(e: EffortArg) -> Effort {
        match e {
            EffortArg::Fast => Effort::Fast,
            EffortArg::Default => Effort::Default,
            EffortArg::Max => Effort::Max,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum CodecArg {
    Neural,
    Jpeg,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum SubsamplingArg {
    #[value(name = "4:2:0")]
    S420,
    #[value(name = "4:2:2")]
    S422,
    #[value(name = "4:4:4")]
    S444,
}

#[derive(Clone, Copy, ValueEnum)]
enum Address {
    Wrap,
    Clamp,
}

#[derive(Args)]
struct EncodeArgs {
    /// Folders and/or map files; roles come from file names (or --map).
    inputs: Vec<PathBuf>,
    /// Output file.
    #[arg(short, long)]
    output: PathBuf,
    /// Assign a role explicitly: ROLE=PATH (albedo, normal, roughness, gloss, specular, height,
    /// ao, metallic, emissive, opacity). Repeatable.
    #[arg(long = "map", value_name = "ROLE=PATH")]
    maps: Vec<String>,
    /// neural: a network and latent grids (the profiles); jpeg: every map as indexed baseline
    /// JPEG (a colour map as YCbCr, others gray), decodable texel by texel like a neural one.
    #[arg(long, value_enum, default_value_t = CodecArg::Neural)]
    codec: CodecArg,
    /// Rate/layout profile (neural).
    #[arg(long, conflicts_with_all = ["bppc", "target_psnr", "quality"])]
    profile: Option<String>,
    /// Neural: pick the profile nearest to this many bits per pixel per channel; jpeg: the
    /// highest quality whose file is at most this rate.
    #[arg(long, conflicts_with_all = ["target_psnr", "quality"])]
    bppc: Option<f64>,
    /// JPEG quality, 1–100 on the IJG scale (cjpeg's) [default: 85] (jpeg).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    quality: Option<u8>,
    /// Chroma resolution of colour maps (albedo, emissive, specular colour); normals are always
    /// 4:4:4 [default: 4:2:0] (jpeg).
    #[arg(long, value_enum)]
    subsampling: Option<SubsamplingArg>,
    /// Search for the smallest profile whose whole-chain PSNR reaches this many dB.
    #[arg(long)]
    target_psnr: Option<f64>,
    /// Resize maps of another size to the first map's size (Lanczos3) instead of failing.
    #[arg(long)]
    resize: bool,
    /// Memory loading the maps may use, e.g. 8G or 512M (MiB without a unit); a map that would
    /// need more is refused before it is decoded [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    max_memory: Option<u64>,
    /// Texture addressing at the edges.
    #[arg(long, value_enum, default_value = "wrap")]
    address: Address,
    /// Solve the layout and print the file's byte budget without training; writes nothing.
    #[arg(long, conflicts_with = "target_psnr")]
    dry_run: bool,
    #[command(flatten)]
    train: TrainArgs,
}

#[derive(Args)]
struct DecodeArgs {
    input: PathBuf,
    /// Output folder (created if missing).
    #[arg(short, long)]
    output: PathBuf,
    /// Which mip to write: a number or "all".
    #[arg(long, default_value = "0")]
    mip: String,
    /// Decode with the float reference decoder instead of the integer-exact one.
    #[arg(long, conflicts_with = "int")]
    float: bool,
    /// Decode with the integer-exact decoder (the default).
    #[arg(long)]
    int: bool,
    /// Decode on the GPU (wgpu; bit-identical to --int). Needs the `gpu` feature:
    /// cargo build --release -p nmat --features gpu
    #[arg(long, conflicts_with = "float")]
    gpu: bool,
    /// Replace files that already exist in the output folder (by default nmat refuses, so the
    /// source maps are never overwritten with their decodes).
    #[arg(long)]
    force: bool,
    /// Write every map as PNG, whatever its original format (e.g. a gray+alpha map that came from
    /// a TIFF, which cannot hold one).
    #[arg(long)]
    png: bool,
    /// Memory the decoded maps may use, e.g. 8G or 512M (MiB without a unit); a larger decode is
    /// refused before it starts [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    max_memory: Option<u64>,
}

#[derive(Args)]
struct TranscodeArgs {
    input: PathBuf,
    /// Output folder (created if missing).
    #[arg(short, long)]
    output: PathBuf,
    /// `auto`: from each map's meaning (albedo → BC1 sRGB, normal → BC5 of X/Y, one channel →
    /// BC4, two → BC5, alpha → its own BC4); or one format for every map (bc7: RGB or RGBA,
    /// higher quality at twice BC1's size).
    #[arg(long, value_enum, default_value_t = FormatArg::Auto)]
    format: FormatArg,
    /// The format of the maps of one role, over --format: ROLE=FORMAT, e.g. albedo=bc7 (roles as
    /// in `nmat encode --map`). Repeatable.
    #[arg(long = "as", value_name = "ROLE=FORMAT")]
    as_role: Vec<String>,
    /// File container.
    #[arg(long, value_enum, default_value_t = ContainerArg::Ktx2)]
    container: ContainerArg,
    /// Worker threads (default: all cores). The files do not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Decode and encode BC1, BC4 and BC5 textures on the GPU (wgpu; the same bytes as the CPU;
    /// BC7 textures stay on the CPU). Needs the `gpu` feature:
    /// cargo build --release -p nmat --features gpu
    #[arg(long)]
    gpu: bool,
    /// Replace files that already exist in the output folder.
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    memory: MemoryArg,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FormatArg {
    Auto,
    Bc1,
    Bc4,
    Bc5,
    Bc7,
}

impl FormatArg {
    fn format(self) -> Option<nmat_core::bc::BcFormat> {
        use nmat_core::bc::BcFormat;
        match self {
            FormatArg::Auto => None,
            FormatArg::Bc1 => Some(BcFormat::Bc1),
            FormatArg::Bc4 => Some(BcFormat::Bc4),
            FormatArg::Bc5 => Some(BcFormat::Bc5),
            FormatArg::Bc7 => Some(BcFormat::Bc7Rgb),
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum ContainerArg {
    Ktx2,
    Dds,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    output::clean_up_on_signal();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("nmat: {e}");
            ExitCode::FAILURE
        }
    }
}

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Encode(args) => cmd_encode(args),
        Command::Decode(args) => cmd_decode(args),
        Command::Transcode(args) => cmd_transcode(args),
        Command::Index { input, output, memory } => cmd_index(&input, &output, memory.bytes()),
        Command::Info { input } => {
            let bytes = read_nmat(&input)?;
            let m = parse(&bytes, &input)?;
            print!("{}", output::describe(&input, &m));
            Ok(())
        }
        Command::Eval { input, reference, force, memory } => {
            cmd_eval(&input, &reference, force, memory.bytes())
        }
        Command::Demo { out, train, profile } => cmd_demo(&out, &train, &profile),
        Command::Walk {
            inputs,
            size,
            frames,
            threads,
            tiles,
            direct_every,
            mips,
            csv,
            image,
            gpu,
            memory,
        } => {
            if frames == 0 || tiles == 0 || inputs.len() > 4 {
                return Err("--frames and --tiles must be at least 1, and at most 4 inputs".into());
            }
            for &n in &threads {
                check_threads(n)?;
            }
            // The outputs are checked before the walk (minutes at the defaults) starts.
            let outputs = [("--csv", &csv), ("--image", &image)];
            for (option, path) in outputs {
                if let Some(path) = path {
                    output::check_output_file(option, path, &inputs)?;
                }
            }
            if let (Some(c), Some(i)) = (&csv, &image)
                && c == i
            {
                return Err(format!("--csv and --image both name {}", c.display()).into());
            }
            walk::run(&walk::Options {
                inputs,
                width: size.0,
                height: size.1,
                frames,
                threads,
                tiles,
                direct_every,
                mips: mips.map_or(vec![true, false], |m| vec![m]),
                csv,
                image,
                gpu,
                max_memory: memory.bytes(),
            })
        }
        Command::BenchTrain(args) => cmd_bench_train(args),
        Command::Bench { inputs, reference, region, runs, gpu, force, memory } => {
            if region == 0 || runs == 0 {
                return Err("--region and --runs must be at least 1".into());
            }
            let max_memory = memory.bytes();
            bench::run(&bench::Options { inputs, reference, region, runs, gpu, force, max_memory })
        }
    }
}

fn cmd_index(input: &Path, out: &Path, max_memory: u64) -> Result<()> {
    output::check_output(out, &[input.to_path_buf()])?;
    // A .nmat file holds at most 4 GiB (docs/FORMAT.md §2), so a larger JPEG cannot be indexed.
    let limit = max_memory.min(u64::from(u32::MAX));
    let file = nmat_encode::input::read_regular(input, limit)?;
    let indexed =
        nmat_encode::jpeg::index_jpeg(&file).map_err(|e| format!("{}: {e}", input.display()))?;
    // `nmat decode` writes the map back as STEM.png.
    let stem = input.file_stem().map_or("image".into(), |s| s.to_string_lossy());
    let bytes = nmat_encode::jpeg::material_from_jpeg(&indexed, &format!("{stem}.png"))
        .to_bytes()
        .map_err(|e| format!("{}: cannot index: {e}", input.display()))?;
    output::write_atomic(out, &bytes)?;
    let m = parse(&bytes, out)?;
    let (extra, coded) = m.jpeg().map_or((0, 0), |j| j.overhead_bits());
    let texels = f64::from(indexed.width) * f64::from(indexed.height);
    println!(
        "{}: {}×{} {}, {} bytes ({} bytes of JPEG data; index and DC values {:.3} bits per pixel)",
        out.display(),
        indexed.width,
        indexed.height,
        if indexed.map.channel_count == 3 {
            format!("YCbCr {}×{} luma per chroma sample", indexed.map.luma_h, indexed.map.luma_v)
        } else {
            "gray".to_string()
        },
        bytes.len(),
        coded / 8,
        extra as f64 / texels
    );
    Ok(())
}

/// `--max-memory`: a size with an optional binary unit (K, M, G; MiB without one), in bytes.
/// `WIDTHxHEIGHT`, each 1 to 16384.
fn parse_size(text: &str) -> std::result::Result<(u32, u32), String> {
    let bad = || format!("expected WIDTHxHEIGHT (each 1 to 16384), got {text:?}");
    let (w, h) = text.split_once(['x', '×']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

fn parse_memory(text: &str) -> std::result::Result<u64, String> {
    let t = text.trim();
    let (digits, shift) = match t.char_indices().last() {
        Some((i, 'K' | 'k')) => (&t[..i], 10),
        Some((i, 'M' | 'm')) => (&t[..i], 20),
        Some((i, 'G' | 'g')) => (&t[..i], 30),
        _ => (t, 20),
    };
    let n: u64 = digits
        .trim()
        .parse()
        .map_err(|_| format!("expected a size such as 8G or 512M, got {text:?}"))?;
    n.checked_mul(1 << shift)
        .filter(|&b| b > 0)
        .ok_or_else(|| format!("{text:?}: must be above 0 and below 16 EiB"))
}

/// The most worker threads `--threads` accepts: 4 × this machine's cores (more only adds
/// switching; a typo such as 10000 would otherwise start 10000 threads).
fn max_threads() -> usize {
    4 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `n` if it is a sane thread count, else an error naming `--threads`.
fn check_threads(n: usize) -> Result<usize> {
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

fn threads(n: Option<usize>) -> Result<()> {
    if let Some(n) = n {
        let n = check_threads(n)?;
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
    }
    Ok(())
}

/// Steps of `nmat demo` when not given: its 256² material needs fewer than a 1024² one.
const DEMO_STEPS: usize = 3000;

fn train_options(t: &TrainArgs, default_steps: usize) -> Result<TrainOptions> {
    let defaults = TrainOptions::default();
    let (steps, batch) = match t.steps {
        Some(steps) => (steps, defaults.batch),
        None => Effort::from(t.effort).schedule(default_steps, defaults.batch),
    };
    if steps == 0 {
        return Err(Box::new(EncodeError::BadOption {
            option: "--steps",
            value: "0".into(),
            reason: "must be at least 1",
        }));
    }
    Ok(TrainOptions { steps, batch, seed: t.seed, ..defaults })
}

fn profile_named(name: &str) -> Result<Profile> {
    Profile::by_name(name).ok_or_else(|| {
        let names: Vec<&str> = PROFILES.iter().map(|p| p.name()).collect();
        format!("--profile {name}: unknown; choose one of {}", names.join(", ")).into()
    })
}

/// Trains with a progress bar (ETA and live PSNR of the training loss).
fn encode_with_progress(set: &TextureSet, options: &EncodeOptions) -> Result<Encoded> {
    let steps = options.train.steps as u64;
    let mut progress = Progress::new(options.profile.name(), steps, "steps");
    let encoded = encode(set, options, &mut |p| {
        progress.set(p.step as u64, &|| format!("train PSNR {:.2} dB ({:?})", p.psnr, p.phase));
    })?;
    progress.finish();
    Ok(encoded)
}

fn cmd_encode(args: EncodeArgs) -> Result<()> {
    threads(args.train.threads)?;
    let explicit = args
        .maps
        .iter()
        .map(|m| texset::parse_map_argument(m))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let files = texset::collect_inputs(&args.inputs)?;
    if files.is_empty() && explicit.is_empty() {
        return Err("no input maps: pass a folder, files, or --map ROLE=PATH".into());
    }
    let roles = texset::assign_roles(&files, &explicit)?;
    if !args.dry_run {
        let inputs: Vec<PathBuf> = roles.iter().map(|(_, p)| p.clone()).collect();
        output::check_output(&args.output, &inputs)?;
    }
    let max_memory = args.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY);
    let set = texset::load(&roles, &LoadOptions { resize: args.resize, max_memory })?;
    let address_mode = match args.address {
        Address::Wrap => AddressMode::Wrap,
        Address::Clamp => AddressMode::Clamp,
    };
    if args.codec == CodecArg::Jpeg {
        return encode_jpeg(&args, &set, address_mode);
    }
    if let Some(q) = args.quality {
        return Err(Box::new(EncodeError::BadOption {
            option: "--quality",
            value: q.to_string(),
            reason: "sets the JPEG codec's quality; pass --codec jpeg (neural rates are \
                     --profile, --bppc or --target-psnr)",
        }));
    }
    if args.subsampling.is_some() {
        return Err("--subsampling belongs to the JPEG codec; pass --codec jpeg".into());
    }
    let train = train_options(&args.train, nmat_encode::train::DEFAULT_STEPS)?;
    let start = Instant::now();
    let encoded = if let Some(target) = args.target_psnr {
        search_target(&set, target, &train, address_mode)?
    } else {
        let profile = match (&args.profile, args.bppc) {
            (Some(name), _) => profile_named(name)?,
            (None, Some(b)) if b.is_finite() && b > 0.0 => Profile::nearest(b),
            (None, Some(b)) => {
                return Err(Box::new(EncodeError::BadOption {
                    option: "--bppc",
                    value: b.to_string(),
                    reason: "must be a positive number",
                }));
            }
            (None, None) => profile_named(nmat_encode::DEFAULT_PROFILE)?,
        };
        if args.dry_run {
            print!("{}", plan(&set, profile));
            return Ok(());
        }
        encode_with_progress(&set, &EncodeOptions { profile, train, address_mode })?
    };
    if let Some(note) = rate_note(&encoded) {
        eprintln!("{note}");
    }
    write_encoded(&args.output, &encoded.bytes, start)?;
    print!(
        "{}",
        output::quality_table(
            &set,
            &encoded.quality,
            Some(&format!("profile {}", encoded.config.profile)),
        )
    );
    Ok(())
}

/// Writes an encoded file atomically and says so, with the time since `start`.
fn write_encoded(path: &Path, bytes: &[u8], start: Instant) -> Result<()> {
    output::write_atomic(path, bytes)?;
    let seconds = start.elapsed().as_secs_f64();
    println!("wrote {} ({} bytes) in {seconds:.1} s", path.display(), bytes.len());
    Ok(())
}

/// `nmat encode --codec jpeg`: at `--quality` or the highest quality within `--bppc`.
fn encode_jpeg(args: &EncodeArgs, set: &TextureSet, address_mode: AddressMode) -> Result<()> {
    use nmat_encode::jpeg::{JpegOptions, Subsampling};
    let neural_only = [
        ("--profile", args.profile.is_some()),
        ("--target-psnr", args.target_psnr.is_some()),
        ("--dry-run", args.dry_run),
        ("--steps", args.train.steps.is_some()),
        ("--effort", args.train.effort != EffortArg::Default),
        ("--seed", args.train.seed != TrainOptions::default().seed),
    ];
    if let Some((option, _)) = neural_only.iter().find(|(_, given)| *given) {
        return Err(format!(
            "{option} belongs to the neural codec; --codec jpeg takes --quality or --bppc"
        )
        .into());
    }
    let subsampling = match args.subsampling {
        None | Some(SubsamplingArg::S420) => Subsampling::S420,
        Some(SubsamplingArg::S422) => Subsampling::S422,
        Some(SubsamplingArg::S444) => Subsampling::S444,
    };
    let quality = args.quality.unwrap_or(nmat_encode::jpeg::DEFAULT_QUALITY);
    let options = JpegOptions { quality, subsampling, address_mode };
    let start = Instant::now();
    let encoded = match args.bppc {
        Some(bppc) => nmat_encode::jpeg::encode_jpeg_to_rate(set, bppc, &options)?,
        None => nmat_encode::jpeg::encode_jpeg(set, &options)?,
    };
    if let Some(bppc) = args.bppc.filter(|&b| encoded.quality.bppc > b) {
        eprintln!(
            "note: {:.3} BPPC at quality 1 is above --bppc {bppc}: the MCU index and DC values \
             alone cost 0.21 bits per pixel of a 4:2:0 map and 0.47 of a gray one",
            encoded.quality.bppc
        );
    }
    write_encoded(&args.output, &encoded.bytes, start)?;
    let maps = nmat_encode::jpeg::plan_maps(set, subsampling);
    let setting = format!("jpeg quality {} ({} JPEG maps)", encoded.jpeg_quality, maps.len());
    print!("{}", output::quality_table(set, &encoded.quality, Some(&setting)));
    Ok(())
}

/// What `encode --dry-run` prints: the solved layout of `profile` for `set` and its byte budget.
fn plan(set: &TextureSet, profile: Profile) -> String {
    let shape = nmat_encode::shape_of(set);
    let cfg = nmat_encode::configure(profile, &shape);
    let budget = cfg.byte_budget(&shape);
    // BPPC's denominator: width · height · channels of mip 0.
    let texel_channels = shape.budget_bits(1.0);
    let mut s = format!(
        "{}: {}×{}, {} channels ({} learned), nominal {} BPPC, this file {:.4} BPPC ({:+.1} %)\n",
        profile.name(),
        set.width,
        set.height,
        set.channel_count(),
        shape.learned,
        profile.bppc(),
        budget.total() as f64 * 8.0 / texel_channels,
        100.0 * (budget.total() as f64 * 8.0 / shape.budget_bits(profile.bppc()) - 1.0)
    );
    s.push_str(&output::map_lines(&set.maps));
    s.push_str(&format!(
        "\nnetwork {} → {:?} → {}\n",
        cfg.input_width(),
        cfg.hidden,
        set.channel_count()
    ));
    for (i, g) in cfg.grids.iter().enumerate() {
        s.push_str(&format!(
            "  grid {i:2} {:5}×{:<5} {:2} channels × {} bits  {:8} bytes\n",
            g.width,
            g.height,
            g.channels,
            g.bits,
            4 * g.bits().div_ceil(32)
        ));
    }
    s.push_str(&output::budget_table(&budget, texel_channels));
    s
}

/// A note when the file lands more than 5 % away from its profile's nominal rate: the material is
/// too small for the rate (the smallest network and grids exceed it) or the layout's largest
/// grids fall short of it.
fn rate_note(e: &Encoded) -> Option<String> {
    let nominal = Profile::by_name(e.config.profile)?.bppc();
    let off = e.quality.bppc / nominal - 1.0;
    let why = if off > 0.0 {
        "the material is too small for that rate: its smallest network and grids are this file"
    } else {
        "the layout's largest grids do not reach that rate on this material"
    };
    (off.abs() > 0.05).then(|| {
        format!(
            "note: {:.3} BPPC is {:+.0} % from {}'s nominal {nominal}: {why}",
            e.quality.bppc,
            100.0 * off,
            e.config.profile
        )
    })
}

/// Encodes with profiles from the smallest rate up until the whole-chain PSNR reaches `target`.
fn search_target(
    set: &TextureSet,
    target: f64,
    train: &TrainOptions,
    address_mode: AddressMode,
) -> Result<Encoded> {
    if !target.is_finite() || target <= 0.0 {
        return Err(Box::new(EncodeError::BadOption {
            option: "--target-psnr",
            value: target.to_string(),
            reason: "must be a positive number of dB",
        }));
    }
    let mut order: Vec<Profile> = PROFILES.to_vec();
    order.sort_by(|a, b| a.bppc().total_cmp(&b.bppc()));
    let mut last = None;
    for profile in order {
        let e = encode_with_progress(
            set,
            &EncodeOptions { profile, train: train.clone(), address_mode },
        )?;
        eprintln!("  {:9} {:.3} BPPC  {:.2} dB", profile.name(), e.quality.bppc, e.quality.psnr);
        if e.quality.psnr >= target {
            return Ok(e);
        }
        last = Some(e);
    }
    eprintln!("no profile reached {target} dB; keeping the largest");
    last.ok_or_else(|| "no profile".into())
}

/// Parses the file at `path`, and says (on stderr, once) which of its optional sections are
/// damaged and so ignored by every command.
fn parse<'a>(bytes: &'a [u8], path: &Path) -> Result<Material<'a>> {
    let m = Container::parse(bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    for warning in output::damaged_sections(path, &m) {
        eprintln!("{warning}");
    }
    Ok(m)
}

fn cmd_decode(args: DecodeArgs) -> Result<()> {
    let bytes = read_nmat(&args.input)?;
    let m = parse(&bytes, &args.input)?;
    let mips: Vec<u32> = if args.mip == "all" {
        (0..m.mip_count()).collect()
    } else {
        let mip: u32 = args
            .mip
            .parse()
            .map_err(|_| format!("--mip {}: expected a number or \"all\"", args.mip))?;
        if mip >= m.mip_count() {
            return Err(
                format!("--mip {mip}: the material has mips 0..{}", m.mip_count() - 1).into()
            );
        }
        vec![mip]
    };
    let plan = output::DecodePlan::new(&m, &mips, args.png)
        .map_err(|e| format!("{}: {e}", args.input.display()))?;
    let names = plan.file_names();
    if !args.force {
        refuse_existing(&args.output, &names)?;
    }
    let (need, allowed) = (plan.memory(&m), args.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY));
    if need > allowed {
        return Err(format!(
            "{}: writing these maps needs about {:.1} MiB, more than the {:.1} MiB allowed; \
             nothing was written. Raise the limit with --max-memory or decode one mip at a time \
             (--mip)",
            args.input.display(),
            mib(need),
            mib(allowed)
        )
        .into());
    }
    let start = Instant::now();
    let float = args.float;
    let written = with_decode_progress("decode", plan.cost(&m), |progress| {
        output::write_all_or_nothing(&args.output, |dir| {
            if args.gpu {
                decode_on_gpu(&m, &plan, dir, progress)
            } else {
                let with = output::DecodeWith { float, batch: None };
                output::write_maps(&m, &plan, dir, with, progress)
            }
        })
    })?;
    for w in &written {
        println!("wrote {}", w.display());
    }
    println!("decoded {} files in {:.1} s", written.len(), start.elapsed().as_secs_f64());
    Ok(())
}

/// An error naming the files of `names` that already exist in `dir` (without `--force`, nothing
/// is replaced: the source maps may be there).
fn refuse_existing(dir: &Path, names: &[String]) -> Result<()> {
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

fn cmd_transcode(args: TranscodeArgs) -> Result<()> {
    use nmat_cli::transcode::{self, Choice, Container};
    threads(args.threads)?;
    let mut choice = Choice { all: args.format.format(), by_semantic: Vec::new() };
    for text in &args.as_role {
        let (role, format) = text
            .split_once('=')
            .ok_or_else(|| format!("--as {text}: expected ROLE=FORMAT, e.g. albedo=bc7"))?;
        let role = Role::parse(role.trim()).ok_or_else(|| {
            let roles: Vec<&str> = Role::ALL.iter().map(|r| r.name()).collect();
            format!("--as {text}: unknown role {role:?}; choose one of {}", roles.join(", "))
        })?;
        let format = FormatArg::from_str(format.trim(), true)
            .ok()
            .and_then(FormatArg::format)
            .ok_or_else(|| format!("--as {text}: the format must be bc1, bc4, bc5 or bc7"))?;
        match choice.by_semantic.iter().find(|(s, _)| *s == role.semantic()) {
            Some(&(_, earlier)) if earlier != format => {
                return Err(format!(
                    "--as {text}: {} maps were already given {} by an earlier --as; give one \
                     format per role",
                    role.name(),
                    earlier.name()
                )
                .into());
            }
            Some(_) => {}
            None => choice.by_semantic.push((role.semantic(), format)),
        }
    }
    let container = match args.container {
        ContainerArg::Ktx2 => Container::Ktx2,
        ContainerArg::Dds => Container::Dds,
    };
    let bytes = read_nmat(&args.input)?;
    let m = parse(&bytes, &args.input)?;
    let plan = transcode::plan(&m, &choice);
    let names: Vec<String> = plan.iter().map(|n| transcode::file_name(n, container)).collect();
    if !args.force {
        refuse_existing(&args.output, &names)?;
    }
    let textures: Vec<_> = plan.iter().map(|n| n.texture).collect();
    let (need, allowed) = (transcode::memory(&m, &textures), args.memory.bytes());
    if need > allowed {
        return Err(format!(
            "{}: transcoding needs about {:.1} MiB, more than the {:.1} MiB allowed; nothing \
             was written. Raise the limit with --max-memory",
            args.input.display(),
            mib(need),
            mib(allowed)
        )
        .into());
    }
    let start = Instant::now();
    let decoder = nmat_core::Decoder::new(&m);
    let gpu = if args.gpu { Some(gpu_transcoder(&m)?) } else { None };
    // One decode of the chain per texture on the GPU, one for all the others on the CPU.
    let chain = output::cost_of_mips(&m, 0..m.mip_count());
    let on_gpu = plan.iter().filter(|n| gpu.is_some() && gpu_encodes(n.texture.format)).count();
    let passes = (on_gpu + usize::from(on_gpu < plan.len())) as u64;
    let cost = nmat_core::DecodeCost { texels: chain.texels * passes, macs: chain.macs * passes };
    let written = with_decode_progress("transcode", cost, |progress| {
        output::write_all_or_nothing(&args.output, |dir| {
            // The GPU's textures first (with --gpu), then all the others in one CPU pass.
            let mut images = Vec::new();
            for named in &plan {
                images.push(match &gpu {
                    Some(levels_of) => levels_of(&named.texture, &mut *progress)?
                        .map(|levels| transcode::image(&m, &named.texture, levels)),
                    None => None,
                });
            }
            let on_cpu: Vec<_> = plan
                .iter()
                .zip(&images)
                .filter(|(_, i)| i.is_none())
                .map(|(n, _)| n.texture)
                .collect();
            let mut cpu_images = transcode::transcode(&m, &decoder, &on_cpu, progress)
                .map_err(|e| format!("{}: {e}", args.input.display()))?
                .into_iter();
            let mut files = Vec::new();
            for (image, name) in images.into_iter().zip(&names) {
                let image =
                    image.or_else(|| cpu_images.next()).ok_or("a texture was not transcoded")?;
                let path = dir.join(name);
                output::write_atomic(&path, &container.bytes(&image))?;
                files.push(path);
            }
            Ok(files)
        })
    })?;
    for ((named, path), name) in plan.iter().zip(&written).zip(&names) {
        let t = &named.texture;
        let channels: Vec<std::borrow::Cow<str>> = t
            .channel_list()
            .iter()
            .map(|&c| {
                m.channels()
                    .get(usize::from(c))
                    .map_or("?".into(), |ch| names::for_terminal(ch.name))
            })
            .collect();
        let size = std::fs::metadata(path).map_or(0, |md| md.len());
        println!(
            "wrote {name}  {}{}  {}  {size} bytes",
            t.format.name(),
            if t.srgb { " sRGB" } else { "" },
            channels.join(" ")
        );
    }
    println!(
        "transcoded {}×{} ({} mips) to {} textures in {:.2} s",
        m.width(),
        m.height(),
        m.mip_count(),
        written.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Runs `work` with a progress callback over the texels a decode evaluates; progress is shown
/// (with the cost printed first) when the decode is long: more than [`LONG_DECODE_TEXELS`].
fn with_decode_progress<T>(
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
fn chain_quality_shown(m: &Material<'_>, set: &TextureSet) -> ChainQuality {
    let cost = output::cost_of_mips(m, 0..m.mip_count());
    with_decode_progress("eval", cost, |progress| {
        nmat_encode::metrics::chain_quality_with(m, set, progress)
    })
}

const MIB: f64 = (1u64 << 20) as f64;

/// `bytes` in MiB, for messages (`walk` and `bench` share it).
fn mib(bytes: u64) -> f64 {
    bytes as f64 / MIB
}

/// Decodes of at least this many texels show a progress bar (one 2048² mip chain is 5.6 M).
const LONG_DECODE_TEXELS: u64 = 4 << 20;

#[cfg(feature = "gpu")]
fn decode_on_gpu(
    m: &Material<'_>,
    plan: &output::DecodePlan,
    dir: &Path,
    progress: &mut dyn FnMut(u64),
) -> Result<Vec<PathBuf>> {
    let (device, queue, info) =
        pollster::block_on(nmat_wgpu::default_device()).ok_or(NO_ADAPTER)?;
    eprintln!("decoding on {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, m)?;
    let decode = |mip: u32| -> Result<Vec<u8>> {
        Ok(ctx.decode_mip(&device, &queue, &gm, mip, nmat_core::ChannelMask::ALL)?)
    };
    let with = output::DecodeWith { float: false, batch: Some(&decode) };
    output::write_maps(m, plan, dir, with, progress)
}

#[cfg(not(feature = "gpu"))]
fn decode_on_gpu(
    _: &Material<'_>,
    _: &output::DecodePlan,
    _: &Path,
    _: &mut dyn FnMut(u64),
) -> Result<Vec<PathBuf>> {
    Err(NO_GPU_BUILD.into())
}

/// Every mip of a texture transcoded on the GPU (`None` for a format the GPU does not encode),
/// reporting texels done.
type GpuLevels =
    Box<dyn Fn(&nmat_core::bc::BcTexture, &mut dyn FnMut(u64)) -> Result<Option<Vec<Vec<u8>>>>>;

/// Whether `nmat-wgpu` encodes `format` (the others are encoded on the CPU).
#[cfg(feature = "gpu")]
fn gpu_encodes(format: nmat_core::bc::BcFormat) -> bool {
    nmat_wgpu::encodes(format)
}

#[cfg(not(feature = "gpu"))]
fn gpu_encodes(_: nmat_core::bc::BcFormat) -> bool {
    false
}

/// What `--gpu` says where wgpu finds no adapter.
#[cfg(feature = "gpu")]
const NO_ADAPTER: &str =
    "--gpu: no GPU adapter found (on Linux without a GPU: apt-get install mesa-vulkan-drivers)";

/// What `--gpu` says in a build without the `gpu` feature.
#[cfg(not(feature = "gpu"))]
const NO_GPU_BUILD: &str =
    "--gpu: this nmat was built without GPU support; build it with `--features gpu`";

#[cfg(feature = "gpu")]
fn gpu_transcoder(m: &Material<'_>) -> Result<GpuLevels> {
    let (device, queue, info) =
        pollster::block_on(nmat_wgpu::default_device()).ok_or(NO_ADAPTER)?;
    eprintln!("transcoding on {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, m)?;
    Ok(Box::new(move |texture, progress| {
        if !gpu_encodes(texture.format) {
            return Ok(None);
        }
        let mut levels = Vec::new();
        for (mip, &(w, h)) in gm.mip_sizes().iter().enumerate() {
            levels.push(ctx.transcode_mip(&device, &queue, &gm, texture, mip as u32)?);
            progress(u64::from(w) * u64::from(h));
        }
        Ok(Some(levels))
    }))
}

#[cfg(not(feature = "gpu"))]
fn gpu_transcoder(_: &Material<'_>) -> Result<GpuLevels> {
    Err(NO_GPU_BUILD.into())
}

/// Median seconds of 5 runs of `f`.
#[cfg(feature = "gpu")]
fn median_seconds(mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut runs = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        f()?;
        runs.push(t.elapsed().as_secs_f64());
    }
    runs.sort_by(f64::total_cmp);
    Ok(runs[2])
}

/// The GPU row of `nmat bench`'s CPU table: `row(adapter, seconds, texels, what was decoded)`.
/// A real GPU decodes the whole mip 0; a software adapter (lavapipe, on a machine without a GPU)
/// only the bench's region `side` of it — the whole mip of a 1024² material takes it minutes.
#[cfg(feature = "gpu")]
fn bench_gpu(m: &Material<'_>, side: (u32, u32), row: &GpuRow<'_>) -> Result<()> {
    let Some((device, queue, info)) = pollster::block_on(nmat_wgpu::default_device()) else {
        println!("  GPU: no adapter found");
        return Ok(());
    };
    let ctx = nmat_wgpu::Context::new(&device);
    let gm = ctx.upload(&device, m)?;
    let all = nmat_core::ChannelMask::ALL;
    if info.device_type == wgpu_device_type_cpu() {
        let what = format!("GPU {} (a software rasterizer on the CPU)", info.name);
        let secs = median_seconds(|| {
            ctx.submit_region(&device, &queue, &gm, 0, (0, 0, side.0, side.1), all)?
                .wait(&device)?;
            Ok(())
        })?;
        let scope = format!("region {}×{} only: software adapter", side.0, side.1);
        row(&what, secs, u64::from(side.0) * u64::from(side.1), &scope);
    } else {
        let what = format!("GPU {}", info.name);
        let secs = median_seconds(|| {
            ctx.decode_mip(&device, &queue, &gm, 0, all)?;
            Ok(())
        })?;
        let (w, h) = m.mip_size(0);
        row(&what, secs, u64::from(w) * u64::from(h), "whole mip 0");
    }
    Ok(())
}

/// What [`bench_gpu`] reports a measurement to: adapter, seconds, texels, what was decoded.
type GpuRow<'a> = dyn Fn(&str, f64, u64, &str) + 'a;

#[cfg(feature = "gpu")]
fn wgpu_device_type_cpu() -> nmat_wgpu::DeviceType {
    nmat_wgpu::DeviceType::Cpu
}

/// `nmat bench --gpu`'s table for `m`.
#[cfg(feature = "gpu")]
fn bench_gpu_table(m: &Material<'_>, opts: &bench::Options) -> Result<()> {
    bench_gpu::table(m, opts)
}

#[cfg(not(feature = "gpu"))]
fn bench_gpu_table(_: &Material<'_>, _: &bench::Options) -> Result<()> {
    Err(NO_GPU_BUILD.into())
}

#[cfg(not(feature = "gpu"))]
fn bench_gpu(_: &Material<'_>, _: (u32, u32), _: &GpuRow<'_>) -> Result<()> {
    println!("  GPU: not measured (build with --features gpu)");
    Ok(())
}

/// Loads the reference maps of `m` from `dir`: the files its SOURCE_MAPS section names if all are
/// there, else the images of `dir` whose role (told from the file name) is one of the material's.
/// The maps' channels must then match the material's by role and component, in order — else the
/// PSNR would compare, say, a roughness channel with a metallic map: refused, or with `force`
/// compared all the same after a warning.
fn load_reference(
    m: &Material<'_>,
    dir: &Path,
    force: bool,
    max_memory: u64,
) -> Result<TextureSet> {
    let roles: Vec<(Role, PathBuf)> = match output::source_maps(m) {
        Some(maps) if maps.iter().all(|s| dir.join(&s.file_name).is_file()) => {
            maps.iter().map(|s| (s.role, dir.join(&s.file_name))).collect()
        }
        _ => {
            let found = texset::assign_roles(&texset::collect_inputs(&[dir.to_path_buf()])?, &[])?;
            let mut ours: Vec<Role> =
                m.channels().iter().filter_map(|c| Role::from_semantic(c.semantic)).collect();
            ours.dedup();
            let missing: Vec<&str> = ours
                .iter()
                .filter(|r| !found.iter().any(|(f, _)| f == *r))
                .map(|r| r.name())
                .collect();
            if !missing.is_empty() && !force {
                let there: Vec<String> =
                    found.iter().map(|(r, p)| format!("{} {}", r.name(), p.display())).collect();
                return Err(format!(
                    "{}: no {} map among the reference maps ({}), so the material's channels \
                     would be compared with other maps. Point --ref at the maps this material \
                     was encoded from, or pass --force to compare anyway",
                    dir.display(),
                    missing.join(", no "),
                    there.join(", ")
                )
                .into());
            }
            if force {
                found
            } else {
                found.into_iter().filter(|(r, _)| ours.contains(r)).collect()
            }
        }
    };
    let set = texset::load(&roles, &LoadOptions { max_memory, ..LoadOptions::default() })?;
    if set.channel_count() != m.channel_count()
        || (set.width, set.height) != (m.width(), m.height())
    {
        return Err(format!(
            "{}: the reference maps give {}×{} with {} channels, the material is {}×{} with {}",
            dir.display(),
            set.width,
            set.height,
            set.channel_count(),
            m.width(),
            m.height(),
            m.channel_count()
        )
        .into());
    }
    let mismatches: Vec<String> = m
        .channels()
        .iter()
        .zip(&set.channels)
        .enumerate()
        .filter(|(_, (ours, theirs))| {
            (ours.semantic, ours.component) != (theirs.role.semantic(), theirs.component)
        })
        .map(|(i, (ours, theirs))| {
            let map = set
                .maps
                .iter()
                .find(|s| (s.first_channel..s.first_channel + s.channel_count).contains(&i));
            format!(
                "channel {i} is {} in the material but {} ({}) in the reference maps",
                nmat_encode::names::for_terminal(ours.name),
                theirs.name,
                map.map_or("?", |s| s.file_name.as_str())
            )
        })
        .collect();
    if let Some(first) = mismatches.first() {
        let what = format!(
            "{}: the reference maps do not match the material's channels: {first}{}",
            dir.display(),
            if mismatches.len() > 1 {
                format!(" (and {} more)", mismatches.len() - 1)
            } else {
                String::new()
            }
        );
        if !force {
            return Err(format!(
                "{what}; the numbers would compare different maps. Point --ref at the maps this \
                 material was encoded from, or pass --force to compare anyway"
            )
            .into());
        }
        eprintln!("warning: {what}; compared anyway (--force): the numbers below mix maps");
    }
    Ok(set)
}

fn cmd_bench_train(args: BenchTrainArgs) -> Result<()> {
    let BenchTrainArgs { inputs, profile, steps, threads, kernel, runs, phases, memory } = args;
    if steps == 0 || runs == 0 {
        return Err("--steps and --runs must be at least 1".into());
    }
    let defaults = TrainOptions::default();
    let (joint_percent, qat_percent) = match phases.as_deref() {
        None => (defaults.joint_percent, defaults.qat_percent),
        Some(&[joint, qat]) if joint + qat <= 100 => (joint, qat),
        Some(p) => {
            return Err(format!(
                "--phases {p:?}: give JOINT,QAT, two percents summing to at most 100"
            )
            .into());
        }
    };
    for &t in &threads {
        check_threads(t)?;
    }
    let kernels = if kernel.iter().any(|k| k == "all") {
        TrainKernel::ALL.into_iter().filter(|k| k.is_available()).collect()
    } else {
        kernel
            .iter()
            .map(|name| {
                let k = TrainKernel::by_name(name).ok_or_else(|| {
                    let names: Vec<&str> = TrainKernel::ALL.iter().map(|k| k.name()).collect();
                    format!("--kernel {name}: unknown; choose all or any of {}", names.join(", "))
                })?;
                if !k.is_available() {
                    return Err(format!("--kernel {name}: this CPU cannot run it"));
                }
                Ok(k)
            })
            .collect::<std::result::Result<Vec<_>, _>>()?
    };
    let (set, label) = if inputs.is_empty() {
        (nmat_encode::demo::bricks(1024), "the bundled procedural material".to_string())
    } else {
        let files = texset::collect_inputs(&inputs)?;
        let roles = texset::assign_roles(&files, &[])?;
        let label = inputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ");
        let options = LoadOptions { max_memory: memory.bytes(), ..LoadOptions::default() };
        (texset::load(&roles, &options)?, label)
    };
    bench_train::run(&bench_train::Options {
        set,
        label,
        profile: profile_named(&profile)?,
        steps,
        threads,
        kernels,
        runs,
        joint_percent,
        qat_percent,
    })
}

fn cmd_eval(input: &Path, reference: &Path, force: bool, max_memory: u64) -> Result<()> {
    let start = Instant::now();
    let bytes = read_nmat(input)?;
    let m = parse(&bytes, input)?;
    let set = load_reference(&m, reference, force, max_memory)?;
    let q = chain_quality_shown(&m, &set);
    warn_if_decoded(&q, reference);
    print!("{}", output::quality_table(&set, &q, None));
    println!("evaluated in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

/// Warns when the reference maps equal the material's own decode at mip 0: `--ref` then points
/// at decoded maps, not at the sources, and the PSNR says nothing about the codec.
fn warn_if_decoded(q: &ChainQuality, reference: &Path) {
    if q.mse.first().is_some_and(|mip0| mip0.iter().all(|&e| e == 0.0)) {
        eprintln!(
            "warning: the maps in {} are identical to this material's own decode at mip 0 — \
             they look like decoded maps, not the source maps it was encoded from, so the \
             numbers below do not measure the codec",
            reference.display()
        );
    }
}

fn cmd_demo(out: &Path, train: &TrainArgs, profile: &str) -> Result<()> {
    threads(train.threads)?;
    let profile = profile_named(profile)?;
    let set = nmat_encode::demo::bricks(256);
    let source = out.join("source");
    output::write_source_maps(&set, &source)?;
    println!(
        "demo: a procedural 256×256 brick material (albedo RGB, normal XYZ, roughness, height; {} mips), profile {}",
        set.mips.len(),
        profile.name()
    );
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let start = Instant::now();
    let options = EncodeOptions {
        profile,
        train: train_options(train, DEMO_STEPS)?,
        address_mode: AddressMode::Wrap,
    };
    let encoded = encode_with_progress(&set, &options)?;
    let path = out.join("demo.nmat");
    output::write_atomic(&path, &encoded.bytes)?;
    println!(
        "encoded in {:.1} s → {} ({} bytes)",
        start.elapsed().as_secs_f64(),
        path.display(),
        encoded.bytes.len()
    );
    let m = parse(&encoded.bytes, &path)?;
    let plan = output::DecodePlan::new(&m, &[0], false)?;
    let decoded = out.join("decoded");
    std::fs::create_dir_all(&decoded).map_err(|e| format!("{}: {e}", decoded.display()))?;
    let with = output::DecodeWith::default();
    let written = output::write_maps(&m, &plan, &decoded, with, &mut |_| {})?;
    println!(
        "source maps in {}, {} decoded maps in {}",
        source.display(),
        written.len(),
        decoded.display()
    );
    print!(
        "{}",
        output::quality_table(&set, &encoded.quality, Some(&format!("profile {}", profile.name())))
    );
    // This binary as the user can type it from here (`target/release/nmat` after `cargo run`).
    let nmat = match (std::env::current_exe(), std::env::current_dir()) {
        (Ok(exe), Ok(here)) => exe.strip_prefix(&here).unwrap_or(&exe).display().to_string(),
        _ => "nmat".to_string(),
    };
    println!(
        "\nnext: measure it against the source maps, and the decode speed and accuracy knobs:\n  \
         {nmat} eval {p} --ref {s}\n  {nmat} bench {p} --ref {s}",
        p = path.display(),
        s = source.display()
    );
    Ok(())
}
