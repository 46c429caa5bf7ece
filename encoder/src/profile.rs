//! Profiles: named rate points that fix the feature-pyramid layout (NTC or NBC), bit depths and
//! grid resolutions, with the number of latent channels solved from the bit budget of the material
//! at hand (docs/ENCODING.md explains the arithmetic).

use nmat_core::TermMode;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Profile {
    /// NTC layout: per level a high-res grid (4 nearest cells) and a low-res grid (bilinear).
    /// Level 0 serves the first `level0_mips` mips (2 in the NTC paper), every other level the
    /// next two ([`ntc_level_of`]).
    Ntc {
        name: &'static str,
        bppc: f64,
        hi_divisor: u32,
        hi_bits: u8,
        lo_bits: u8,
        level0_mips: u32,
        /// Whether each level also reads its high-resolution grid bilinearly (a third term,
        /// `Bilinear[hi]`, after NTC's `Nearest4[hi]` and `Bilinear[lo]`): the same four cells,
        /// interpolated, so the network has smooth features at that resolution as well as the
        /// four corners. On at `ntc-0.2` (+0.39 dB mean over the development materials, for
        /// 4–10 % more multiply-adds per texel); off at `ntc-0.5` (measured: +0.51 dB for 12–15 %
        /// more decode instructions) and the others (not measured); [`Profile::with_hi_bilinear`]
        /// chooses (docs/ENCODING.md, "The high-resolution grid read twice").
        hi_bilinear: bool,
        /// The trainer's default [`TrainOptions::output_margin`](crate::TrainOptions::output_margin).
        output_margin: f32,
        /// The default [`EncodeOptions::polish_sweeps`](crate::EncodeOptions::polish_sweeps).
        polish_sweeps: u8,
    },
    /// NBC layout: 4 residual levels with 8-4-2-1 bits coarse → fine, fused.
    Nbc { name: &'static str, bppc: f64, output_margin: f32, polish_sweeps: u8 },
}

pub const PROFILES: [Profile; 8] = [
    Profile::Nbc { name: "nbc-0.05", bppc: 0.05, output_margin: 0.0, polish_sweeps: 0 },
    Profile::Nbc { name: "nbc-0.1", bppc: 0.1, output_margin: 0.02, polish_sweeps: 0 },
    Profile::Nbc { name: "nbc-0.2", bppc: 0.2, output_margin: 0.0, polish_sweeps: 0 },
    Profile::Ntc {
        name: "ntc-0.2",
        bppc: 0.2,
        hi_divisor: 4,
        hi_bits: 2,
        lo_bits: 4,
        level0_mips: 3,
        hi_bilinear: true,
        output_margin: 0.02,
        polish_sweeps: 2,
    },
    Profile::Nbc { name: "nbc-0.5", bppc: 0.5, output_margin: 0.0, polish_sweeps: 0 },
    Profile::Ntc {
        name: "ntc-0.5",
        bppc: 0.5,
        hi_divisor: 4,
        hi_bits: 4,
        lo_bits: 4,
        level0_mips: 3,
        hi_bilinear: false,
        output_margin: 0.0,
        polish_sweeps: 0,
    },
    Profile::Ntc {
        name: "ntc-1.0",
        bppc: 1.0,
        hi_divisor: 2,
        hi_bits: 4,
        lo_bits: 4,
        level0_mips: 2,
        hi_bilinear: false,
        output_margin: 0.0,
        polish_sweeps: 0,
    },
    Profile::Ntc {
        name: "ntc-2.25",
        bppc: 2.25,
        hi_divisor: 2,
        hi_bits: 8,
        lo_bits: 8,
        level0_mips: 2,
        hi_bilinear: false,
        output_margin: 0.0,
        polish_sweeps: 0,
    },
];

/// The default profile.
pub const DEFAULT_PROFILE: &str = "ntc-0.5";

impl Profile {
    pub fn name(&self) -> &'static str {
        match *self {
            Profile::Ntc { name, .. } | Profile::Nbc { name, .. } => name,
        }
    }
    pub fn bppc(&self) -> f64 {
        match *self {
            Profile::Ntc { bppc, .. } | Profile::Nbc { bppc, .. } => bppc,
        }
    }
    /// How far past their unit range the trainer lets outputs go by default
    /// ([`TrainOptions::output_margin`](crate::TrainOptions::output_margin)): 0.02 at `ntc-0.2`
    /// and `nbc-0.1`, where it gained on the development materials; 0 (plain squared error)
    /// elsewhere — it lost at `ntc-0.5`, the others are not measured (docs/ENCODING.md, "Outputs
    /// past the ends of their range").
    pub fn output_margin(&self) -> f32 {
        match *self {
            Profile::Ntc { output_margin, .. } | Profile::Nbc { output_margin, .. } => {
                output_margin
            }
        }
    }
    /// How many sweeps of the latent polish an encode runs by default (docs/ENCODING.md, "The
    /// latent polish"): 2 at `ntc-0.2`, where it is measured, 0 at the others.
    pub fn polish_sweeps(&self) -> u8 {
        match *self {
            Profile::Ntc { polish_sweeps, .. } | Profile::Nbc { polish_sweeps, .. } => {
                polish_sweeps
            }
        }
    }
    /// Whether the profile reads each level's high-resolution grid bilinearly as well as at its
    /// 4 nearest cells (`Nearest4[hi] + Bilinear[lo] + Bilinear[hi]`; NBC profiles: `None`).
    pub fn hi_bilinear(&self) -> Option<bool> {
        match *self {
            Profile::Ntc { hi_bilinear, .. } => Some(hi_bilinear),
            Profile::Nbc { .. } => None,
        }
    }
    /// This NTC profile with the high-resolution grids read twice (`on`) or only at their 4
    /// nearest cells — the same latents and rate; reading twice costs decode time for quality
    /// (`ntc-0.2`'s default; at `ntc-0.5` +0.51 dB mean PSNR over the development materials for
    /// 12–15 % more decode instructions: docs/ENCODING.md, "The high-resolution grid read
    /// twice"). `None` for an NBC profile, which has no such grid.
    pub fn with_hi_bilinear(self, on: bool) -> Option<Profile> {
        let mut profile = self;
        match &mut profile {
            Profile::Ntc { hi_bilinear, .. } => *hi_bilinear = on,
            Profile::Nbc { .. } => return None,
        }
        Some(profile)
    }
    pub fn by_name(name: &str) -> Option<Profile> {
        PROFILES.into_iter().find(|p| p.name() == name)
    }
    /// The profile whose nominal rate is nearest to `bppc` (ties go to the NTC layout, which has
    /// the better quality at equal rate in our measurements).
    pub fn nearest(bppc: f64) -> Profile {
        let mut best = PROFILES[0];
        for p in PROFILES {
            let (d, e) = ((p.bppc() - bppc).abs(), (best.bppc() - bppc).abs());
            if d < e || (d == e && matches!(p, Profile::Ntc { .. })) {
                best = p;
            }
        }
        best
    }
}

