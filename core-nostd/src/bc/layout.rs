//! Which channels of a material go into which BC texture ([`BcTexture`]), and the default choice
//! from the channels' meanings ([`default_layout`]).

use crate::format::channel::{Channel, ColorSpace, Semantic};
use crate::limits::MAX_CHANNELS;
use crate::material::Material;

/// A BC format the core encodes.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BcFormat {
    /// RGB, 8 bytes per 4×4 block.
    Bc1,
    /// One channel, 8 bytes per block.
    Bc4,
    /// Two channels, 16 bytes per block.
    Bc5,
    /// RGB in BC7 (every pixel decodes with alpha 255), 16 bytes per block.
    Bc7Rgb,
    /// RGBA in BC7, 16 bytes per block.
    Bc7Rgba,
}

impl BcFormat {
    /// Bytes per 4×4 block.
    pub fn block_bytes(self) -> usize {
        match self {
            BcFormat::Bc1 | BcFormat::Bc4 => 8,
            BcFormat::Bc5 | BcFormat::Bc7Rgb | BcFormat::Bc7Rgba => 16,
        }
    }

    /// Channels a texture of this format holds.
    pub fn components(self) -> usize {
        match self {
            BcFormat::Bc4 => 1,
            BcFormat::Bc5 => 2,
            BcFormat::Bc1 | BcFormat::Bc7Rgb => 3,
            BcFormat::Bc7Rgba => 4,
        }
    }

    /// Short lowercase name (`bc1`, …, `bc7`) for file names and logs; both BC7 forms are `bc7`
    /// (the GPU format is the same).
    pub fn name(self) -> &'static str {
        match self {
            BcFormat::Bc1 => "bc1",
            BcFormat::Bc4 => "bc4",
            BcFormat::Bc5 => "bc5",
            BcFormat::Bc7Rgb | BcFormat::Bc7Rgba => "bc7",
        }
    }

    /// Whether the GPU may sample it as sRGB (`*_UNORM_SRGB` formats exist for BC1 and BC7).
    pub fn has_srgb(self) -> bool {
        matches!(self, BcFormat::Bc1 | BcFormat::Bc7Rgb | BcFormat::Bc7Rgba)
    }
}

/// One BC texture made from a material: its format, the material channels of its components
/// (R, G, B, A in order; the first `format.components()` are used, repeats allowed, e.g. a gray
/// map as BC1 is `[c, c, c, _]`), and whether the engine should sample it as sRGB
/// (`BC1_UNORM_SRGB`, `BC7_UNORM_SRGB`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BcTexture {
    pub format: BcFormat,
    pub channels: [u8; 4],
    pub srgb: bool,
}

impl BcTexture {
    /// The material channels this texture reads.
    pub fn channel_list(&self) -> &[u8] {
        self.channels.get(..self.format.components()).unwrap_or(&[])
    }
}

/// A map of a material: a run of channels with the same semantic and components 0, 1, 2, …
/// (at most 4; a longer run continues as the next map).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MapChannels {
    pub semantic: Semantic,
    /// The first channel and how many follow.
    pub first: u8,
    pub count: u8,
    /// Stored as sRGB (its first channel is).
    pub srgb: bool,
}

/// The material's maps, in channel order (every channel in exactly one).
pub fn maps(material: &Material<'_>) -> heapless::Vec<MapChannels, MAX_CHANNELS> {
    maps_of(material.channels())
}

