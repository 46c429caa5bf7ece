//! Deterministic generator of test materials: random but seeded latents and weights in the NTC and
//! NBC layouts of docs/FORMAT.md §8, or in a level of any terms. The weights are built as a
//! quantization-aware trainer would leave them: int8 codes with per-row scales and i32 biases. The
//! file stores that one network; the float decoder dequantizes it, so the two decoders differ in
//! arithmetic only.

use nmat_core::{
    Activation, AddressMode, ChannelSpec, ColorSpace, GridSpec, LayerSpec, LevelSpec, MaterialSpec,
    MlpSpec, Semantic, TermMode, TermSpec,
};

/// SplitMix64: tiny, seedable, and identical on every platform.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x6A09_E667_F3BC_C909)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [lo, hi] (inclusive).
    pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
        lo + (self.next_u64() % ((hi - lo + 1) as u64)) as i64
    }
}

/// How the feature pyramid is laid out.
#[derive(Clone, Debug, PartialEq)]
pub enum Layout {
    /// NTC: level k covers mips 2k and 2k+1 with a high-res grid (1/4 of mip 2k, sampled by its 4
    /// nearest cells) and a low-res grid (1/8, bilinear).
    Ntc { hi_channels: u8, lo_channels: u8, hi_bits: u8, lo_bits: u8 },
    /// NBC: one residual grid per level with its own bit depth (given coarse → fine); level l reads
    /// its fused features (bilinear sum of its residual and every coarser one) and, as its low-res
    /// input, the fused next-coarser level. Level l covers mip l; the coarsest covers the rest.
    Nbc { channels: u8, bits_coarse_to_fine: Vec<u8> },
    /// One level of `terms` read by every mip, over `grids` given as (channels, bits per code),
    /// grid g at 1/2^(g + 2) of mip 0: the orders and combinations the format allows (FORMAT.md
    /// §5.2) that the NTC and NBC layouts never write, such as two `Nearest4` terms in a level
    /// or a grid read bilinearly before it is read by its nearest cells. A chain's grids need
    /// the same channel count.
    Terms { grids: Vec<(u8, u8)>, terms: Vec<TermSpec> },
}

#[derive(Clone, Debug, PartialEq)]
pub struct FixtureConfig {
    pub name: &'static str,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// 0 = the full chain.
    pub mip_count: u8,
    pub channels: u8,
    pub layout: Layout,
    pub address_mode: AddressMode,
    pub hidden: Vec<u16>,
    pub pe_frequencies: u8,
    /// The file's `lod_input` code: 0 none, 1 `mip / 16`, 2–5 `mip · 2^(code − 5)`.
    pub lod_input: u8,
    pub input_frac_bits: u8,
    pub hidden_frac_bits: u8,
    pub output_frac_bits: u8,
    /// NTC only: each level also reads its high-resolution grid bilinearly, a third term after
    /// `Nearest4[hi]` and `Bilinear[lo]` (one grid read in two modes, as `ntc-0.2` files do).
    pub ntc_hi_bilinear: bool,
}

impl FixtureConfig {
    /// A small NTC material with sensible defaults, to be adjusted field by field.
    pub fn ntc(
        name: &'static str,
        seed: u64,
        width: u32,
        height: u32,
        channels: u8,
    ) -> FixtureConfig {
        FixtureConfig {
            name,
            seed,
            width,
            height,
            mip_count: 0,
            channels,
            layout: Layout::Ntc { hi_channels: 4, lo_channels: 4, hi_bits: 4, lo_bits: 4 },
            address_mode: AddressMode::Wrap,
            hidden: vec![32, 32],
            pe_frequencies: 2,
            lod_input: 1,
            input_frac_bits: 12,
            hidden_frac_bits: 12,
            output_frac_bits: 14,
            ntc_hi_bilinear: false,
        }
    }

