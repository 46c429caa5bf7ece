//! What every material has, whatever its codec: its channels (name, meaning, colour space,
//! range), how coordinates outside the image are addressed, and its mips' sizes. Below the
//! codecs: the material, the JPEG section and the latent grids all read these.

use crate::bytes::{f32_at, u8_at};

/// How texel and grid coordinates outside the image are brought back in (FORMAT.md §6.1).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AddressMode {
    /// `x mod size`: tiling materials.
    Wrap = 0,
    /// `min(max(x, 0), size - 1)`: decals, atlases.
    Clamp = 1,
}

/// What a channel means. Descriptive only: an unknown value is kept, not rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Semantic(pub u8);

impl Semantic {
    pub const UNKNOWN: Semantic = Semantic(0);
    pub const ALBEDO: Semantic = Semantic(1);
    pub const NORMAL: Semantic = Semantic(2);
    pub const ROUGHNESS: Semantic = Semantic(3);
    pub const GLOSS: Semantic = Semantic(4);
    pub const HEIGHT: Semantic = Semantic(5);
    pub const AMBIENT_OCCLUSION: Semantic = Semantic(6);
    pub const METALLIC: Semantic = Semantic(7);
    pub const EMISSIVE: Semantic = Semantic(8);
    pub const OPACITY: Semantic = Semantic(9);
    pub const SPECULAR: Semantic = Semantic(10);
}

/// Colour space of a channel's values (FORMAT.md §3). Decoding returns stored values; converting
/// sRGB to linear is the renderer's business, as with any sRGB texture.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorSpace {
    Linear = 0,
    Srgb = 1,
}

/// One output channel of the material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Channel<'a> {
    pub name: &'a str,
    pub semantic: Semantic,
    /// Which component of a multi-channel map this is (0 = R/X, 1 = G/Y, …).
    pub component: u8,
    pub color_space: ColorSpace,
    /// Decoded value = `range_min + unit · (range_max - range_min)`, unit ∈ [0, 1].
    pub range_min: f32,
    pub range_max: f32,
}

impl Channel<'_> {
    /// The usual range of this channel's values in image files: [−1, 1] for the X, Y and Z of a
    /// normal map (stored as `(n + 1)/2`), [0, 1] for everything else.
    pub fn nominal_range(&self) -> (f32, f32) {
        if self.semantic == Semantic::NORMAL && self.component < 3 {
            (-1.0, 1.0)
        } else {
            (0.0, 1.0)
        }
    }

    /// For a constant channel (`range_min == range_max`, nothing decoded), the 8-bit code of its
    /// value in [`Channel::nominal_range`] (clamped), as an image or a transcoded texture holds it;
    /// `None` for a decoded channel, whose 8-bit codes are its units.
    pub fn constant_code(&self) -> Option<u8> {
        if self.range_min != self.range_max {
            return None;
        }
        let (lo, hi) = self.nominal_range();
        let unit = ((self.range_min - lo) / (hi - lo)).clamp(0.0, 1.0);
        Some(libm::roundf(unit * 255.0) as u8)
    }
}

/// Size of `mip` of a `width` × `height` chain of `mip_count` mips (clamped to the chain).
pub(crate) fn mip_size(width: u32, height: u32, mip_count: u8, mip: u32) -> (u32, u32) {
    let m = mip.min(u32::from(mip_count).saturating_sub(1));
    ((width >> m).max(1), (height >> m).max(1))
}

/// Reads channel `i` of a 32-byte channel record (FORMAT.md §3).
pub(crate) fn channel_range(rec: &[u8]) -> (f32, f32) {
    (f32_at(rec, 20), f32_at(rec, 24))
}

/// The name bytes of a channel record, up to the first NUL.
pub(crate) fn channel_name_bytes(rec: &[u8]) -> &[u8] {
    let name = rec.get(..16).unwrap_or(&[]);
    let end = name.iter().position(|&b| b == 0).unwrap_or(name.len());
    name.get(..end).unwrap_or(&[])
}

pub(crate) fn channel_codes(rec: &[u8]) -> (u8, u8, u8, u8) {
    (u8_at(rec, 16), u8_at(rec, 17), u8_at(rec, 18), u8_at(rec, 19))
}