/// One latent grid of the model.
#[derive(Clone, Debug, PartialEq)]
pub struct GridCfg {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub bits: u8,
}

#[derive(Clone, Debug, PartialEq)]
pub struct TermCfg {
    pub mode: TermMode,
    pub grids: Vec<usize>,
}

/// Everything that fixes the shape of a model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelConfig {
    pub profile: &'static str,
    pub grids: Vec<GridCfg>,
    pub levels: Vec<Vec<TermCfg>>,
    pub mip_to_level: Vec<u8>,
    pub pe_frequencies: u8,
    /// The LOD feature's code (docs/FORMAT.md §5.3): 0 none, 1 `mip / 16` (formats before 2.3),
    /// 2–5 `mip · 2^(code − 5)`; the profiles use 4 (`mip / 2`).
    pub lod_code: u8,
    pub hidden: Vec<usize>,
    /// Learned output channels.
    pub outputs: usize,
}

/// What the solver needs to know of a material: its size, channels and what else its file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaterialShape {
    pub width: u32,
    pub height: u32,
    pub mip_count: u32,
    /// Channels of the material, constant ones included.
    pub channels: usize,
    /// Channels the network learns: those that vary (BPPC's denominator; a constant channel
    /// costs nothing and is not counted).
    pub learned: usize,
    /// Bytes of the optional sections the file will carry (SOURCE_MAPS), each padded to 4.
    pub optional_bytes: usize,
}