    pub fn nbc(
        name: &'static str,
        seed: u64,
        width: u32,
        height: u32,
        channels: u8,
    ) -> FixtureConfig {
        FixtureConfig {
            layout: Layout::Nbc { channels: 6, bits_coarse_to_fine: vec![8, 4, 2, 1] },
            ..FixtureConfig::ntc(name, seed, width, height, channels)
        }
    }
}

/// The golden fixtures of `tests/fixtures/` (see `tests/fixtures/README.md`).
pub fn golden_configs() -> Vec<FixtureConfig> {
    vec![
        // The NTC paper's shape: 2 hidden layers of 64, 4-cell high-res + bilinear low-res grids.
        FixtureConfig {
            hidden: vec![64, 64],
            layout: Layout::Ntc { hi_channels: 8, lo_channels: 8, hi_bits: 4, lo_bits: 4 },
            ..FixtureConfig::ntc("ntc_rgb_64", 1, 64, 64, 3)
        },
        // Non-power-of-two, clamp addressing, a PBR set of 10 channels.
        FixtureConfig {
            address_mode: AddressMode::Clamp,
            ..FixtureConfig::ntc("ntc_pbr10_96x80_clamp", 2, 96, 80, 10)
        },
        // Every channel the format allows; 8-bit latents on both grids.
        FixtureConfig {
            layout: Layout::Ntc { hi_channels: 4, lo_channels: 4, hi_bits: 8, lo_bits: 8 },
            ..FixtureConfig::ntc("ntc_16ch_8bit_32", 3, 32, 32, 16)
        },
        // 1-bit latents on the high-res grid, other Q-formats.
        FixtureConfig {
            layout: Layout::Ntc { hi_channels: 6, lo_channels: 2, hi_bits: 1, lo_bits: 2 },
            input_frac_bits: 10,
            hidden_frac_bits: 11,
            output_frac_bits: 13,
            pe_frequencies: 3,
            ..FixtureConfig::ntc("ntc_1bit_q10_40x24", 4, 40, 24, 4)
        },
        // NBC: 8-4-2-1 bits coarse → fine, residual fusion and feature reuse.
        FixtureConfig { hidden: vec![64, 64], ..FixtureConfig::nbc("nbc_8421_64", 5, 64, 64, 4) },
        FixtureConfig {
            address_mode: AddressMode::Clamp,
            lod_input: 0,
            pe_frequencies: 0,
            layout: Layout::Nbc { channels: 4, bits_coarse_to_fine: vec![8, 1, 1] },
            hidden_frac_bits: 10, // three fused grids reach beyond the ±8 of Q.12 (FORMAT.md §6.6)
            ..FixtureConfig::nbc("nbc_clamp_nolod_48x36", 6, 48, 36, 3)
        },
        // Degenerate sizes: one texel; a 1×N strip; a single hidden layer.
        FixtureConfig { hidden: vec![8], ..FixtureConfig::ntc("tiny_1x1", 7, 1, 1, 1) },
        FixtureConfig { hidden: vec![16, 16, 16], ..FixtureConfig::ntc("strip_1x37", 8, 1, 37, 2) },
        // One grid read in two modes: each level's high-res grid by its 4 nearest cells and
        // bilinearly (the layout of `ntc-0.2` files); 2-bit high-res latents as there.
        FixtureConfig {
            layout: Layout::Ntc { hi_channels: 6, lo_channels: 2, hi_bits: 2, lo_bits: 4 },
            ntc_hi_bilinear: true,
            ..FixtureConfig::ntc("ntc_hi_twice_48x40", 9, 48, 40, 6)
        },
    ]
}

fn full_chain(width: u32, height: u32) -> u8 {
    (32 - width.max(height).leading_zeros()) as u8
}

