//! The command line: every command's arguments as clap reads them, and the parsers of sizes.
//! Only declarations here; what a command does is in `commands/`.

use clap::{Args, Parser, Subcommand, ValueEnum};
use nmat_encode::texset;
use nmat_encode::{Effort, LayoutChoice, TrainOptions};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "nmat",
    version,
    about = "Neural material textures: encode, decode, inspect, evaluate"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
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
    Index(IndexArgs),
    /// Build every material of a TOML manifest (folders or patterns of folders, each with its
    /// options and output): several at a time, each by its own `nmat encode`; outputs whose
    /// inputs, options and encoder are unchanged are kept; one failure does not stop the others;
    /// a CSV or JSON summary at the end (docs/ENCODING.md, "Building a library").
    Build(BuildArgs),
    /// Print what a .nmat file holds.
    Info(InfoArgs),
    /// Pack a .nmat file (format 2.2, docs/FORMAT.md §12): a neural material's latents
    /// entropy-coded, a JPEG material's streams without their MCU index: the same material in a
    /// smaller file, unpacked once when it is opened. Lossless; `nmat unpack` gives back the
    /// very same bytes.
    Pack(PackArgs),
    /// Write a packed .nmat file fixed-rate again (latents as codes, JPEG streams with their
    /// index): a larger file that opens without unpacking (zero-copy, memory-mapped) and that
    /// readers without format 2.2's packed sections read (2.3 for neural files encoded since
    /// its scaled LOD feature, 2.1 for JPEG ones).
    Unpack(PackArgs),
    /// Compare .nmat files with their source maps: PSNR per map and mip, SSIM, BPPC; with
    /// `--report`, one HTML page to look at them (with a rate–quality plot for several files).
    Eval(EvalArgs),
    /// The speed–accuracy table of docs/PERFORMANCE.md for one or more .nmat files: every decode
    /// mode (kernels, float, channel subsets, filters, random access, threads) over one region of
    /// mip 0, with the CPU's roofline, BC1/BC4 and PNG decoding measured in the same run, and the
    /// GPU when built with `--features gpu`.
    Bench(BenchArgs),
    /// The trainer's throughput (docs/PERFORMANCE.md): steps/s, samples/s, GFLOP/s and share of
    /// the CPU's f32 FMA peak for every matrix-product kernel and thread count, on one material.
    BenchTrain(BenchTrainArgs),
    /// A headless walk down a textured corridor at 1920×1080 with the tile cache: per frame the
    /// tiles marked, decoded and kept, the texels decoded, and the milliseconds of marking,
    /// decoding and resolving, against decoding every lookup directly (docs/PERFORMANCE.md,
    /// "Tile cache"). The materials cover floor, walls, ceiling and end wall in turn.
    Walk(WalkArgs),
    /// Encode, decode and evaluate a bundled procedural material, and print a report.
    Demo(DemoArgs),
}

#[derive(Args)]
pub struct IndexArgs {
    /// The JPEG file (gray or YCbCr; 4:4:4, 4:2:2, 4:4:0 or 4:2:0).
    pub input: PathBuf,
    /// The .nmat file to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Keep the MCU index in the file (fixed-rate, format 2.1: opens without a scan, zero-copy);
    /// by default it is rebuilt when the file is opened (format 2.2, a smaller file).
    #[arg(long)]
    pub fixed_rate: bool,
    #[command(flatten)]
    pub memory: MemoryArg,
}