impl MaterialShape {
    /// The bits a file of `bppc` bits per pixel per channel has for this material, counted over
    /// the channels that vary (as `Material::bppc` counts them).
    pub fn budget_bits(&self, bppc: f64) -> f64 {
        bppc * f64::from(self.width) * f64::from(self.height) * self.learned.max(1) as f64
    }
}

/// Where the bytes of a file go (docs/FORMAT.md §1–§5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ByteBudget {
    /// File header and section table.
    pub header: usize,
    /// MATERIAL section: size, channel records.
    pub material: usize,
    /// LEVELS section: grid records with their quantizers, level records.
    pub levels: usize,
    /// MLP section: int8 weights, row scales and biases, layer records.
    pub network: usize,
    /// LATENTS section: the packed latent codes.
    pub latents: usize,
    /// Optional sections (SOURCE_MAPS).
    pub optional: usize,
}

impl ByteBudget {
    pub fn total(&self) -> usize {
        self.header + self.material + self.levels + self.network + self.latents + self.optional
    }
}

fn align4(n: usize) -> usize {
    n.div_ceil(4) * 4
}

impl ModelConfig {
    pub fn input_width(&self) -> usize {
        let level: usize = self.levels[0]
            .iter()
            .map(|t| {
                let c = self.grids[t.grids[0]].channels;
                if t.mode == TermMode::Nearest4 { 4 * c } else { c }
            })
            .sum();
        level + 4 * usize::from(self.pe_frequencies) + usize::from(self.lod_code != 0)
    }

    /// The exact size of the file this model makes for `shape` (the writer's layout; a test
    /// compares the two on encoded files).
    pub fn byte_budget(&self, shape: &MaterialShape) -> ByteBudget {
        let mut widths = vec![self.input_width()];
        widths.extend(&self.hidden);
        widths.push(shape.channels);
        let network =
            8 + widths.windows(2).map(|w| 8 + align4(w[0] * w[1]) + 8 * w[1]).sum::<usize>();
        let levels = 20
            + self.grids.iter().map(|g| 16 + 4 * g.channels).sum::<usize>()
            + self.levels.iter().map(|terms| 4 + 12 * terms.len()).sum::<usize>();
        ByteBudget {
            header: 32 + 16 * (4 + usize::from(shape.optional_bytes > 0)),
            material: 12 + 32 * shape.channels,
            levels,
            network,
            latents: self.grids.iter().map(|g| 4 * g.bits().div_ceil(32)).sum(),
            optional: align4(shape.optional_bytes),
        }
    }

    pub fn latent_bits(&self) -> usize {
        self.grids.iter().map(GridCfg::bits).sum()
    }
}

impl GridCfg {
    /// Bits of its codes.
    pub fn bits(&self) -> usize {
        (self.width * self.height) as usize * self.channels * usize::from(self.bits)
    }
}

/// Hidden widths the solver may give the network, widest (the NTC paper's 64) first; multiples of
/// 16 so the SIMD decoders' row blocks stay full.
const HIDDEN_WIDTHS: [usize; 4] = [64, 48, 32, 16];
/// The largest share of a file the network may take. On small materials at low rates a 64-wide
/// network alone would be most of the file (at `nbc-0.05` on a 512² material with 7 channels,
/// ≈ 6.5 KB of 11.5): past this share a narrower network leaves the bits to the latents.
const MAX_NETWORK_SHARE: f64 = 0.25;
/// How far from the nominal rate the solver lets a file land. File sizes are exact (no entropy
/// coding), so this is what a file gets; docs/ENCODING.md promises ±5 %.
pub(crate) const RATE_TOLERANCE: f64 = 0.02;
/// Share of the latent bits an NTC layout gives its high-resolution grids (the 4-nearest features
/// carry the detail; the low-resolution grid is a smooth base).
const NTC_HI_SHARE: f64 = 0.8;