fn random_grid(
    rng: &mut Rng,
    width: u32,
    height: u32,
    channels: u8,
    bits: u8,
    frac_bits: u8,
) -> GridSpec {
    let max_code = (1i32 << bits) - 1;
    let one = 1i32 << frac_bits;
    let quantization = (0..channels)
        .map(|_| {
            // Latents spread over about ±2 (asymmetric: a random offset), exact in Q.frac_bits.
            // Capped so that every dequantized value stays an i16 at high fraction bits.
            let span = (one * 4 * (75 + rng.range(0, 50) as i32) / 100).min(60000);
            let step = (span / max_code).clamp(1, 32767);
            let half = step * max_code / 2;
            let jitter = (one / 4).min(32767 - (step * max_code - half)).min(32768 - half);
            let offset = -half + rng.range(-i64::from(jitter), i64::from(jitter)) as i32;
            (offset as i16, step as i16)
        })
        .collect();
    let cells = (width * height) as usize * usize::from(channels);
    GridSpec {
        width: width as u16,
        height: height as u16,
        channels,
        bits,
        quantization,
        codes: (0..cells).map(|_| rng.range(0, i64::from(max_code)) as u8).collect(),
    }
}

/// A layer with int8 codes, per-row scales and the matching float weights (see module docs).
/// `gain` sets the output spread; `center` the real value the outputs are centred on.
fn random_layer(
    rng: &mut Rng,
    inputs: u16,
    outputs: u16,
    frac: (u8, u8),
    activation: Activation,
    gain: f64,
    center: f64,
) -> LayerSpec {
    let (in_frac, out_frac) = frac;
    let n = usize::from(inputs) * usize::from(outputs);
    let weights_i8: Vec<i8> = (0..n).map(|_| rng.range(-127, 127) as i8).collect();
    let base = gain / (127.0 * (f64::from(inputs)).sqrt() * 0.577);
    let scales: Vec<f32> =
        (0..outputs).map(|_| (base * (0.75 + 0.5 * rng.unit())) as f32).collect();
    let in_lsb = 1.0 / f64::from(1u32 << in_frac);
    let bias: Vec<i32> = scales
        .iter()
        .map(|&s| ((center + 0.2 * (rng.unit() - 0.5)) / (f64::from(s) * in_lsb)).round() as i32)
        .collect();
    LayerSpec { inputs, outputs, out_frac_bits: out_frac, activation, weights_i8, scales, bias }
}

const CHANNEL_NAMES: [(&str, Semantic, ColorSpace); 16] = [
    ("albedo.r", Semantic::ALBEDO, ColorSpace::Srgb),
    ("albedo.g", Semantic::ALBEDO, ColorSpace::Srgb),
    ("albedo.b", Semantic::ALBEDO, ColorSpace::Srgb),
    ("normal.x", Semantic::NORMAL, ColorSpace::Linear),
    ("normal.y", Semantic::NORMAL, ColorSpace::Linear),
    ("normal.z", Semantic::NORMAL, ColorSpace::Linear),
    ("roughness", Semantic::ROUGHNESS, ColorSpace::Linear),
    ("height", Semantic::HEIGHT, ColorSpace::Linear),
    ("ao", Semantic::AMBIENT_OCCLUSION, ColorSpace::Linear),
    ("metallic", Semantic::METALLIC, ColorSpace::Linear),
    ("emissive.r", Semantic::EMISSIVE, ColorSpace::Srgb),
    ("emissive.g", Semantic::EMISSIVE, ColorSpace::Srgb),
    ("emissive.b", Semantic::EMISSIVE, ColorSpace::Srgb),
    ("opacity", Semantic::OPACITY, ColorSpace::Linear),
    ("specular", Semantic::SPECULAR, ColorSpace::Linear),
    ("mask", Semantic::UNKNOWN, ColorSpace::Linear),
];

