//! Which channels of a material go into which BC texture ([`BcTexture`]), and the default choice
//! from the channels' meanings ([`default_layout`]).

use crate::limits::MAX_CHANNELS;
use crate::material::{Channel, ColorSpace, Material, Semantic};

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
}

impl BcFormat {
    /// Bytes per 4×4 block.
    pub fn block_bytes(self) -> usize {
        match self {
            BcFormat::Bc1 | BcFormat::Bc4 => 8,
            BcFormat::Bc5 => 16,
        }
    }

    /// Channels a texture of this format holds.
    pub fn components(self) -> usize {
        match self {
            BcFormat::Bc1 => 3,
            BcFormat::Bc4 => 1,
            BcFormat::Bc5 => 2,
        }
    }

    /// Short lowercase name (`bc1`, …) for file names and logs.
    pub fn name(self) -> &'static str {
        match self {
            BcFormat::Bc1 => "bc1",
            BcFormat::Bc4 => "bc4",
            BcFormat::Bc5 => "bc5",
        }
    }
}

/// One BC texture made from a material: its format, the material channels of its components
/// (R, G, B in order; `format.components()` of them are used), and whether the engine should
/// sample it as sRGB (BC1 of sRGB colour: `BC1_UNORM_SRGB`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BcTexture {
    pub format: BcFormat,
    pub channels: [u8; 3],
    pub srgb: bool,
}

impl BcTexture {
    /// The material channels this texture reads.
    pub fn channel_list(&self) -> &[u8] {
        self.channels.get(..self.format.components()).unwrap_or(&[])
    }
}

/// The textures for a material's maps, chosen from the channels' meanings. A map is a run of
/// channels with the same semantic and components 0, 1, 2, …; each becomes:
/// - a normal map (X, Y[, Z]) → BC5 of X and Y (Z = √(1 − X² − Y²) in the shader, as usual);
/// - three components (albedo, emissive, specular colour, packed maps) → BC1, sRGB if stored so;
///   a fourth (alpha, …) → its own BC4;
/// - two components of another kind → BC5; one → BC4.
///
/// Every channel of the material lands in exactly one texture, in channel order — except a normal
/// map's Z, which the shader reconstructs.
pub fn default_layout(material: &Material<'_>) -> heapless::Vec<BcTexture, MAX_CHANNELS> {
    layout_of(material.channels())
}

fn layout_of(channels: &[Channel<'_>]) -> heapless::Vec<BcTexture, MAX_CHANNELS> {
    let mut out = heapless::Vec::new();
    let mut first = 0;
    while first < channels.len() {
        let Some(head) = channels.get(first) else { break };
        // The map: following channels of the same semantic with the next component numbers.
        let len = channels
            .iter()
            .skip(first)
            .enumerate()
            .take_while(|(k, c)| {
                c.semantic == head.semantic
                    && usize::from(c.component) == usize::from(head.component) + k
            })
            .count()
            .max(1);
        let at = |k: usize| (first + k) as u8;
        let texture = |format, channels, srgb| BcTexture { format, channels, srgb };
        let srgb = head.color_space == ColorSpace::Srgb;
        let picked: heapless::Vec<BcTexture, 2> = match len {
            1 => [texture(BcFormat::Bc4, [at(0), 0, 0], false)].into_iter().collect(),
            2 => [texture(BcFormat::Bc5, [at(0), at(1), 0], false)].into_iter().collect(),
            _ if head.semantic == Semantic::NORMAL => {
                // X and Y; a fourth component, if any, on its own.
                let mut v: heapless::Vec<BcTexture, 2> =
                    [texture(BcFormat::Bc5, [at(0), at(1), 0], false)].into_iter().collect();
                if len > 3 {
                    let _ = v.push(texture(BcFormat::Bc4, [at(3), 0, 0], false));
                }
                v
            }
            3 => [texture(BcFormat::Bc1, [at(0), at(1), at(2)], srgb)].into_iter().collect(),
            _ => [
                texture(BcFormat::Bc1, [at(0), at(1), at(2)], srgb),
                texture(BcFormat::Bc4, [at(3), 0, 0], false),
            ]
            .into_iter()
            .collect(),
        };
        for t in picked {
            let _ = out.push(t);
        }
        // A map of more than 4 components: the rest starts a new map.
        first += len.min(4);
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
        let got = layout_of(&channels);
        let want = [
            BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2], srgb: true },
            BcTexture { format: BcFormat::Bc5, channels: [3, 4, 0], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [6, 0, 0], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [7, 0, 0], srgb: false },
            BcTexture { format: BcFormat::Bc4, channels: [8, 0, 0], srgb: false },
            BcTexture { format: BcFormat::Bc5, channels: [9, 10, 0], srgb: false },
        ];
        assert_eq!(got.as_slice(), &want);
    }

    /// Albedo with alpha: BC1 of the colour and BC4 of the alpha; two gray maps of the same
    /// semantic in a row stay separate (each starts at component 0).
    #[test]
    fn alpha_and_repeated_maps() {
        let channels = [
            ch(Semantic::ALBEDO, 0, true),
            ch(Semantic::ALBEDO, 1, true),
            ch(Semantic::ALBEDO, 2, true),
            ch(Semantic::ALBEDO, 3, true),
            ch(Semantic::HEIGHT, 0, false),
            ch(Semantic::HEIGHT, 0, false),
        ];
        let got = layout_of(&channels);
        let formats: heapless::Vec<(BcFormat, u8), 8> =
            got.iter().map(|t| (t.format, t.channels[0])).collect();
        assert_eq!(
            formats.as_slice(),
            &[(BcFormat::Bc1, 0), (BcFormat::Bc4, 3), (BcFormat::Bc4, 4), (BcFormat::Bc4, 5)]
        );
        // Every channel exactly once.
        let mut seen = [0u8; 6];
        for t in &got {
            for &c in t.channel_list() {
                seen[usize::from(c)] += 1;
            }
        }
        assert_eq!(seen, [1; 6]);
    }
}