fn scaled(size: u32, divisor: f64) -> u32 {
    ((f64::from(size) / divisor).round() as u32).max(1)
}

/// The model of `profile` for a material of `shape`: the profile fixes the layout (NTC or NBC),
/// bit depths and the resolution of the grids that the positional encoding is tiled to; the
/// solver picks the network width, the latent channels and the resolution of the smooth grids so
/// that the whole file — header, network and latents — lands within ±2 % of the nominal rate
/// (docs/ENCODING.md). Materials too small for a rate get the closest file the layout can make.
pub fn configure(profile: Profile, shape: &MaterialShape) -> ModelConfig {
    let target = shape.budget_bits(profile.bppc()) / 8.0;
    let error = |cfg: &ModelConfig| {
        (cfg.byte_budget(shape).total() as f64 - target).abs() / target.max(1.0)
    };
    let mut closest: Option<(f64, ModelConfig)> = None;
    for hidden in HIDDEN_WIDTHS {
        let candidates = match profile {
            Profile::Ntc { .. } => ntc_candidates(profile, shape, hidden, target),
            Profile::Nbc { .. } => nbc_candidates(profile.name(), shape, hidden, target),
        };
        let mut fitting: Option<(f64, ModelConfig)> = None;
        for (preference, cfg) in candidates {
            let e = error(&cfg);
            if closest.as_ref().is_none_or(|(best, _)| e < *best) {
                closest = Some((e, cfg.clone()));
            }
            if e <= RATE_TOLERANCE && fitting.as_ref().is_none_or(|(p, _)| preference < *p) {
                fitting = Some((preference, cfg));
            }
        }
        if let Some((_, cfg)) = fitting {
            let share = cfg.byte_budget(shape).network as f64 / target;
            if share <= MAX_NETWORK_SHARE || hidden == HIDDEN_WIDTHS[HIDDEN_WIDTHS.len() - 1] {
                return cfg;
            }
        }
    }
    closest.map(|(_, cfg)| cfg).expect("every width has candidates")
}

/// How far under its target a grown layout may stay before [`configure_like`] adds bits per
/// latent (and solves smaller grids for them). The bits step costs quality where the grids alone
/// come near the target: at the same disk rate, 0.40–1.28 dB on the seven layouts measured
/// (`ntc-0.2`, `ntc-0.5`, `ntc-1.0`; docs/ENCODING.md, "Rate control"), and 5-bit latents decode
/// slower. Where the grids stay far under it (a material whose smooth grids reach the
/// high-resolution grids' size early), the bits keep the packed file near its nominal rate.
pub(crate) const BITS_STEP_ROOM: f64 = 0.05;

/// `like` (a [`configure`] result for `profile`) with the same latent channels and network, its
/// fixed-rate file grown toward `target` bytes: first the grids' resolution (the NTC layouts'
/// smooth grids up to the high-resolution grids' own, the NBC layouts' up to one cell per texel),
/// then, where that leaves the file more than [`BITS_STEP_ROOM`] under `target`, one or two more
/// bits per latent.
pub fn configure_like(
    profile: Profile,
    shape: &MaterialShape,
    target: f64,
    like: &ModelConfig,
) -> ModelConfig {
    let size = |cfg: &ModelConfig| cfg.byte_budget(shape).total() as f64;
    let mut best = grown(profile, shape, target, like, 0);
    for extra in 1..=2 {
        if size(&best) >= target * (1.0 - BITS_STEP_ROOM) {
            break;
        }
        let more = grown(profile, shape, target, like, extra);
        if (size(&more) - target).abs() < (size(&best) - target).abs() {
            best = more;
        }
    }
    best
}