/// Builds the material a config describes. Same config → same spec → same bytes.
pub fn generate(cfg: &FixtureConfig) -> MaterialSpec {
    let mut rng = Rng::new(cfg.seed);
    let mip_count =
        if cfg.mip_count == 0 { full_chain(cfg.width, cfg.height) } else { cfg.mip_count };
    let f = cfg.input_frac_bits;
    let (mut grids, mut levels, mut mip_to_level) = (Vec::new(), Vec::new(), Vec::new());
    let scaled = |size: u32, shift: u32| (size >> shift.min(31)).max(1);
    match &cfg.layout {
        Layout::Ntc { hi_channels, lo_channels, hi_bits, lo_bits } => {
            let level_count = usize::from(mip_count).div_ceil(2);
            for k in 0..level_count as u32 {
                let hi = grids.len() as u8;
                grids.push(random_grid(
                    &mut rng,
                    scaled(cfg.width, 2 * k + 2),
                    scaled(cfg.height, 2 * k + 2),
                    *hi_channels,
                    *hi_bits,
                    f,
                ));
                grids.push(random_grid(
                    &mut rng,
                    scaled(cfg.width, 2 * k + 3),
                    scaled(cfg.height, 2 * k + 3),
                    *lo_channels,
                    *lo_bits,
                    f,
                ));
                let mut terms = vec![
                    TermSpec { mode: TermMode::Nearest4, grids: vec![hi] },
                    TermSpec { mode: TermMode::Bilinear, grids: vec![hi + 1] },
                ];
                if cfg.ntc_hi_bilinear {
                    terms.push(TermSpec { mode: TermMode::Bilinear, grids: vec![hi] });
                }
                levels.push(LevelSpec { terms });
            }
            mip_to_level.extend((0..mip_count).map(|m| m / 2));
        }
        Layout::Nbc { channels, bits_coarse_to_fine } => {
            let level_count = bits_coarse_to_fine.len().min(usize::from(mip_count));
            // Grid l is level l's residual; l = 0 is the finest.
            for l in 0..level_count {
                let bits = bits_coarse_to_fine[bits_coarse_to_fine.len() - 1 - l];
                grids.push(random_grid(
                    &mut rng,
                    scaled(cfg.width, l as u32 + 2),
                    scaled(cfg.height, l as u32 + 2),
                    *channels,
                    bits,
                    f,
                ));
            }
            for l in 0..level_count {
                let fused: Vec<u8> = (l..level_count).map(|g| g as u8).collect();
                let coarser: Vec<u8> =
                    if l + 1 < level_count { fused[1..].to_vec() } else { fused.clone() };
                levels.push(LevelSpec {
                    terms: vec![
                        TermSpec { mode: TermMode::Bilinear, grids: fused },
                        TermSpec { mode: TermMode::Bilinear, grids: coarser },
                    ],
                });
            }
            mip_to_level.extend((0..mip_count).map(|m| (m as usize).min(level_count - 1) as u8));
        }
        Layout::Terms { grids: layout, terms } => {
            for (g, &(channels, bits)) in layout.iter().enumerate() {
                let (w, h) = (scaled(cfg.width, g as u32 + 2), scaled(cfg.height, g as u32 + 2));
                grids.push(random_grid(&mut rng, w, h, channels, bits, f));
            }
            levels.push(LevelSpec { terms: terms.clone() });
            mip_to_level.resize(usize::from(mip_count), 0);
        }
    }
    let level_width: usize = levels[0]
        .terms
        .iter()
        .map(|t| {
            let c = usize::from(grids[usize::from(t.grids[0])].channels);
            if t.mode == TermMode::Nearest4 { 4 * c } else { c }
        })
        .sum();
    let input_width = (level_width
        + 4 * usize::from(cfg.pe_frequencies)
        + usize::from(cfg.lod_input != 0)) as u16;
    let mut layers = Vec::new();
    let mut prev = (input_width, f);
    for &h in &cfg.hidden {
        layers.push(random_layer(
            &mut rng,
            prev.0,
            h,
            (prev.1, cfg.hidden_frac_bits),
            Activation::HardGelu,
            1.0,
            0.0,
        ));
        prev = (h, cfg.hidden_frac_bits);
    }
    layers.push(random_layer(
        &mut rng,
        prev.0,
        u16::from(cfg.channels),
        (prev.1, cfg.output_frac_bits),
        Activation::None,
        0.35,
        0.5,
    ));
    let channels = (0..usize::from(cfg.channels))
        .map(|c| {
            let (name, semantic, color_space) = CHANNEL_NAMES[c];
            let ranged = semantic == Semantic::NORMAL;
            ChannelSpec {
                name: name.to_string(),
                semantic,
                component: name.ends_with(".g") as u8
                    + name.ends_with(".y") as u8
                    + 2 * (name.ends_with(".b") || name.ends_with(".z")) as u8,
                color_space,
                range_min: if ranged { -1.0 } else { 0.0 },
                range_max: 1.0,
            }
        })
        .collect();
    MaterialSpec {
        width: cfg.width,
        height: cfg.height,
        mip_count,
        address_mode: cfg.address_mode,
        channels,
        mip_to_level,
        grids,
        levels,
        mlp: MlpSpec {
            input_frac_bits: f,
            pe_frequencies: cfg.pe_frequencies,
            lod_input: cfg.lod_input,
            layers,
        },
        optional_sections: Vec::new(),
    }
}

