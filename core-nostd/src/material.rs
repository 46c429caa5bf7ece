//! The parsed, validated material: borrowed views into the file plus small fixed-size
//! descriptors. Built only by `Container::parse`, so every value here is within the limits of
//! docs/FORMAT.md and decoding it cannot fail or panic.

use crate::format::channel::{AddressMode, Channel, mip_size};
use crate::limits::{
    MAX_CHAIN, MAX_CHANNELS, MAX_GRIDS, MAX_LAYERS, MAX_LEVELS, MAX_MIPS, MAX_TERMS,
};
use crate::neural::latents::LatentGrid;
use crate::neural::mlp::Layer;

/// How a term of a feature level reads its grids (FORMAT.md §6.3).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TermMode {
    /// The 4 nearest cells of one grid, concatenated (NTC's high-resolution grid): 4·c features.
    Nearest4 = 0,
    /// Bilinear samples of a chain of grids, summed (NTC's low-resolution grid when the chain has
    /// one grid; NBC's residual fusion when it has several): c features.
    Bilinear = 1,
}

/// One sampling term: a mode and the grids it reads (a chain of one for `Nearest4`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Term {
    pub mode: TermMode,
    pub grids: heapless::Vec<u8, MAX_CHAIN>,
}

/// The sampling graph of one feature level: its terms, in input order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FeatureLevel {
    pub terms: heapless::Vec<Term, MAX_TERMS>,
}

/// How a material stores its texels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Codec {
    /// Latent grids and an MLP (FORMAT.md §2–§6).
    Neural,
    /// Indexed baseline JPEG streams, one per map and mip (FORMAT.md §11).
    Jpeg,
}

/// The decoder network (FORMAT.md §5).
#[derive(Clone, Debug)]
pub struct Mlp<'a> {
    pub(crate) input_frac_bits: u8,
    pub(crate) pe_frequencies: u8,
    /// 0: no LOD feature; 1: `mip / 16`; 2–5: `mip · 2^(lod_input − 5)` (FORMAT.md §6.5).
    pub(crate) lod_input: u8,
    pub(crate) input_width: u16,
    pub(crate) layers: heapless::Vec<Layer<'a>, MAX_LAYERS>,
}

impl<'a> Mlp<'a> {
    /// Fraction bits of the input vector's Q-format (latents, positional encoding, LOD).
    pub fn input_frac_bits(&self) -> u8 {
        self.input_frac_bits
    }
    /// Number of triangle-wave frequencies of the positional encoding (4 features each).
    pub fn pe_frequencies(&self) -> u8 {
        self.pe_frequencies
    }
    /// Whether the mip level is an input feature.
    pub fn lod_input(&self) -> bool {
        self.lod_input != 0
    }
    /// The file's `lod_input` code (FORMAT.md §5.3): 0 no LOD feature, 1 `mip / 16`, 2–5
    /// `mip · 2^(code − 5)` (format 2.3).
    pub fn lod_code(&self) -> u8 {
        self.lod_input
    }
    /// The LOD feature of `mip`, a mip of the chain (decoders clamp it first), in the input's
    /// Q-format (`None` without one): `mip · 2^(code − 5)`, `mip / 16` for code 1; exact, and
    /// parsing guarantees it fits an i16 for every mip a file can have.
    pub fn lod_feature(&self, mip: u32) -> Option<i32> {
        // f ≥ 4 and code ≥ 1: the shift is never negative.
        let code = u32::from(self.lod_input).checked_sub(1)?;
        Some((mip << (u32::from(self.input_frac_bits) + code - 4)) as i32)
    }
    /// Number of input features.
    pub fn input_width(&self) -> usize {
        usize::from(self.input_width)
    }
    pub fn layers(&self) -> &[Layer<'a>] {
        &self.layers
    }
    /// Multiply-adds per texel with all outputs (the cost model of the benchmarks).
    pub fn macs_per_texel(&self) -> usize {
        self.layers.iter().map(|l| l.inputs() * l.outputs()).sum()
    }
}

