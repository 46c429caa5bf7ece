//! Profiles: named rate points that fix the feature-pyramid layout (NTC or NBC), bit depths and
//! grid resolutions, with the number of latent channels solved from the bit budget of the material
//! at hand (docs/ENCODING.md explains the arithmetic).

use nmat_core::TermMode;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Profile {
    /// NTC layout: per level a high-res grid (4 nearest cells) and a low-res grid (bilinear).
    Ntc { name: &'static str, bppc: f64, hi_divisor: u32, hi_bits: u8, lo_bits: u8 },
    /// NBC layout: 4 residual levels with 8-4-2-1 bits coarse → fine, fused.
    Nbc { name: &'static str, bppc: f64 },
}

pub const PROFILES: [Profile; 8] = [
    Profile::Nbc { name: "nbc-0.05", bppc: 0.05 },
    Profile::Nbc { name: "nbc-0.1", bppc: 0.1 },
    Profile::Nbc { name: "nbc-0.2", bppc: 0.2 },
    Profile::Ntc { name: "ntc-0.2", bppc: 0.2, hi_divisor: 4, hi_bits: 2, lo_bits: 4 },
    Profile::Nbc { name: "nbc-0.5", bppc: 0.5 },
    Profile::Ntc { name: "ntc-0.5", bppc: 0.5, hi_divisor: 4, hi_bits: 4, lo_bits: 4 },
    Profile::Ntc { name: "ntc-1.0", bppc: 1.0, hi_divisor: 2, hi_bits: 4, lo_bits: 4 },
    Profile::Ntc { name: "ntc-2.25", bppc: 2.25, hi_divisor: 2, hi_bits: 8, lo_bits: 8 },
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
    pub lod_input: bool,
    pub hidden: Vec<usize>,
    /// Learned output channels.
    pub outputs: usize,
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
        level + 4 * usize::from(self.pe_frequencies) + usize::from(self.lod_input)
    }

    /// Bytes of the MLP in the file (int8 + f16 weights, scales, two biases).
    pub fn mlp_bytes(&self, channels: usize) -> usize {
        let mut widths = vec![self.input_width()];
        widths.extend(&self.hidden);
        widths.push(channels);
        widths.windows(2).map(|w| w[0] * w[1] * 3 + w[1] * 12 + 8).sum()
    }

    pub fn latent_bits(&self) -> usize {
        self.grids
            .iter()
            .map(|g| (g.width * g.height) as usize * g.channels * usize::from(g.bits))
            .sum()
    }
}

const HIDDEN: [usize; 2] = [64, 64];

fn scaled(size: u32, divisor: u32) -> u32 {
    size.div_ceil(divisor).max(1)
}

/// Solves the layout of `profile` for a `width × height` material with `channels` channels
/// (`learned` of them not constant) and `mip_count` mips.
pub fn configure(
    profile: Profile,
    width: u32,
    height: u32,
    mip_count: u32,
    channels: usize,
    learned: usize,
) -> ModelConfig {
    let texels = f64::from(width) * f64::from(height);
    // Bits per mip-0 texel the latents may spend; the MLP (estimated for a mid-size model) is
    // paid first, so small materials get fewer latent channels at the same nominal rate.
    let mlp_estimate = ((40 * 64 + 64 * 64 + 64 * channels) * 3 * 8) as f64;
    let budget = ((profile.bppc() * texels * channels as f64 - mlp_estimate) / texels).max(0.0);
    match profile {
        Profile::Ntc { hi_divisor, hi_bits, lo_bits, .. } => {
            // Level k's high-res grid is mip 2k / divisor per side; all levels together hold
            // 16/15 of level 0's cells, the low-res grids a quarter of that.
            let cells = 16.0 / (15.0 * f64::from(hi_divisor * hi_divisor));
            let per_cell = budget / cells;
            let c_hi = ((0.8 * per_cell / f64::from(hi_bits)).floor() as usize).clamp(1, 16);
            let rest = (per_cell - (c_hi * usize::from(hi_bits)) as f64).max(0.0);
            let c_lo = ((4.0 * rest / f64::from(lo_bits)).floor() as usize).clamp(1, 16);
            let level_count = mip_count.div_ceil(2) as usize;
            let mut grids = Vec::new();
            let mut levels = Vec::new();
            for k in 0..level_count as u32 {
                let (mw, mh) = ((width >> (2 * k)).max(1), (height >> (2 * k)).max(1));
                let hi = grids.len();
                grids.push(GridCfg {
                    width: scaled(mw, hi_divisor),
                    height: scaled(mh, hi_divisor),
                    channels: c_hi,
                    bits: hi_bits,
                });
                grids.push(GridCfg {
                    width: scaled(mw, 2 * hi_divisor),
                    height: scaled(mh, 2 * hi_divisor),
                    channels: c_lo,
                    bits: lo_bits,
                });
                levels.push(vec![
                    TermCfg { mode: TermMode::Nearest4, grids: vec![hi] },
                    TermCfg { mode: TermMode::Bilinear, grids: vec![hi + 1] },
                ]);
            }
            ModelConfig {
                profile: profile.name(),
                grids,
                levels,
                mip_to_level: (0..mip_count).map(|m| (m / 2) as u8).collect(),
                pe_frequencies: 2,
                lod_input: true,
                hidden: HIDDEN.to_vec(),
                outputs: learned,
            }
        }
        Profile::Nbc { .. } => {
            const BITS_FINE_TO_COARSE: [u8; 4] = [1, 2, 4, 8];
            // Bits per finest-grid cell of one channel over the 4 levels: 1 + 2/4 + 4/16 + 8/64.
            let per_channel = 1.875;
            let (mut divisor, mut c) = (4u32, 0usize);
            for d in [4u32, 2, 1] {
                divisor = d;
                c = (budget * f64::from(d * d) / per_channel).floor() as usize;
                if c <= 16 {
                    break;
                }
            }
            let c = c.clamp(1, 16);
            let level_count = (mip_count as usize).min(4);
            let grids: Vec<GridCfg> = (0..level_count)
                .map(|l| GridCfg {
                    width: scaled((width >> l).max(1), divisor),
                    height: scaled((height >> l).max(1), divisor),
                    channels: c,
                    bits: BITS_FINE_TO_COARSE[l],
                })
                .collect();
            let levels = (0..level_count)
                .map(|l| {
                    let fused: Vec<usize> = (l..level_count).collect();
                    let coarser =
                        if l + 1 < level_count { fused[1..].to_vec() } else { fused.clone() };
                    vec![
                        TermCfg { mode: TermMode::Bilinear, grids: fused },
                        TermCfg { mode: TermMode::Bilinear, grids: coarser },
                    ]
                })
                .collect();
            ModelConfig {
                profile: profile.name(),
                grids,
                levels,
                mip_to_level: (0..mip_count)
                    .map(|m| (m as usize).min(level_count - 1) as u8)
                    .collect(),
                pe_frequencies: 2,
                lod_input: true,
                hidden: HIDDEN.to_vec(),
                outputs: learned,
            }
        }
    }
}