/// A one-layer material whose 128 inputs are two constant 16-channel grids read by `Nearest4`.
pub fn wide_constant_material(input: i16, weight: i8, bias: i32) -> MaterialSpec {
    let cfg = FixtureConfig {
        mip_count: 1,
        hidden: vec![],
        pe_frequencies: 0,
        lod_input: 0,
        layout: Layout::Ntc { hi_channels: 16, lo_channels: 16, hi_bits: 1, lo_bits: 1 },
        ..FixtureConfig::ntc("wide", 12, 4, 4, 1)
    };
    let mut spec = generate(&cfg);
    for g in &mut spec.grids {
        g.quantization = vec![(input, 0); 16];
    }
    spec.levels[0].terms[1].mode = TermMode::Nearest4;
    let layer = &mut spec.mlp.layers[0];
    layer.inputs = 128;
    layer.weights_i8 = vec![weight; 128];
    layer.bias = vec![bias];
    layer.scales = vec![1.0 / 65536.0];
    spec
}

/// The largest |bias| the format allows for a fan-in of 128 (FORMAT.md §5.3): with every input
/// at ±2^15 and every weight ±127 the accumulator then reaches ±(2^31 − 1).
pub const BIAS_LIMIT_128: i32 = i32::MAX - 128 * 127 * 32768;

/// The (input, weight, bias) of [`wide_constant_material`] whose accumulators reach the bound,
/// ±(2^31 − 1): the sum at its largest magnitude of each sign, each from both sign pairs of
/// input and weight, with the bias of the same sign.
pub fn accumulator_corners() -> [(i16, i8, i32); 4] {
    [
        (i16::MAX, 127, BIAS_LIMIT_128),
        (i16::MIN, 127, -BIAS_LIMIT_128),
        (i16::MIN, -127, BIAS_LIMIT_128),
        (i16::MAX, -127, -BIAS_LIMIT_128),
    ]
}