/// The most bits a high-resolution latent takes in a bits-first layout (`configure_bits_first`):
/// from 4 bits up, the layouts measured did better with larger grids (`ntc-0.5`, `ntc-1.0`: 7
/// of 8) and 5-bit latents decoded slower (docs/ENCODING.md, "The bits step").
pub const BITS_FIRST_MAX_BITS: u8 = 4;

/// The other way to grow `like` toward `target` bytes, for a layout trial: one more bit per
/// latent first, then the grids' resolution. Only NTC layouts whose high-resolution latents stay
/// within [`BITS_FIRST_MAX_BITS`] have it (`ntc-0.2`: 3-bit high-resolution and 5-bit smooth
/// grids; where [`configure_like`] took the bit too, the two are the same); `None` otherwise.
pub fn configure_bits_first(
    profile: Profile,
    shape: &MaterialShape,
    target: f64,
    like: &ModelConfig,
) -> Option<ModelConfig> {
    let Profile::Ntc { hi_bits, .. } = profile else { return None };
    if hi_bits + 1 > BITS_FIRST_MAX_BITS {
        return None;
    }
    Some(grown(profile, shape, target, like, 1))
}

/// `like` with `extra` more bits per latent (at most 8) and its grids' resolution solved so that
/// the fixed-rate file comes nearest `target` bytes.
fn grown(
    profile: Profile,
    shape: &MaterialShape,
    target: f64,
    like: &ModelConfig,
    extra: u8,
) -> ModelConfig {
    let hidden = like.hidden[0];
    match profile {
        Profile::Ntc { hi_bits, lo_bits, .. } => {
            let (c_hi, c_lo) = (like.grids[0].channels, like.grids[1].channels);
            let bits = |b: u8| (b + extra).min(8);
            solve_scale(shape, target, (0.5, 8.0), |s| {
                ntc_layout(profile, shape, hidden, (c_hi, bits(hi_bits)), (c_lo, bits(lo_bits), s))
            })
        }
        Profile::Nbc { .. } => {
            let c = like.grids[0].channels;
            solve_scale(shape, target, (1.0, 64.0), |d| {
                let mut cfg = nbc_layout(profile.name(), shape, hidden, c, d);
                cfg.grids.iter_mut().for_each(|g| g.bits = (g.bits + extra).min(8));
                cfg
            })
        }
    }
}

/// The resolution factor of a continuous grid knob that brings the file closest to `target`
/// bytes: `make(s)` must give files that shrink as `s` grows; `s` is searched in `[lo, hi]`.
fn solve_scale(
    shape: &MaterialShape,
    target: f64,
    (lo, hi): (f64, f64),
    make: impl Fn(f64) -> ModelConfig,
) -> ModelConfig {
    let size = |s: f64| make(s).byte_budget(shape).total() as f64;
    let (mut a, mut b) = (lo, hi);
    // Geometric bisection: the knob divides a grid side, its effect is multiplicative.
    for _ in 0..40 {
        let mid = (a * b).sqrt();
        if size(mid) > target { a = mid } else { b = mid }
    }
    let (ea, eb) = ((size(a) - target).abs(), (size(b) - target).abs());
    make(if ea <= eb { a } else { b })
}