#[derive(Args)]
pub struct BuildArgs {
    /// The manifest (TOML); paths in it are relative to its folder.
    pub manifest: PathBuf,
    /// Materials encoded at a time [default: this machine's cores]; the cores are shared
    /// between them (`--threads` of each encode).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Rebuild every output, up to date or not.
    #[arg(long)]
    pub force: bool,
    /// Build only shard K of N (e.g. 2/8): the same split on every machine, by output path.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Where to write the summary (.csv, or .json) [default: MANIFEST with extension
    /// summary.csv].
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Also write `OUTPUT.html` for every material, `nmat eval --report` of it against its
    /// folder (remade when the output is newer), and a page for the whole build beside the
    /// summary (SUMMARY with extension html): every material linked, and a rate–quality plot
    /// for each folder built more than once (profiles, codecs) or with `--anchors` points.
    #[arg(long)]
    pub report: bool,
    /// Other codecs' rate–quality points for the build's page, as `nmat eval --anchors` takes
    /// them: the rows of each folder's name are drawn beside its outputs.
    #[arg(long, requires = "report")]
    pub anchors: Option<PathBuf>,
    /// Build nothing: write a build file with one edge per material (of the shard) calling
    /// `nmat encode`, for Ninja, Make or a distributed executor to schedule (-o names it).
    #[arg(long, requires = "output")]
    pub emit: Option<EmitArg>,
    /// The build file --emit writes.
    #[arg(short, long, requires = "emit")]
    pub output: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum EmitArg {
    Ninja,
    Make,
}

#[derive(Args)]
pub struct PackArgs {
    pub input: PathBuf,
    /// The .nmat file to write (never the input).
    #[arg(short, long)]
    pub output: PathBuf,
}

#[derive(Args)]
pub struct InfoArgs {
    pub input: PathBuf,
}

#[derive(Args)]
pub struct EvalArgs {
    /// One or more .nmat files of the same source (profiles, rates or codecs to compare).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Folder with the reference maps.
    #[arg(long = "ref")]
    pub reference: PathBuf,
    /// Compare even when the reference maps do not match the material's channels by role
    /// (by default that is refused: the numbers would compare different maps).
    #[arg(long)]
    pub force: bool,
    /// Also write a self-contained HTML report: per map and mip the source, the decode and an
    /// error heat map, PSNR and SSIM per map, the rate and the decode cost; with several files
    /// or `--anchors`, a rate–quality plot (SVG) of them all first.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Other codecs' rate–quality points for the report's plot: a CSV of
    /// `material,codec,setting,bppc,psnr_db[,…]` rows (what `nmat-anchors MATERIAL --sweep`
    /// and `bench/quality.sh` write); the rows of the `--ref` folder's name are drawn, one
    /// curve per codec (`jpegxl@ntc-0.2` counts as `jpegxl`).
    #[arg(long, requires = "report")]
    pub anchors: Option<PathBuf>,
    #[command(flatten)]
    pub memory: MemoryArg,
}

#[derive(Args)]
pub struct BenchArgs {
    /// One or more .nmat files; with several, a last section gives each file's decode speed
    /// against the first's, timed in alternation (give a file twice to see the noise).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Folder with the source maps: adds PSNR and PNG decode time.
    #[arg(long = "ref")]
    pub reference: Option<PathBuf>,
    /// Side of the square region of mip 0 each mode decodes.
    #[arg(long, default_value_t = 256)]
    pub region: u32,
    /// Timed runs per row (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Measure the GPU decoder instead (docs/GPU.md): kernels timed with GPU timestamps
    /// against the adapter's measured integer peak, for a region, the whole chain, random
    /// requests and channel subsets. Needs the `gpu` feature.
    #[arg(long)]
    pub gpu: bool,
    /// With --gpu: measure this kernel only (it decodes every row, with its parts), instead of
    /// the one `upload` picks plus a region row for every other kernel; an error where the
    /// device cannot run it or its codes differ from the CPU's.
    #[arg(long, value_enum, requires = "gpu")]
    pub kernel: Option<GpuKernelArg>,
    /// The CPU rows only: a `--features gpu` build leaves out its GPU row (on a machine whose
    /// only adapter is a software one, that row takes minutes and measures the CPU again).
    #[arg(long, conflicts_with = "gpu")]
    pub cpu_only: bool,
    /// With --ref: measure even when the reference maps do not match the material's
    /// channels by role.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub memory: MemoryArg,
}

#[derive(Args)]
pub struct WalkArgs {
    /// One to four .nmat files with at least 3 channels (channels 0–2 are shown).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Frame size in pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "1920x1080", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Frames of the camera path (the same path, sampled more or less densely).
    #[arg(long, default_value_t = 60)]
    pub frames: u32,
    /// Thread counts to measure, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
    pub threads: Vec<usize>,
    /// Tiles the cache holds (16×16 texels each).
    #[arg(long, default_value_t = 16384)]
    pub tiles: usize,
    /// Every how many frames to also decode every lookup directly, without the cache, and
    /// compare (0: never).
    #[arg(long, default_value_t = 10)]
    pub direct_every: u32,
    /// Only the walk with mips (trilinear) or without (bilinear at mip 0); default both.
    #[arg(long)]
    pub mips: Option<bool>,
    /// Write one row per frame and setting to this CSV file.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write the last frame of the walk with mips (channels 0–2) to this PNG file.
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Also walk with the GPU's tile cache (wgpu), against `nmat_sample` without it (neural
    /// materials). Needs the `gpu` feature: cargo build --release -p nmat --features gpu
    #[arg(long)]
    pub gpu: bool,
    #[command(flatten)]
    pub memory: MemoryArg,
}

#[derive(Args)]
pub struct DemoArgs {
    /// Where to write demo.nmat and the decoded maps.
    #[arg(short, long, default_value = "target/nmat-demo")]
    pub out: PathBuf,
    #[command(flatten)]
    pub train: TrainArgs,
    #[arg(long, default_value = nmat_encode::DEFAULT_PROFILE)]
    pub profile: String,
}

#[derive(Args)]
pub struct BenchTrainArgs {
    /// Folders and/or map files (default: the bundled procedural material at 1024²).
    pub inputs: Vec<PathBuf>,
    #[arg(long, default_value = nmat_encode::DEFAULT_PROFILE)]
    pub profile: String,
    /// Optimizer steps per timed run.
    #[arg(long, default_value_t = 100)]
    pub steps: usize,
    /// Thread counts to measure, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
    pub threads: Vec<usize>,
    /// Kernels to measure, comma-separated (scalar, avx2, avx512), or `all` this CPU runs.
    #[arg(long, value_delimiter = ',', default_values_t = ["all".to_string()])]
    pub kernel: Vec<String>,
    /// Timed runs per row (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Percent of the steps in the joint and the quantization-aware phase, as `JOINT,QAT`
    /// (default: the encoder's; `80,5` is the phase mix of the trainer before the SIMD work).
    #[arg(long, value_delimiter = ',', value_name = "JOINT,QAT")]
    pub phases: Option<Vec<u32>>,
    #[command(flatten)]
    pub memory: MemoryArg,
}

/// `--max-memory` of the commands whose memory grows with a number given to them or read from a
/// file's header.
#[derive(Args)]
pub struct MemoryArg {
    /// Memory this command may use, e.g. 8G or 512M (MiB without a unit); work that would need
    /// more is refused before it starts [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    pub max_memory: Option<u64>,
}

impl MemoryArg {
    pub fn bytes(&self) -> u64 {
        self.max_memory.unwrap_or(texset::DEFAULT_MAX_MEMORY)
    }
}

#[derive(Args)]
pub struct TrainArgs {
    /// Optimizer steps (more: better quality, longer encode) [default: 30000 for encode, 3000
    /// for demo]. More than the default: the network trains on its int8 weights throughout.
    #[arg(long, conflicts_with = "effort")]
    pub steps: Option<usize>,
    /// Encode time for quality: fast = ¼ of the default steps (0.4–0.9 dB lower); max = twice
    /// the steps with the network on its int8 weights throughout, about twice the time
    /// (docs/ENCODING.md, "Speed").
    #[arg(long, value_enum, default_value_t = EffortArg::Default)]
    pub effort: EffortArg,
    /// Seed of every random choice: same inputs, seed and steps give the same file.
    #[arg(long, default_value_t = TrainOptions::default().seed)]
    pub seed: u64,
    /// Worker threads (default: all cores). The file does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// A GPU kernel of nmat-wgpu (docs/GPU.md, "The kernels").
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum GpuKernelArg {
    Reference,
    UnrolledI32,
    UnrolledDot4,
    I32,
    Dot4,
    Matrix,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EffortArg {
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
pub enum LayoutArg {
    Trial,
    ResolutionFirst,
    BitsFirst,
}

impl From<LayoutArg> for LayoutChoice {
    fn from(l: LayoutArg) -> LayoutChoice {
        match l {
            LayoutArg::Trial => LayoutChoice::Trial,
            LayoutArg::ResolutionFirst => LayoutChoice::ResolutionFirst,
            LayoutArg::BitsFirst => LayoutChoice::BitsFirst,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OnOffArg {
    On,
    Off,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CodecArg {
    Neural,
    Jpeg,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SubsamplingArg {
    #[value(name = "4:2:0")]
    S420,
    #[value(name = "4:2:2")]
    S422,
    #[value(name = "4:4:4")]
    S444,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum Address {
    Wrap,
    Clamp,
}

#[derive(Args)]
pub struct EncodeArgs {
    /// Folders and/or map files; roles come from file names (or --map).
    pub inputs: Vec<PathBuf>,
    /// Output file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Assign a role explicitly: ROLE=PATH (albedo, normal, roughness, gloss, specular, height,
    /// ao, metallic, emissive, opacity). Repeatable.
    #[arg(long = "map", value_name = "ROLE=PATH")]
    pub maps: Vec<String>,
    /// neural: a network and latent grids (the profiles); jpeg: every map as indexed baseline
    /// JPEG (a colour map as YCbCr, others gray), decodable texel by texel like a neural one.
    #[arg(long, value_enum, default_value_t = CodecArg::Neural)]
    pub codec: CodecArg,
    /// Rate/layout profile (neural).
    #[arg(long, conflicts_with_all = ["bppc", "target_psnr", "quality"])]
    pub profile: Option<String>,
    /// Neural: pick the profile nearest to this many bits per pixel per channel; jpeg: the
    /// highest quality whose file is at most this rate.
    #[arg(long, conflicts_with_all = ["target_psnr", "quality"])]
    pub bppc: Option<f64>,
    /// JPEG quality, 1–100 on the IJG scale (cjpeg's) [default: 85] (jpeg).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub quality: Option<u8>,
    /// Chroma resolution of colour maps (albedo, emissive, specular colour); normals are always
    /// 4:4:4 [default: 4:2:0] (jpeg).
    #[arg(long, value_enum)]
    pub subsampling: Option<SubsamplingArg>,
    /// Search for the smallest profile whose whole-chain PSNR reaches this many dB.
    #[arg(long)]
    pub target_psnr: Option<f64>,
    /// Resize maps of another size to the first map's size (Lanczos3) instead of failing.
    #[arg(long)]
    pub resize: bool,
    /// Memory loading the maps may use, e.g. 8G or 512M (MiB without a unit); a map that would
    /// need more is refused before it is decoded [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    pub max_memory: Option<u64>,
    /// Texture addressing at the edges.
    #[arg(long, value_enum, default_value = "wrap")]
    pub address: Address,
    /// Write the file fixed-rate, as decoders hold it in memory (latents as codes, JPEG streams
    /// with their index): a larger file that opens without unpacking (zero-copy, e.g.
    /// memory-mapped), for readers without format 2.2's packed sections (neural files are
    /// format 2.3 for their LOD feature, JPEG ones 2.1). By default latents are entropy-coded
    /// and the index left to be rebuilt on opening (format 2.2), where that is smaller.
    #[arg(long)]
    pub fixed_rate: bool,
    /// Neural: train on the LOD feature of formats before 2.3 (mip/16), so that older decoders
    /// read the file — format 2.0 readers with --fixed-rate, 2.2 readers packed. Costs quality:
    /// the int8 network keeps less of the float one (at ntc-1.0 1.66 dB on average over 15
    /// materials, up to 3.7; docs/QUALITY.md, "The LOD feature's scale")
    #[arg(long)]
    pub legacy_lod: bool,
    /// Neural, packed: the in-memory (fixed-rate) layout may be this many times the profile's
    /// nominal size, 1–2: larger latent grids, kept to the nominal rate on disk by training
    /// (docs/ENCODING.md, "Rate control"); 1: the nominal layout, whose packed file lands below
    /// the nominal rate [default: 1.5]. A polished file that lands more than 0.3 % under the
    /// nominal rate is trained again at 2 and polished down to it, kept where it decodes better
    /// (docs/ENCODING.md, "The regrown layout").
    #[arg(long, conflicts_with = "fixed_rate")]
    pub memory_factor: Option<f64>,
    /// Neural, packed ntc-0.2: how the in-memory layout grows past the nominal one — one more
    /// bit per latent first, the grids' resolution first, or `trial`: train both for a quarter of
    /// the steps each and keep the better (about 1.5× the encode time) (docs/ENCODING.md, "The
    /// layout trial") [default: bits-first]
    #[arg(long, value_enum, conflicts_with = "fixed_rate")]
    pub layout: Option<LayoutArg>,
    /// Neural, NTC profiles: read each level's high-resolution grid bilinearly as well as at its
    /// 4 nearest cells — the same latents and rate, more quality for more decode time (ntc-0.5:
    /// +0.51 dB mean PSNR over the development materials, 12–15 % more decode instructions)
    /// (docs/ENCODING.md, "The high-resolution grid read twice") [default: on at ntc-0.2, off at
    /// the others]
    #[arg(long, value_enum)]
    pub hi_bilinear: Option<OnOffArg>,
    /// Neural: how far past its range an output may go without cost where its target sits at
    /// that end, 0–0.25 of the range [default: the profile's, 0.02 at ntc-0.2 and nbc-0.1, else
    /// 0]. Every decoder clamps the outputs, so a 0/1 mask, pure white or zero padding then
    /// decodes exactly (docs/ENCODING.md, "Outputs past the ends of their range").
    #[arg(long)]
    pub output_margin: Option<f32>,
    /// Neural: sweeps of the latent polish after training, 0–8 [default: the profile's, 2 at
    /// ntc-0.2, else 0]. Each moves every latent code by ±1 where the decoder then decodes the
    /// chain better, a packed file's size kept (ntc-0.2: stk-eggkart +0.63 dB, brickfloor +1.17
    /// at the same rate; each sweep about as long as 70 decodes of the finest mips)
    /// (docs/ENCODING.md, "The latent polish").
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=8))]
    pub polish_sweeps: Option<u8>,
    /// Solve the layout and print the file's byte budget without training; writes nothing.
    #[arg(long, conflicts_with = "target_psnr")]
    pub dry_run: bool,
    #[command(flatten)]
    pub train: TrainArgs,
}

#[derive(Args)]
pub struct DecodeArgs {
    pub input: PathBuf,
    /// Output folder (created if missing).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Which mip to write: a number or "all".
    #[arg(long, default_value = "0")]
    pub mip: String,
    /// Decode with the float reference decoder instead of the integer-exact one.
    #[arg(long, conflicts_with = "int")]
    pub float: bool,
    /// Decode with the integer-exact decoder (the default).
    #[arg(long)]
    pub int: bool,
    /// Decode on the GPU (wgpu; bit-identical to --int). Needs the `gpu` feature:
    /// cargo build --release -p nmat --features gpu
    #[arg(long, conflicts_with = "float")]
    pub gpu: bool,
    /// With --gpu: keep the kernels nmat-wgpu measured fastest on this GPU in FILE (read where
    /// it exists, written after the upload where they changed; choices made on another
    /// adapter, driver or nmat version are replaced), so that later runs measure nothing. A
    /// remembered kernel is still checked against the CPU (docs/GPU.md).
    #[arg(long, value_name = "FILE", requires = "gpu")]
    pub kernel_choices: Option<PathBuf>,
    /// Replace files that already exist in the output folder (by default nmat refuses, so the
    /// source maps are never overwritten with their decodes).
    #[arg(long)]
    pub force: bool,
    /// Write every map as PNG, whatever its original format (e.g. a gray+alpha map that came from
    /// a TIFF, which cannot hold one).
    #[arg(long)]
    pub png: bool,
    /// Memory the decoded maps may use, e.g. 8G or 512M (MiB without a unit); a larger decode is
    /// refused before it starts [default: 8G].
    #[arg(long, value_parser = parse_memory)]
    pub max_memory: Option<u64>,
}

#[derive(Args)]
pub struct TranscodeArgs {
    pub input: PathBuf,
    /// Output folder (created if missing).
    #[arg(short, long)]
    pub output: PathBuf,
    /// `auto`: from each map's meaning (albedo → BC1 sRGB, normal → BC5 of X/Y, one channel →
    /// BC4, two → BC5, alpha → its own BC4); or one format for every map (bc7: RGB or RGBA,
    /// higher quality at twice BC1's size).
    #[arg(long, value_enum, default_value_t = FormatArg::Auto)]
    pub format: FormatArg,
    /// The format of the maps of one role, over --format: ROLE=FORMAT, e.g. albedo=bc7 (roles as
    /// in `nmat encode --map`). Repeatable.
    #[arg(long = "as", value_name = "ROLE=FORMAT")]
    pub as_role: Vec<String>,
    /// File container.
    #[arg(long, value_enum, default_value_t = ContainerArg::Ktx2)]
    pub container: ContainerArg,
    /// Worker threads (default: all cores). The files do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Decode and encode the textures on the GPU (wgpu; the same bytes as the CPU). Needs the
    /// `gpu` feature:
    /// cargo build --release -p nmat --features gpu
    #[arg(long)]
    pub gpu: bool,
    /// With --gpu: keep the kernels nmat-wgpu measured fastest on this GPU in FILE (read where
    /// it exists, written after the upload where they changed; choices made on another
    /// adapter, driver or nmat version are replaced), so that later runs measure nothing. A
    /// remembered kernel is still checked against the CPU (docs/GPU.md).
    #[arg(long, value_name = "FILE", requires = "gpu")]
    pub kernel_choices: Option<PathBuf>,
    /// Replace files that already exist in the output folder.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub memory: MemoryArg,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    Auto,
    Bc1,
    Bc4,
    Bc5,
    Bc7,
}

impl FormatArg {
    pub fn format(self) -> Option<nmat_core::bc::BcFormat> {
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
pub enum ContainerArg {
    Ktx2,
    Dds,
}

/// `--size`: `WIDTHxHEIGHT`, each 1 to 16384.
fn parse_size(text: &str) -> std::result::Result<(u32, u32), String> {
    let bad = || format!("expected WIDTHxHEIGHT (each 1 to 16384), got {text:?}");
    let (w, h) = text.split_once(['x', '×']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// `--max-memory`: a size with an optional binary unit (K, M, G; MiB without one), in bytes.
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