/// What a material's texels are stored as: its codec's own data, matched once where a decode
/// starts.
#[derive(Clone, Debug)]
// Inline, not boxed: the core parses without an allocator, and a material is made once per file.
#[allow(clippy::large_enum_variant)]
pub enum Body<'a> {
    /// Latent grids and the network that decodes them (FORMAT.md §2–§6).
    Neural(Neural<'a>),
    /// Indexed baseline JPEG streams, one per map and mip (FORMAT.md §11).
    Jpeg(crate::jpeg::Jpeg<'a>),
}

impl<'a> Body<'a> {
    /// The codec of this body.
    pub fn codec(&self) -> Codec {
        match self {
            Body::Neural(_) => Codec::Neural,
            Body::Jpeg(_) => Codec::Jpeg,
        }
    }
}

/// A neural material's model: its latent grids, the feature levels that sample them, the
/// network, and the level of each mip.
#[derive(Clone, Debug)]
pub struct Neural<'a> {
    pub(crate) mip_count: u8,
    pub(crate) mip_to_level: [u8; MAX_MIPS],
    pub(crate) grids: heapless::Vec<LatentGrid<'a>, MAX_GRIDS>,
    pub(crate) levels: heapless::Vec<FeatureLevel, MAX_LEVELS>,
    pub(crate) mlp: Mlp<'a>,
}

impl<'a> Neural<'a> {
    /// The feature level that decodes `mip` (clamped to the chain).
    pub fn level_for_mip(&self, mip: u32) -> usize {
        let m = mip.min(u32::from(self.mip_count).saturating_sub(1)) as usize;
        usize::from(self.mip_to_level.get(m).copied().unwrap_or(0))
    }
    pub fn levels(&self) -> &[FeatureLevel] {
        &self.levels
    }
    pub fn grids(&self) -> &[LatentGrid<'a>] {
        &self.grids
    }
    pub fn mlp(&self) -> &Mlp<'a> {
        &self.mlp
    }
    /// Fraction bits of the network's outputs (those of its last layer).
    pub(crate) fn last_frac_bits(&self) -> u32 {
        self.mlp.layers.last().map_or(1, |l| u32::from(l.out_frac_bits))
    }
}

/// What [`Material::decode_cost`] reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecodeCost {
    /// Texels of the mip.
    pub texels: u64,
    /// Multiply-adds of the network over those texels (all outputs); divide by a kernel's
    /// measured rate (`nmat bench`) for the time.
    pub macs: u64,
}

/// A parsed `.nmat` material. Cheap to copy around by reference; immutable, so one instance can be
/// decoded from many threads at once.
#[derive(Clone, Debug)]
pub struct Material<'a> {
    pub(crate) version_major: u16,
    pub(crate) version_minor: u16,
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) mip_count: u8,
    pub(crate) address_mode: AddressMode,
    pub(crate) channels: heapless::Vec<Channel<'a>, MAX_CHANNELS>,
    pub(crate) body: Body<'a>,
    pub(crate) file_len: usize,
    /// Lengths of the MATERIAL, LEVELS, MLP, LATENTS and JPEG sections (0: absent).
    pub(crate) section_lens: [usize; 5],
    pub(crate) optional_sections:
        heapless::Vec<(crate::SectionKind, &'a [u8]), { crate::limits::MAX_SECTIONS }>,
}

