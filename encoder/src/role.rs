//! What a map is (albedo, normal, …): its channels' meaning and colour space in the material.

use nmat_core::{ColorSpace, Semantic};

/// What a map is. The order here is the order of the material's channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    Albedo,
    Normal,
    Roughness,
    Gloss,
    Specular,
    Height,
    Ao,
    Metallic,
    Emissive,
    Opacity,
}

impl Role {
    pub const ALL: [Role; 10] = [
        Role::Albedo,
        Role::Normal,
        Role::Roughness,
        Role::Gloss,
        Role::Specular,
        Role::Height,
        Role::Ao,
        Role::Metallic,
        Role::Emissive,
        Role::Opacity,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Role::Albedo => "albedo",
            Role::Normal => "normal",
            Role::Roughness => "roughness",
            Role::Gloss => "gloss",
            Role::Specular => "specular",
            Role::Height => "height",
            Role::Ao => "ao",
            Role::Metallic => "metallic",
            Role::Emissive => "emissive",
            Role::Opacity => "opacity",
        }
    }

    pub fn semantic(self) -> Semantic {
        match self {
            Role::Albedo => Semantic::ALBEDO,
            Role::Normal => Semantic::NORMAL,
            Role::Roughness => Semantic::ROUGHNESS,
            Role::Gloss => Semantic::GLOSS,
            Role::Specular => Semantic::SPECULAR,
            Role::Height => Semantic::HEIGHT,
            Role::Ao => Semantic::AMBIENT_OCCLUSION,
            Role::Metallic => Semantic::METALLIC,
            Role::Emissive => Semantic::EMISSIVE,
            Role::Opacity => Semantic::OPACITY,
        }
    }

    pub fn from_semantic(s: Semantic) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.semantic() == s)
    }

    /// Colour maps are stored sRGB-encoded, data maps linear (the usual engine convention).
    pub fn color_space(self) -> ColorSpace {
        match self {
            Role::Albedo | Role::Emissive | Role::Specular => ColorSpace::Srgb,
            _ => ColorSpace::Linear,
        }
    }

    /// The value range a unit value of component `component` maps to: a normal's X, Y, Z are
    /// signed, everything else (an alpha included) is [0, 1].
    pub fn nominal_range(self, component: u8) -> (f32, f32) {
        if self == Role::Normal && component < 3 { (-1.0, 1.0) } else { (0.0, 1.0) }
    }

    pub fn parse(text: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.name() == text.to_ascii_lowercase())
    }
}
