//! What several test files of the encoder share: baseline JPEG files of a texture-like pattern.
// Not every test file uses every helper.
#![allow(dead_code)]

use jpeg_encoder::{ColorType, Encoder, SamplingFactor};

/// A texture-like test image: gradients, a few hard edges and noise.
pub fn pattern(w: u32, h: u32, components: usize, seed: u32) -> Vec<u8> {
    let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    let mut out = Vec::with_capacity((w * h) as usize * components);
    for y in 0..h {
        for x in 0..w {
            for c in 0..components as u32 {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let base = (x * 255 / w.max(1) + y * 97 / h.max(1) + c * 60) % 256;
                let edge = if (x / 5 + y / 7 + c) % 3 == 0 { 70 } else { 0 };
                let noise = state % 24;
                out.push(((base + edge + noise) % 256) as u8);
            }
        }
    }
    out
}

pub fn jpeg(
    w: u32,
    h: u32,
    components: usize,
    sampling: SamplingFactor,
    quality: u8,
    restart: u16,
) -> Vec<u8> {
    let mut out = Vec::new();
    let mut e = Encoder::new(&mut out, quality);
    e.set_sampling_factor(sampling);
    if restart > 0 {
        e.set_restart_interval(restart);
    }
    let color = if components == 1 { ColorType::Luma } else { ColorType::Rgb };
    e.encode(&pattern(w, h, components, w * 31 + h), w as u16, h as u16, color).unwrap();
    out
}

/// Every component layout the JPEG tests cover: gray and each chroma subsampling.
pub const MODES: [(usize, SamplingFactor, &str); 5] = [
    (1, SamplingFactor::F_1_1, "gray"),
    (3, SamplingFactor::R_4_4_4, "4:4:4"),
    (3, SamplingFactor::R_4_2_0, "4:2:0"),
    (3, SamplingFactor::R_4_2_2, "4:2:2"),
    (3, SamplingFactor::R_4_4_0, "4:4:0"),
];