impl<'a> Material<'a> {
    /// Major format version of the file: [`crate::VERSION_MAJOR`], or 1 for a file written before
    /// the network was stored once (read all the same, FORMAT.md §10).
    pub fn version_major(&self) -> u16 {
        self.version_major
    }
    /// Minor format version of the file (readers accept any minor of a major they know).
    pub fn version_minor(&self) -> u16 {
        self.version_minor
    }
    /// Width of mip 0 in texels.
    pub fn width(&self) -> u32 {
        self.width
    }
    /// Height of mip 0 in texels.
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn mip_count(&self) -> u32 {
        u32::from(self.mip_count)
    }
    /// Size of `mip` (clamped to the chain): `max(1, size >> mip)` on each axis.
    pub fn mip_size(&self, mip: u32) -> (u32, u32) {
        mip_size(self.width, self.height, self.mip_count, mip)
    }
    pub fn address_mode(&self) -> AddressMode {
        self.address_mode
    }
    pub fn channel_count(&self) -> usize {
        self.channels.len()
    }
    pub fn channels(&self) -> &[Channel<'a>] {
        &self.channels
    }
    /// How this material stores its texels. Every decode call works for both codecs.
    pub fn codec(&self) -> Codec {
        self.body.codec()
    }
    /// The codec's data: the model of a neural material, the section of a JPEG one.
    pub fn body(&self) -> &Body<'a> {
        &self.body
    }
    /// The model of a neural material.
    pub fn neural(&self) -> Option<&Neural<'a>> {
        match &self.body {
            Body::Neural(n) => Some(n),
            Body::Jpeg(_) => None,
        }
    }
    /// The JPEG section of a JPEG material.
    pub fn jpeg(&self) -> Option<&crate::jpeg::Jpeg<'a>> {
        match &self.body {
            Body::Jpeg(j) => Some(j),
            Body::Neural(_) => None,
        }
    }
    /// Size of the file this material was parsed from, in bytes.
    pub fn file_len(&self) -> usize {
        self.file_len
    }
    /// Length in bytes of a section of the file (a required one, or an optional one it has).
    pub fn section_len(&self, kind: crate::SectionKind) -> Option<usize> {
        let required = crate::SectionKind::KNOWN.iter().position(|&k| k == kind);
        match required {
            Some(i) => self.section_lens.get(i).copied().filter(|&n| n > 0 || i == 0),
            None => self.optional_section(kind).map(<[u8]>::len),
        }
    }

    /// The bytes of an optional section (one without the REQUIRED flag and of a kind the decoder
    /// does not need, FORMAT.md §1.3 and §9), if the file has one of that kind.
    pub fn optional_section(&self, kind: crate::SectionKind) -> Option<&'a [u8]> {
        self.optional_sections.iter().find(|(k, _)| *k == kind).map(|(_, d)| *d)
    }

    /// Every optional section, in file order.
    pub fn optional_sections(&self) -> &[(crate::SectionKind, &'a [u8])] {
        &self.optional_sections
    }

    /// The work of decoding every texel of `mip` (clamped to the chain) once, all channels at
    /// a time: know it before a large decode (a small file may declare a 16384² chain).
    pub fn decode_cost(&self, mip: u32) -> DecodeCost {
        let (w, h) = self.mip_size(mip);
        let texels = u64::from(w) * u64::from(h);
        let per_texel = self.neural().map_or(0, |n| n.mlp.macs_per_texel());
        DecodeCost { texels, macs: texels * per_texel as u64 }
    }

    /// Channels that carry information: all but those whose range is one value (a constant
    /// map costs nothing and decodes to that value whatever the network says); at least 1.
    pub fn informative_channels(&self) -> usize {
        self.channels.iter().filter(|c| c.range_min < c.range_max).count().max(1)
    }

    /// Bits per pixel per channel of this (fixed-rate) file: [`Material::bppc_of`] its length.
    pub fn bppc(&self) -> f64 {
        self.bppc_of(self.file_len)
    }

    /// Bits per pixel per channel of a file of `file_bytes` bytes holding this material (e.g.
    /// the packed file it was unpacked from): file bits / (width · height · informative
    /// channels) of mip 0.
    pub fn bppc_of(&self, file_bytes: usize) -> f64 {
        let denom =
            f64::from(self.width) * f64::from(self.height) * self.informative_channels() as f64;
        (file_bytes as f64 * 8.0) / denom
    }
}
