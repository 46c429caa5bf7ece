//! The scene of `nmat walk` (docs/PERFORMANCE.md, "Tile cache") and what one frame of it
//! measures, shared by the CPU's walk (`commands::walk`) and the GPU's (`gpu::walk`). The scene
//! and the camera path are fixed here, so the numbers reproduce: a box corridor 2 wide, 2.5 high
//! and 40 long, floor, walls, ceiling and end wall each showing one of the materials (in that
//! order, repeating), every texture repeating once per world unit (metre); a camera at eye height
//! 1.6 walking from z = 0.5 to z = 3.5 over the frames — 60 frames (the default) are two seconds
//! at 30 frames per second, a walk at 1.5 m/s — while it looks left and right once (yaw ±0.25
//! rad) and up and down a little, with a 60° vertical field of view. Every pixel is one filtered
//! lookup: trilinear with the mip its screen footprint asks for, or bilinear at mip 0.

use nmat_core::{ChannelMask, Filter, FrameStats, Material, Precision, SampleRequest};
use rayon::prelude::*;
use std::path::PathBuf;

/// What to run.
pub struct Options {
    pub inputs: Vec<PathBuf>,
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub threads: Vec<usize>,
    /// Tiles of the cache.
    pub tiles: usize,
    /// Every how many frames the walk also decodes without the cache (0: never).
    pub direct_every: u32,
    pub mips: Vec<bool>,
    /// Where to write one row per frame and variant.
    pub csv: Option<PathBuf>,
    /// Where to write the last frame (channels 0–2) as a PNG.
    pub image: Option<PathBuf>,
    /// Also walk with the GPU's tile cache (`nmat_wgpu::GpuTileCache`; the `gpu` feature).
    pub gpu: bool,
    /// Bytes the walk may hold (`--max-memory`): a larger cache or frame is refused first.
    pub max_memory: u64,
}

/// The corridor: x ∈ [−1, 1], y ∈ [0, 2.5], z ∈ [0, 40].
const HALF_WIDTH: f32 = 1.0;
const HEIGHT: f32 = 2.5;
const LENGTH: f32 = 40.0;

/// One pixel's lookup: material, (u, v) and the mip its footprint asks for.
#[derive(Clone, Copy, Default)]
pub struct Lookup {
    pub material: u8,
    pub u: f32,
    pub v: f32,
    pub lod: f32,
}

/// The camera of frame `f` of `frames`: position, and the forward, right and up axes.
fn camera(f: u32, frames: u32) -> ([f32; 3], [[f32; 3]; 3]) {
    let t = if frames > 1 { f as f32 / (frames - 1) as f32 } else { 0.0 };
    let tau = std::f32::consts::TAU;
    let yaw = 0.25 * (tau * t).sin();
    let pitch = -0.1 + 0.05 * (2.0 * tau * t).sin();
    let forward = [yaw.sin() * pitch.cos(), pitch.sin(), yaw.cos() * pitch.cos()];
    let right = [yaw.cos(), 0.0, -yaw.sin()];
    let up = cross(forward, right);
    ([0.0, 1.6, 0.5 + 3.0 * t], [forward, right, up])
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// The surface a ray from `o` along `d` leaves the corridor through: (surface, axis of its plane,
/// plane coordinate). Surfaces: 0 floor, 1 walls, 2 ceiling, 3 the two end walls.
fn exit(o: [f32; 3], d: [f32; 3]) -> (u8, usize, f32) {
    let planes = [
        (0u8, 1usize, 0.0f32),
        (2, 1, HEIGHT),
        (1, 0, -HALF_WIDTH),
        (1, 0, HALF_WIDTH),
        (3, 2, 0.0),
        (3, 2, LENGTH),
    ];
    let mut best = (f32::INFINITY, planes[0]);
    for p in planes {
        let t = (p.2 - o[p.1]) / d[p.1];
        if t > 0.0 && t < best.0 {
            best = (t, p);
        }
    }
    best.1
}

/// Texture coordinates where the ray from `o` along `d` meets plane `axis = value`.
fn uv_on(o: [f32; 3], d: [f32; 3], axis: usize, value: f32) -> [f32; 2] {
    let t = (value - o[axis]) / d[axis];
    let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
    match axis {
        1 => [p[0], p[2]],
        0 => [p[2], p[1]],
        _ => [p[0], p[1]],
    }
}

/// Every pixel's lookup for frame `f` (the G-buffer a renderer would have).
pub fn gbuffer(opts: &Options, materials: &[Material<'_>], f: u32, mips: bool) -> Vec<Lookup> {
    let (o, [fw, rt, up]) = camera(f, opts.frames);
    let (w, h) = (opts.width as f32, opts.height as f32);
    let tan = (30f32).to_radians().tan();
    let ray = |px: f32, py: f32| {
        let sx = (2.0 * px / w - 1.0) * tan * w / h;
        let sy = (1.0 - 2.0 * py / h) * tan;
        [0, 1, 2].map(|k| fw[k] + sx * rt[k] + sy * up[k])
    };
    (0..opts.height * opts.width)
        .into_par_iter()
        .map(|i| {
            let (px, py) = ((i % opts.width) as f32 + 0.5, (i / opts.width) as f32 + 0.5);
            let d = ray(px, py);
            let (surface, axis, value) = exit(o, d);
            let material = usize::from(surface) % materials.len();
            let [u, v] = uv_on(o, d, axis, value);
            let lod = if mips {
                // The footprint of one pixel in texels, from the neighbours' rays on this plane.
                let size = materials[material].width() as f32;
                let [ux, vx] = uv_on(o, ray(px + 1.0, py), axis, value);
                let [uy, vy] = uv_on(o, ray(px, py + 1.0), axis, value);
                let dx = ((ux - u).powi(2) + (vx - v).powi(2)).sqrt() * size;
                let dy = ((uy - u).powi(2) + (vy - v).powi(2)).sqrt() * size;
                dx.max(dy).max(1e-6).log2()
            } else {
                0.0
            };
            Lookup { material: material as u8, u, v, lod }
        })
        .collect()
}

/// The sample request of a lookup: trilinear with mips, bilinear at mip 0 without; channels
/// 0–2.
pub fn request(l: &Lookup, mips: bool) -> SampleRequest {
    SampleRequest {
        u: l.u,
        v: l.v,
        lod: l.lod,
        filter: if mips { Filter::Trilinear } else { Filter::Bilinear },
        precision: Precision::Integer,
        random: [0.0; 3],
        channels: ChannelMask(0b111),
    }
}

/// One frame's measurements.
pub struct Row {
    pub stats: FrameStats,
    /// Marking, decoding, resolving (on the GPU between timestamps; none on the wall clock).
    pub stages: Option<[f64; 3]>,
    /// The frame with the cache: the stages' sum.
    pub cached_ms: f64,
    pub direct_ms: Option<f64>,
    pub identical: Option<bool>,
}