fn maps_of(channels: &[Channel<'_>]) -> heapless::Vec<MapChannels, MAX_CHANNELS> {
    let mut out = heapless::Vec::new();
    let mut first = 0;
    while let Some(head) = channels.get(first) {
        let count = channels
            .iter()
            .skip(first)
            .enumerate()
            .take_while(|(k, c)| {
                c.semantic == head.semantic
                    && usize::from(c.component) == usize::from(head.component) + k
            })
            .count()
            .clamp(1, 4);
        let _ = out.push(MapChannels {
            semantic: head.semantic,
            first: first as u8,
            count: count as u8,
            srgb: head.color_space == ColorSpace::Srgb,
        });
        first += count;
    }
    out
}

/// The textures for a material's maps, chosen from the channels' meanings ([`auto_textures`]
/// for every map): albedo → BC1 (sRGB), normal → BC5 of X and Y, single maps → BC4, two
/// components → BC5, alpha → its own BC4.
pub fn default_layout(material: &Material<'_>) -> heapless::Vec<BcTexture, MAX_CHANNELS> {
    layout_with(material, |_| None)
}

/// The textures for a material's maps, each map in the format `format_of` returns for it
/// ([`textures_in`]), or chosen from its meaning where it returns `None` ([`auto_textures`]).
pub fn layout_with(
    material: &Material<'_>,
    format_of: impl Fn(&MapChannels) -> Option<BcFormat>,
) -> heapless::Vec<BcTexture, MAX_CHANNELS> {
    layout_of(material.channels(), format_of)
}

fn layout_of(
    channels: &[Channel<'_>],
    format_of: impl Fn(&MapChannels) -> Option<BcFormat>,
) -> heapless::Vec<BcTexture, MAX_CHANNELS> {
    let mut out = heapless::Vec::new();
    for map in maps_of(channels) {
        let textures = match format_of(&map) {
            Some(format) => textures_in(&map, format),
            None => auto_textures(&map),
        };
        for t in textures {
            let _ = out.push(t);
        }
    }
    out
}

/// The default textures of one map:
/// - a normal map (X, Y[, Z]) → BC5 of X and Y (Z = √(1 − X² − Y²) in the shader, as usual);
///   a fourth component → its own BC4;
/// - three components (albedo, emissive, specular colour, packed maps) → BC1, sRGB if stored so;
///   a fourth (alpha, …) → its own BC4;
/// - two components of another kind → BC5; one → BC4.
pub fn auto_textures(map: &MapChannels) -> heapless::Vec<BcTexture, 4> {
    let at = |k: u8| map.first + k.min(map.count.saturating_sub(1));
    let texture = |format, channels, srgb| BcTexture { format, channels, srgb };
    let mut v = heapless::Vec::new();
    let (first, second) = match map.count {
        1 => (texture(BcFormat::Bc4, [at(0); 4], false), None),
        2 => (texture(BcFormat::Bc5, [at(0), at(1), at(1), at(1)], false), None),
        n if map.semantic == Semantic::NORMAL => (
            texture(BcFormat::Bc5, [at(0), at(1), at(1), at(1)], false),
            (n > 3).then(|| texture(BcFormat::Bc4, [at(3); 4], false)),
        ),
        n => (
            texture(BcFormat::Bc1, [at(0), at(1), at(2), at(2)], map.srgb),
            (n > 3).then(|| texture(BcFormat::Bc4, [at(3); 4], false)),
        ),
    };
    let _ = v.push(first);
    if let Some(t) = second {
        let _ = v.push(t);
    }
    v
}

/// One map in `format`: its channels in groups of `format.components()` (BC7: up to 4, RGBA for
/// a group of 4, else RGB), a last short group repeating its last channel (a gray map in BC1 is
/// gray). A normal map's Z is left out when the format holds fewer than three components (the
/// shader reconstructs it). sRGB when the map is stored so and the format has an sRGB form.
pub fn textures_in(map: &MapChannels, format: BcFormat) -> heapless::Vec<BcTexture, 4> {
    let mut channels: heapless::Vec<u8, 4> = (map.first..map.first + map.count).collect();
    let per = if matches!(format, BcFormat::Bc7Rgb | BcFormat::Bc7Rgba) {
        4
    } else {
        format.components()
    };
    if map.semantic == Semantic::NORMAL && map.count >= 3 && per < 3 {
        channels.remove(2);
    }
    let mut out = heapless::Vec::new();
    for group in channels.chunks(per) {
        let format = match format {
            BcFormat::Bc7Rgb | BcFormat::Bc7Rgba if group.len() == 4 => BcFormat::Bc7Rgba,
            BcFormat::Bc7Rgb | BcFormat::Bc7Rgba => BcFormat::Bc7Rgb,
            f => f,
        };
        let last = group.last().copied().unwrap_or(map.first);
        let picked = core::array::from_fn(|k| group.get(k).copied().unwrap_or(last));
        let srgb = map.srgb && format.has_srgb();
        let _ = out.push(BcTexture { format, channels: picked, srgb });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(semantic: Semantic, component: u8, srgb: bool) -> Channel<'static> {
        Channel {
            name: "c",
            semantic,
            component,
            color_space: if srgb { ColorSpace::Srgb } else { ColorSpace::Linear },
            range_min: 0.0,
            range_max: 1.0,
        }
    }

    /// The names in transcoded files' names (`albedo.bc1.ktx2`, docs/TRANSCODING.md): both BC7
    /// forms are `bc7`, one GPU format.
    #[test]
    fn formats_have_the_names_of_their_files() {
        let names = [
            (BcFormat::Bc1, "bc1"),
            (BcFormat::Bc4, "bc4"),
            (BcFormat::Bc5, "bc5"),
            (BcFormat::Bc7Rgb, "bc7"),
            (BcFormat::Bc7Rgba, "bc7"),
        ];
        for (format, name) in names {
            assert_eq!(format.name(), name, "{format:?}");
        }
    }

    #[test]
    fn maps_get_the_usual_formats() {
        let channels = [
            ch(Semantic::ALBEDO, 0, true),
            ch(Semantic::ALBEDO, 1, true),
            ch(Semantic::ALBEDO, 2, true),
            ch(Semantic::NORMAL, 0, false),
            ch(Semantic::NORMAL, 1, false),
            ch(Semantic::NORMAL, 2, false),
            ch(Semantic::GLOSS, 0, false),
            ch(Semantic::HEIGHT, 0, false),
            ch(Semantic::AMBIENT_OCCLUSION, 0, false),
            ch(Semantic::UNKNOWN, 0, false),
            ch(Semantic::UNKNOWN, 1, false),
        ];
        let got = layout_of(&channels, |_| None);
        let want = [
            BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 2], srgb: true },
            BcTexture { format: BcFormat::Bc5, channels: [3, 4, 4, 4], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [6; 4], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [7; 4], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [8; 4], srgb: false },
            BcTexture { format: BcFormat::Bc5, channels: [9, 10, 10, 10], srgb: false },
        ];
        assert_eq!(got.as_slice(), &want);
    }

    /// Albedo with alpha: BC1 of the colour and BC4 of the alpha; two gray maps of the same
    /// semantic in a row stay separate (each starts at component 0); a normal map's fourth
    /// component gets its own BC4 too (after the BC5 of X and Y, Z left to the shader).
    #[test]
    fn alpha_and_repeated_maps() {
        let channels = [
            ch(Semantic::ALBEDO, 0, true),
            ch(Semantic::ALBEDO, 1, true),
            ch(Semantic::ALBEDO, 2, true),
            ch(Semantic::ALBEDO, 3, true),
            ch(Semantic::HEIGHT, 0, false),
            ch(Semantic::HEIGHT, 0, false),
            ch(Semantic::NORMAL, 0, false),
            ch(Semantic::NORMAL, 1, false),
            ch(Semantic::NORMAL, 2, false),
            ch(Semantic::NORMAL, 3, false),
        ];
        let got = layout_of(&channels, |_| None);
        let formats: heapless::Vec<(BcFormat, u8), 8> =
            got.iter().map(|t| (t.format, t.channels[0])).collect();
        assert_eq!(
            formats.as_slice(),
            &[
                (BcFormat::Bc1, 0),
                (BcFormat::Bc4, 3),
                (BcFormat::Bc4, 4),
                (BcFormat::Bc4, 5),
                (BcFormat::Bc5, 6),
                (BcFormat::Bc4, 9)
            ]
        );
        // Every channel exactly once, but the normal map's Z.
        let mut seen = [0u8; 10];
        for t in &got {
            for &c in t.channel_list() {
                seen[usize::from(c)] += 1;
            }
        }
        assert_eq!(seen, [1, 1, 1, 1, 1, 1, 1, 1, 0, 1]);
    }

    /// A chosen format: groups of its component count, short groups repeat their last channel,
    /// a normal map keeps Z only where the format holds three components, sRGB only for
    /// formats that have an sRGB form.
    #[test]
    fn chosen_formats_group_the_channels() {
        let channels = [
            ch(Semantic::ALBEDO, 0, true),
            ch(Semantic::ALBEDO, 1, true),
            ch(Semantic::ALBEDO, 2, true),
            ch(Semantic::ALBEDO, 3, true),
            ch(Semantic::NORMAL, 0, false),
            ch(Semantic::NORMAL, 1, false),
            ch(Semantic::NORMAL, 2, false),
            ch(Semantic::GLOSS, 0, false),
        ];
        let t = |format, channels: [u8; 4], srgb| BcTexture { format, channels, srgb };
        let bc7 = layout_of(&channels, |_| Some(BcFormat::Bc7Rgb));
        assert_eq!(
            bc7.as_slice(),
            &[
                t(BcFormat::Bc7Rgba, [0, 1, 2, 3], true),
                t(BcFormat::Bc7Rgb, [4, 5, 6, 6], false),
                t(BcFormat::Bc7Rgb, [7, 7, 7, 7], false),
            ]
        );
        let bc4 = layout_of(&channels, |_| Some(BcFormat::Bc4));
        let firsts: heapless::Vec<u8, 16> = bc4.iter().map(|t| t.channels[0]).collect();
        assert_eq!(firsts.as_slice(), &[0, 1, 2, 3, 4, 5, 7], "normal Z left out");
        assert!(bc4.iter().all(|t| t.format == BcFormat::Bc4 && !t.srgb));
        let bc1 = layout_of(&channels, |_| Some(BcFormat::Bc1));
        assert_eq!(
            bc1.as_slice(),
            &[
                t(BcFormat::Bc1, [0, 1, 2, 2], true),
                t(BcFormat::Bc1, [3, 3, 3, 3], true),
                t(BcFormat::Bc1, [4, 5, 6, 6], false),
                t(BcFormat::Bc1, [7, 7, 7, 7], false),
            ]
        );
        // Only the albedo chosen; the rest as by default.
        let mixed =
            layout_of(&channels, |m| (m.semantic == Semantic::ALBEDO).then_some(BcFormat::Bc7Rgb));
        let formats: heapless::Vec<BcFormat, 16> = mixed.iter().map(|t| t.format).collect();
        assert_eq!(formats.as_slice(), &[BcFormat::Bc7Rgba, BcFormat::Bc5, BcFormat::Bc4]);
    }
}