/// NTC: per level a high-resolution grid (4 nearest cells; one cell per `hi_divisor` texels, the
/// period the positional encoding tiles) and a bilinear low-resolution grid, one cell per
/// `2·hi_divisor·lo_scale` texels. Candidates over the channel counts, each with the
/// low-resolution scale solved for the target size; preference: the high-resolution share of the
/// latent bits nearest [`NTC_HI_SHARE`], then the smooth grid nearest its nominal resolution.
fn ntc_candidates(
    profile: Profile,
    shape: &MaterialShape,
    hidden: usize,
    target: f64,
) -> Vec<(f64, ModelConfig)> {
    let Profile::Ntc { hi_divisor, hi_bits, lo_bits, .. } = profile else {
        unreachable!("ntc_candidates of an NBC profile")
    };
    let mut out = Vec::new();
    for c_hi in 1..=16 {
        for c_lo in 1..=16 {
            let cfg = solve_scale(shape, target, (0.5, 8.0), |s| {
                ntc_layout(profile, shape, hidden, (c_hi, hi_bits), (c_lo, lo_bits, s))
            });
            let hi: usize = cfg.grids.iter().step_by(2).map(GridCfg::bits).sum();
            let share = hi as f64 / cfg.latent_bits().max(1) as f64;
            let nominal = f64::from(cfg.grids[1].width)
                / f64::from(scaled(shape.width, f64::from(2 * hi_divisor)));
            out.push(((share - NTC_HI_SHARE).abs() + 0.1 * nominal.log2().abs(), cfg));
        }
    }
    out
}

/// The level of an NTC layout that mip `mip` reads: the first `level0_mips` mips read level 0,
/// the others two by two the next levels. Level `k` is sized from mip `2k` (its high-resolution
/// grid one cell per `hi_divisor` texels there), so with `level0_mips` 3 and `hi_divisor` 4
/// every mip from 1 on reads a grid of one or two texels per cell along each axis, where the
/// NTC paper's pairs (`level0_mips` 2) leave the even mips from 2 on at `hi_divisor` texels per
/// cell, as sparse as mip 0 while a clean texture's small mips keep its edges (docs/ENCODING.md,
/// "Which level a mip reads").
pub fn ntc_level_of(mip: u32, level0_mips: u32) -> u32 {
    if mip < level0_mips { 0 } else { (mip - level0_mips) / 2 + 1 }
}

fn ntc_layout(
    profile: Profile,
    shape: &MaterialShape,
    hidden: usize,
    (c_hi, hi_bits): (usize, u8),
    (c_lo, lo_bits, lo_scale): (usize, u8, f64),
) -> ModelConfig {
    let Profile::Ntc { hi_divisor, level0_mips, hi_bilinear, .. } = profile else {
        unreachable!("ntc_layout of an NBC profile")
    };
    let level_of = |mip: u32| ntc_level_of(mip, level0_mips);
    let level_count = level_of(shape.mip_count.max(1) - 1) as usize + 1;
    let mut grids = Vec::new();
    let mut levels = Vec::new();
    for k in 0..level_count as u32 {
        let (mw, mh) = ((shape.width >> (2 * k)).max(1), (shape.height >> (2 * k)).max(1));
        let hi = grids.len();
        let d = f64::from(hi_divisor);
        grids.push(GridCfg {
            width: scaled(mw, d),
            height: scaled(mh, d),
            channels: c_hi,
            bits: hi_bits,
        });
        grids.push(GridCfg {
            width: scaled(mw, 2.0 * d * lo_scale),
            height: scaled(mh, 2.0 * d * lo_scale),
            channels: c_lo,
            bits: lo_bits,
        });
        let mut terms = vec![
            TermCfg { mode: TermMode::Nearest4, grids: vec![hi] },
            TermCfg { mode: TermMode::Bilinear, grids: vec![hi + 1] },
        ];
        if hi_bilinear {
            terms.push(TermCfg { mode: TermMode::Bilinear, grids: vec![hi] });
        }
        levels.push(terms);
    }
    ModelConfig {
        profile: profile.name(),
        grids,
        levels,
        mip_to_level: (0..shape.mip_count).map(|m| level_of(m) as u8).collect(),
        pe_frequencies: 2,
        lod_code: crate::train::LOD_CODE,
        hidden: vec![hidden; 2],
        outputs: shape.learned,
    }
}

/// Finest-grid divisor NBC is designed around (NBC's 1/4 resolution).
const NBC_DIVISOR: f64 = 4.0;