/// A material whose one level reads its grids in an order the NTC and NBC layouts never write
/// (`Layout::Terms`): `Bilinear[0]`, `Nearest4[1]`, `Nearest4[0]`, `Bilinear[2, 0, 2, 2, 0, 0,
/// 2, 0]` — two nearest terms, the second on a grid read bilinearly before, and the longest
/// chain the format allows (8), fusing that grid with another, each several times; grids of 3,
/// 5 and 3 channels at 4, 2 and 8 bits per code; 47 inputs (Q.10, so that the sums of eight
/// latents mostly stay inside i16), 5 channels.
pub fn terms_in_any_order() -> FixtureConfig {
    let term = |mode, grids: &[u8]| TermSpec { mode, grids: grids.to_vec() };
    FixtureConfig {
        layout: Layout::Terms {
            grids: vec![(3, 4), (5, 2), (3, 8)],
            terms: vec![
                term(TermMode::Bilinear, &[0]),
                term(TermMode::Nearest4, &[1]),
                term(TermMode::Nearest4, &[0]),
                term(TermMode::Bilinear, &[2, 0, 2, 2, 0, 0, 2, 0]),
            ],
        },
        hidden: vec![24],
        input_frac_bits: 10,
        ..FixtureConfig::ntc("terms_in_any_order", 16, 37, 29, 5)
    }
}

/// A material whose grids' cells are wider than one 64-bit read holds (the decoders' window
/// reads take at most 57 bits; a cell wider than that is read latent by latent): 16 channels at
/// 8 bits (128 bits a cell), 12 at 5 (60) and 8 at 8 (64), read by their 4 nearest cells and
/// bilinearly; 93 inputs, 4 channels.
pub fn wide_cells() -> FixtureConfig {
    let term = |mode, grid| TermSpec { mode, grids: vec![grid] };
    FixtureConfig {
        layout: Layout::Terms {
            grids: vec![(16, 8), (12, 5), (8, 8)],
            terms: vec![
                term(TermMode::Nearest4, 0),
                term(TermMode::Bilinear, 1),
                term(TermMode::Bilinear, 2),
            ],
        },
        hidden: vec![16],
        ..FixtureConfig::ntc("wide_cells", 17, 45, 27, 4)
    }
}

/// A level that reads all 16 grids the format allows, in two chains of 8 and two nearest terms:
/// `Bilinear[0..8]`, `Bilinear[8..16]`, `Nearest4[3]`, `Nearest4[12]` — 18 distinct (grid, mode)
/// pairs, the most a level can have, each of which a decoder steps along a row once; grids of 2
/// channels at 1 to 8 bits per code; 29 inputs (Q.10, as in [`terms_in_any_order`]), 3
/// channels.
pub fn sixteen_grids_in_one_level() -> FixtureConfig {
    let term = |mode, grids: core::ops::Range<u8>| TermSpec { mode, grids: grids.collect() };
    FixtureConfig {
        layout: Layout::Terms {
            grids: (0..16).map(|g| (2, g % 8 + 1)).collect(),
            terms: vec![
                term(TermMode::Bilinear, 0..8),
                term(TermMode::Bilinear, 8..16),
                term(TermMode::Nearest4, 3..4),
                term(TermMode::Nearest4, 12..13),
            ],
        },
        hidden: vec![16],
        input_frac_bits: 10,
        ..FixtureConfig::ntc("sixteen_grids_in_one_level", 18, 64, 48, 3)
    }
}

/// A 16384² material of 15 mips, the largest the format allows (two grids of 2 channels at 2
/// bits, one hidden layer of 8, 8 frequencies of the positional encoding, 2 channels): its
/// grids are those of a 64² material, since the NTC layout's at 16384² (4096²) would be too big
/// for a test.
pub fn largest_material() -> MaterialSpec {
    let cfg = FixtureConfig {
        mip_count: 7,
        layout: Layout::Ntc { hi_channels: 2, lo_channels: 2, hi_bits: 2, lo_bits: 2 },
        hidden: vec![8],
        pe_frequencies: 8,
        ..FixtureConfig::ntc("huge", 15, 64, 64, 2)
    };
    let mut spec = generate(&cfg);
    spec.width = 16384;
    spec.height = 16384;
    spec.mip_count = 15;
    spec.mip_to_level = (0..15).map(|m: u8| (m / 2).min(3)).collect();
    spec
}