/// NBC: 4 residual levels of 8-4-2-1 bits coarse → fine, the finest one cell per `divisor`
/// texels. Candidates over the channel count, each with the divisor solved for the target size;
/// preference: the divisor nearest [`NBC_DIVISOR`].
fn nbc_candidates(
    name: &'static str,
    shape: &MaterialShape,
    hidden: usize,
    target: f64,
) -> Vec<(f64, ModelConfig)> {
    (1..=16)
        .map(|c| {
            let cfg =
                solve_scale(shape, target, (1.0, 64.0), |d| nbc_layout(name, shape, hidden, c, d));
            let d = f64::from(shape.width) / f64::from(cfg.grids[0].width);
            ((d / NBC_DIVISOR).log2().abs(), cfg)
        })
        .collect()
}

fn nbc_layout(
    name: &'static str,
    shape: &MaterialShape,
    hidden: usize,
    c: usize,
    divisor: f64,
) -> ModelConfig {
    const BITS_FINE_TO_COARSE: [u8; 4] = [1, 2, 4, 8];
    let level_count = (shape.mip_count as usize).min(4);
    let grids: Vec<GridCfg> = (0..level_count)
        .map(|l| GridCfg {
            width: scaled((shape.width >> l).max(1), divisor),
            height: scaled((shape.height >> l).max(1), divisor),
            channels: c,
            bits: BITS_FINE_TO_COARSE[l],
        })
        .collect();
    let levels = (0..level_count)
        .map(|l| {
            let fused: Vec<usize> = (l..level_count).collect();
            let coarser = if l + 1 < level_count { fused[1..].to_vec() } else { fused.clone() };
            vec![
                TermCfg { mode: TermMode::Bilinear, grids: fused },
                TermCfg { mode: TermMode::Bilinear, grids: coarser },
            ]
        })
        .collect();
    ModelConfig {
        profile: name,
        grids,
        levels,
        mip_to_level: (0..shape.mip_count)
            .map(|m| (m as usize).min(level_count - 1) as u8)
            .collect(),
        pe_frequencies: 2,
        lod_code: crate::train::LOD_CODE,
        hidden: vec![hidden; 2],
        outputs: shape.learned,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(size: u32, channels: usize, learned: usize) -> MaterialShape {
        MaterialShape {
            width: size,
            height: size,
            mip_count: 32 - size.leading_zeros(),
            channels,
            learned,
            // SOURCE_MAPS of four maps with short names, as the development set has.
            optional_bytes: 4 + 4 * 20,
        }
    }

    /// Every profile lands within ±5 % of its nominal rate — the whole file
    /// counted — on every material size of the development set (512² and 1024², 4–16 channels,
    /// some constant), and the 8 profiles are 8 different models.
    #[test]
    fn every_profile_holds_its_rate_on_development_sized_materials() {
        for size in [512, 1024] {
            for channels in 4..=16 {
                for learned in [channels, channels - 1] {
                    let s = shape(size, channels, learned);
                    let mut configs: Vec<ModelConfig> = Vec::new();
                    for p in PROFILES {
                        let cfg = configure(p, &s);
                        let bits = cfg.byte_budget(&s).total() as f64 * 8.0;
                        let off = bits / s.budget_bits(p.bppc()) - 1.0;
                        assert!(
                            off.abs() <= 0.05,
                            "{} on {size}² × {channels} ({learned} learned): {:+.1} %",
                            p.name(),
                            100.0 * off
                        );
                        let same = configs.iter().find(|c| c.grids == cfg.grids);
                        assert!(same.is_none(), "{} repeats {}", p.name(), same.unwrap().profile);
                        configs.push(cfg);
                    }
                }
            }
        }
    }

    /// Growing a layout toward a larger in-memory target: the grids' resolution first; more bits
    /// per latent only where the grids at their largest stay more than `BITS_STEP_ROOM` under it.
    #[test]
    fn grown_layouts_add_bits_only_where_the_grids_fall_far_short() {
        let s = shape(512, 9, 9);
        let p = Profile::by_name("ntc-1.0").unwrap();
        let nominal = configure(p, &s);
        let bits = |cfg: &ModelConfig| cfg.grids.iter().map(|g| g.bits).max().unwrap();
        let size = |cfg: &ModelConfig| cfg.byte_budget(&s).total() as f64;
        // The grids at their largest: the smooth grids as fine as the high-resolution ones.
        let Profile::Ntc { hi_bits, lo_bits, .. } = p else { unreachable!() };
        let (c_hi, c_lo) = (nominal.grids[0].channels, nominal.grids[1].channels);
        let hi = (c_hi, hi_bits);
        let largest = ntc_layout(p, &s, nominal.hidden[0], hi, (c_lo, lo_bits, 0.5));
        assert_eq!(largest.grids[1].width, largest.grids[0].width, "{:?}", largest.grids);
        let room = size(&largest);
        // A target the grids come within the room of: no extra bits, the largest grids.
        let near = configure_like(p, &s, room / (1.0 - BITS_STEP_ROOM / 2.0), &nominal);
        assert_eq!((bits(&near), &near.grids), (bits(&nominal), &largest.grids));
        // Far beyond it: more bits, and the file nearer the target than the grids alone get.
        let target = room * 1.3;
        let far = configure_like(p, &s, target, &nominal);
        assert!(bits(&far) > bits(&nominal), "{:?}", far.grids);
        assert!((size(&far) - target).abs() < (room - target).abs());
    }

    /// `ntc-0.2` and `ntc-0.5` (high-resolution grids at 1/4) read mips 0–2 from level 0 and the
    /// others two by two; every level is read, and every mip from 1 on finds its high-resolution
    /// grid at one or two texels per cell (the reason for the rule). The profiles whose grids are
    /// at 1/2 keep the paper's pairs.
    #[test]
    fn ntc_0_2_and_0_5_read_three_mips_from_level_0_and_the_others_two_by_two() {
        let expected: [&[u8]; 4] =
            [&[0], &[0, 0, 0], &[0, 0, 0, 1], &[0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4]];
        for name in ["ntc-0.2", "ntc-0.5"] {
            let p = Profile::by_name(name).unwrap();
            for (size, want) in [1, 4, 8, 1024].into_iter().zip(expected) {
                let s = shape(size, 9, 9);
                let cfg = configure(p, &s);
                assert_eq!(cfg.mip_to_level, want, "{name} {size}²");
                assert_eq!(cfg.levels.len(), usize::from(want[want.len() - 1]) + 1, "{size}²");
            }
            for size in [256, 512, 1024, 2048] {
                let s = shape(size, 9, 9);
                let cfg = configure(p, &s);
                for mip in 1..s.mip_count {
                    let level = &cfg.levels[usize::from(cfg.mip_to_level[mip as usize])];
                    let hi = &cfg.grids[level[0].grids[0]];
                    let texels = (size >> mip).max(1);
                    let ok = hi.width <= texels && texels <= 2 * hi.width;
                    assert!(ok, "{name} {size}² mip {mip}: {texels} texels, {hi:?}");
                }
            }
        }
        // High-resolution grids at 1/2: mip 2 would read two cells per texel.
        for name in ["ntc-1.0", "ntc-2.25"] {
            let cfg = configure(Profile::by_name(name).unwrap(), &shape(1024, 9, 9));
            let pairs: Vec<u8> = (0..11).map(|m| m / 2).collect();
            assert_eq!(cfg.mip_to_level, pairs, "{name}");
        }
    }

    #[test]
    fn narrow_networks_only_where_the_wide_one_would_crowd_out_the_latents() {
        let big = shape(1024, 9, 9);
        for p in PROFILES {
            assert_eq!(configure(p, &big).hidden, [64, 64], "{} on 1024²", p.name());
        }
        let small = shape(512, 4, 4);
        let cfg = configure(Profile::by_name("nbc-0.05").unwrap(), &small);
        assert!(cfg.hidden[0] < 64, "{:?}", cfg.hidden);
        let b = cfg.byte_budget(&small);
        assert!(b.network as f64 <= MAX_NETWORK_SHARE * b.total() as f64 * 1.05, "{b:?}");
    }
}