/// Every latent code of `spec` set to `pattern(index, max)`, where `max` is the largest code of
/// the code's grid (its bits per code all set).
pub fn set_codes(spec: &mut MaterialSpec, pattern: impl Fn(usize, u8) -> u8) {
    for g in &mut spec.grids {
        let max = ((1u16 << g.bits) - 1) as u8;
        g.codes = (0..g.codes.len()).map(|i| pattern(i, max)).collect();
    }
}

/// The `lod_input` code a uniform draw `u` picks: 0 below ½, else 1–5 evenly.
fn lod_code(u: f64, f: u8) -> u8 {
    if u < 0.5 { 0 } else { fitting_lod_code(1 + ((u - 0.5) * 10.0).min(4.0) as u8, f) }
}

/// `code` (0–5) where input format Q.`f` holds its LOD feature at every mip (`f + code ≤ 16` for
/// the scaled codes 2–5, FORMAT.md §6.5), else 1 (`mip / 16`).
pub fn fitting_lod_code(code: u8, f: u8) -> u8 {
    if code <= 1 || u16::from(f) + u16::from(code) <= 16 { code } else { 1 }
}

/// The golden fixtures' configurations, [`terms_in_any_order`], [`wide_cells`],
/// [`sixteen_grids_in_one_level`], then `random` random ones
/// (seeds 0, 1, …): the network shapes and latent layouts a code generator is checked on.
pub fn golden_and_random_configs(random: u64) -> Vec<FixtureConfig> {
    let unusual = [terms_in_any_order(), wide_cells(), sixteen_grids_in_one_level()];
    let configs = golden_configs().into_iter().chain(unusual);
    configs.chain((0..random).map(random_config)).collect()
}

/// A random but valid configuration: sizes, layouts, bit depths, Q-formats, widths.
pub fn random_config(seed: u64) -> FixtureConfig {
    let mut r = Rng::new(seed);
    let pick = |r: &mut Rng, lo: i64, hi: i64| r.range(lo, hi);
    let width = pick(&mut r, 1, 70) as u32;
    let height = pick(&mut r, 1, 70) as u32;
    let channels = pick(&mut r, 1, 16) as u8;
    let input_frac_bits = pick(&mut r, 6, 14) as u8;
    let layout = if r.unit() < 0.5 {
        Layout::Ntc {
            hi_channels: pick(&mut r, 1, 12) as u8,
            lo_channels: pick(&mut r, 1, 12) as u8,
            hi_bits: pick(&mut r, 1, 8) as u8,
            lo_bits: pick(&mut r, 1, 8) as u8,
        }
    } else {
        let levels = pick(&mut r, 1, 5) as usize;
        Layout::Nbc {
            channels: pick(&mut r, 1, 16) as u8,
            bits_coarse_to_fine: (0..levels).map(|_| pick(&mut r, 1, 8) as u8).collect(),
        }
    };
    let hidden = (0..pick(&mut r, 0, 3)).map(|_| pick(&mut r, 1, 64) as u16).collect();
    let full = (32 - width.max(height).leading_zeros()) as i64;
    let is_ntc = matches!(layout, Layout::Ntc { .. });
    FixtureConfig {
        name: "random",
        seed,
        width,
        height,
        mip_count: pick(&mut r, 1, full) as u8,
        channels,
        layout,
        address_mode: if r.unit() < 0.5 { AddressMode::Wrap } else { AddressMode::Clamp },
        hidden,
        pe_frequencies: pick(&mut r, 0, i64::from(input_frac_bits - 2).min(4)) as u8,
        // Half without a LOD feature, the rest spread over the codes that fit the input format.
        lod_input: lod_code(r.unit(), input_frac_bits),
        input_frac_bits,
        hidden_frac_bits: pick(&mut r, 8, 13) as u8,
        output_frac_bits: pick(&mut r, 8, 14) as u8,
        // Drawn last, so the draws above are those of the configurations before this field.
        ntc_hi_bilinear: is_ntc && r.unit() < 0.5,
    }
}
