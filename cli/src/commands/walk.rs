//! `nmat walk`: a headless walk down a textured corridor (docs/PERFORMANCE.md, "Tile cache"),
//! to measure what the tile cache saves a renderer. The scene and the camera path are fixed here,
//! so the numbers reproduce: a box corridor 2 wide, 2.5 high and 40 long, floor, walls, ceiling
//! and end wall each showing one of the materials (in that order, repeating), every texture
//! repeating once per world unit (metre); a camera at eye height 1.6 walking from z = 0.5 to
//! z = 3.5 over the frames — 60 frames (the default) are two seconds at 30 frames per second, a
//! walk at 1.5 m/s — while it looks left and right once (yaw ±0.25 rad) and up and down a little,
//! with a 60° vertical field of view. Every pixel is one filtered lookup: trilinear with the mip its
//! screen footprint asks for, or bilinear at mip 0 (`--no-mips`).

#[cfg(feature = "gpu")]
#[path = "walk_gpu.rs"]
mod gpu;

use crate::Result;
use nmat_core::{
    ChannelMask, Decoder, Filter, FrameStats, Material, Precision, SampleRequest, Slot, TileCache,
    TileKey,
};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

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
struct Lookup {
    material: u8,
    u: f32,
    v: f32,
    lod: f32,
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
fn gbuffer(opts: &Options, materials: &[Material<'_>], f: u32, mips: bool) -> Vec<Lookup> {
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

fn request(l: &Lookup, mips: bool) -> SampleRequest {
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
struct Row {
    stats: FrameStats,
    /// Marking, decoding, resolving (the CPU's stages; the GPU times the frame as a whole).
    stages: Option<[f64; 3]>,
    /// The frame with the cache: the stages' sum.
    cached_ms: f64,
    direct_ms: Option<f64>,
    identical: Option<bool>,
}

pub fn run(opts: &Options) -> Result<()> {
    let files: Vec<Vec<u8>> = opts
        .inputs
        .iter()
        .map(|p| nmat_cli::input::read_nmat(p).map_err(Into::into))
        .collect::<Result<_>>()?;
    let materials: Vec<Material> =
        files.iter().zip(&opts.inputs).map(|(b, p)| crate::parse(b, p)).collect::<Result<_>>()?;
    for (m, p) in materials.iter().zip(&opts.inputs) {
        if m.channel_count() < 3 {
            return Err(format!(
                "{}: nmat walk shows channels 0–2, this has {}",
                p.display(),
                m.channel_count()
            )
            .into());
        }
    }
    let refs: Vec<&Material> = materials.iter().collect();
    check_memory(opts, &refs, files.iter().map(|f| f.len() as u64).sum())?;
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let decoders: Vec<&Decoder> = decoders.iter().collect();
    // What decoding every texture whole would cost: every texel of every mip of every material.
    let whole: u64 = materials
        .iter()
        .map(|m| (0..m.mip_count()).map(|i| m.decode_cost(i).texels).sum::<u64>())
        .sum();
    let whole_mip0: u64 = materials.iter().map(|m| m.decode_cost(0).texels).sum();
    println!(
        "walk: {} frames at {}×{}, {} materials ({} texels in their mip chains, {} at mip 0), cache of {} tiles",
        opts.frames,
        opts.width,
        opts.height,
        materials.len(),
        whole,
        whole_mip0,
        opts.tiles
    );
    let mut csv = String::from(
        "mips,threads,frame,marked,hits,decoded,decoded_texels,evicted,overflowed,resolve_misses,mark_ms,decode_ms,resolve_ms,cached_ms,direct_ms,identical\n",
    );
    println!(
        "\n| mips | threads | frames | tiles marked | decoded | hit rate | texels decoded / frame | ÷ whole chains | mark ms | decode ms | resolve ms | cached ms | direct ms | direct ÷ cached |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &mips in &opts.mips {
        for &threads in &opts.threads {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
            let (rows, last) = pool.install(|| {
                walk(opts, &materials, &refs, &decoders, mips).map_err(|e| e.to_string())
            })?;
            if let (Some(path), true) = (&opts.image, mips) {
                write_png(path, opts, &last)?;
            }
            report(&mut csv, &rows, mips, &threads.to_string(), whole)?;
        }
        if opts.gpu {
            gpu_walk(opts, &materials, mips, &mut csv, whole)?;
        }
    }
    if let Some(path) = &opts.csv {
        nmat_cli::output::write_atomic(path, csv.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("\nper-frame rows: {}", path.display());
    }
    Ok(())
}

/// Refuses a walk whose cache and frames would need more than `--max-memory`, before anything
/// is allocated: the files (`file_bytes`), the cache's slots and tiles, and per pixel the
/// G-buffer, the cached, direct and last frames, a found tile key, the PNG's bytes, and with
/// `--gpu` the GPU's lookup and result.
fn check_memory(opts: &Options, refs: &[&Material<'_>], file_bytes: u64) -> Result<()> {
    use std::mem::size_of;
    let size = TileCache::<Vec<Slot>, Vec<u8>>::memory_for(refs, opts.tiles)
        .map_err(|e| format!("--tiles {}: {e}", opts.tiles))?;
    let (cache, slot_bytes) = (size.total_bytes as u64, size.slot_bytes + size_of::<Slot>());
    let per_pixel = size_of::<Lookup>()
        + 3 * size_of::<[f32; 3]>()
        + size_of::<TileKey>()
        + 3
        + if opts.gpu { 2 * size_of::<[f32; 4]>() + size_of::<Lookup>() } else { 0 };
    let frames = u64::from(opts.width) * u64::from(opts.height) * per_pixel as u64;
    let need = file_bytes.saturating_add(cache).saturating_add(frames);
    if need > opts.max_memory {
        return Err(format!(
            "nmat walk needs about {:.1} MiB ({:.1} MiB for the cache's {} tiles of {slot_bytes} \
             bytes, --tiles; {:.1} MiB for {}×{} frames, --size), more than the {:.1} MiB \
             allowed; nothing was run. Lower --tiles or --size, or raise --max-memory",
            crate::mib(need),
            crate::mib(cache),
            opts.tiles,
            crate::mib(frames),
            opts.width,
            opts.height,
            crate::mib(opts.max_memory)
        )
        .into());
    }
    Ok(())
}

/// The walk on the GPU, reported like the CPU's (threads "GPU").
#[cfg(feature = "gpu")]
fn gpu_walk(
    opts: &Options,
    materials: &[Material<'_>],
    mips: bool,
    csv: &mut String,
    whole: u64,
) -> Result<()> {
    let walk = gpu::walk(opts, materials, mips)?;
    println!(
        "| | GPU: {}{}, {} | | | | | | | | | | | | |",
        walk.adapter,
        if walk.software { ", a software rasterizer on the CPU: not a GPU's numbers" } else { "" },
        walk.clock.name()
    );
    report(csv, &walk.rows, mips, "GPU", whole)
}

#[cfg(not(feature = "gpu"))]
fn gpu_walk(_: &Options, _: &[Material<'_>], _: bool, _: &mut String, _: u64) -> Result<()> {
    Err(crate::NO_GPU_BUILD.into())
}

/// One walk's rows into the CSV, its summary row into the table; an error if a checked frame
/// differed from direct decoding.
fn report(csv: &mut String, rows: &[Row], mips: bool, threads: &str, whole: u64) -> Result<()> {
    for (f, r) in rows.iter().enumerate() {
        let s = &r.stats;
        let stage = |k: usize| r.stages.map_or(String::new(), |st| format!("{:.3}", st[k]));
        csv.push_str(&format!(
            "{mips},{threads},{f},{},{},{},{},{},{},{},{},{},{},{:.3},{},{}\n",
            s.marked,
            s.hits,
            s.decoded,
            s.decoded_texels,
            s.evicted,
            s.overflowed,
            s.resolve_misses,
            stage(0),
            stage(1),
            stage(2),
            r.cached_ms,
            r.direct_ms.map_or(String::new(), |v| format!("{v:.3}")),
            r.identical.map_or(String::new(), |v| v.to_string()),
        ));
    }
    summary(rows, mips, threads, whole);
    if rows.iter().any(|r| r.identical == Some(false)) {
        return Err("the cached frame differs from direct decoding (a bug: please report)".into());
    }
    Ok(())
}

/// Channels 0–2 of a frame as a PNG.
fn write_png(path: &std::path::Path, opts: &Options, frame: &[[f32; 3]]) -> Result<()> {
    let bytes: Vec<u8> =
        frame.iter().flatten().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    let mut png = Vec::new();
    image::RgbImage::from_raw(opts.width, opts.height, bytes)
        .ok_or("image size")?
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    nmat_cli::output::write_atomic(path, &png).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

fn median(v: impl Iterator<Item = f64>) -> f64 {
    crate::bench::median(v.collect())
}

fn summary(rows: &[Row], mips: bool, threads: &str, whole: u64) {
    let marked = median(rows.iter().map(|r| f64::from(r.stats.marked)));
    let decoded = median(rows.iter().map(|r| f64::from(r.stats.decoded)));
    let (hits, all) = rows.iter().skip(1).fold((0u64, 0u64), |(h, a), r| {
        (h + u64::from(r.stats.hits), a + u64::from(r.stats.marked))
    });
    let texels = median(rows.iter().map(|r| f64::from(r.stats.decoded_texels)));
    let stage = |k: usize| {
        let v: Vec<f64> = rows.iter().filter_map(|r| Some(r.stages?[k])).collect();
        if v.is_empty() { "—".to_string() } else { format!("{:.1}", median(v.into_iter())) }
    };
    let (mark, decode, resolve) = (stage(0), stage(1), stage(2));
    let cached = median(rows.iter().map(|r| r.cached_ms));
    let direct: Vec<_> = rows.iter().filter_map(|r| Some((r.direct_ms?, r.cached_ms))).collect();
    let (direct_ms, ratio) = if direct.is_empty() {
        ("—".to_string(), "—".to_string())
    } else {
        (
            format!("{:.1}", median(direct.iter().map(|d| d.0))),
            format!("{:.1}×", median(direct.iter().map(|d| d.0 / d.1))),
        )
    };
    println!(
        "| {} | {threads} | {} | {marked:.0} | {decoded:.0} | {:.1} % | {texels:.0} | {:.4} | {mark} | {decode} | {resolve} | {cached:.1} | {direct_ms} | {ratio} |",
        if mips { "yes" } else { "no" },
        rows.len(),
        100.0 * hits as f64 / all.max(1) as f64,
        texels / whole as f64,
    );
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// The whole walk with one cache, on the current rayon pool; its rows and last frame.
fn walk(
    opts: &Options,
    materials: &[Material<'_>],
    refs: &[&Material<'_>],
    decoders: &[&Decoder],
    mips: bool,
) -> Result<(Vec<Row>, Vec<[f32; 3]>)> {
    let mut cache = TileCache::with_capacity(refs, opts.tiles)?;
    let (mut rows, mut last) = (Vec::new(), Vec::new());
    for f in 0..opts.frames {
        let lookups = gbuffer(opts, materials, f, mips);
        cache.begin_frame();
        // Marking: the footprints on every thread, a row of pixels each (a tile met by the
        // previous few lookups is not listed again), then one pass that marks them.
        let start = Instant::now();
        let found: Vec<Vec<TileKey>> = lookups
            .par_chunks(opts.width as usize)
            .map(|row| {
                let mut keys: Vec<TileKey> = Vec::new();
                for l in row {
                    for key in cache.footprint(usize::from(l.material), &request(l, mips))? {
                        if !keys.iter().rev().take(16).any(|k| *k == key) {
                            keys.push(key);
                        }
                    }
                }
                Ok(keys)
            })
            .collect::<std::result::Result<_, nmat_core::Error>>()?;
        cache.mark_tiles(&found.concat())?;
        let mark_ms = ms(start);
        let start = Instant::now();
        cache.pending().par_bridge().try_for_each(|t| {
            let d = decoders[usize::from(t.key().material)];
            t.decode_with(d)
        })?;
        let decode_ms = ms(start);
        let start = Instant::now();
        let image: Vec<[f32; 3]> = lookups
            .par_iter()
            .map(|l| {
                let mut rgb = [0f32; 3];
                cache.resolve(usize::from(l.material), &request(l, mips), &mut rgb).map(|_| rgb)
            })
            .collect::<std::result::Result<_, _>>()?;
        let resolve_ms = ms(start);
        let stats = cache.end_frame();
        let (mut direct_ms, mut identical) = (None, None);
        if opts.direct_every > 0 && f % opts.direct_every == 0 {
            let start = Instant::now();
            let direct: Vec<[f32; 3]> = lookups
                .par_iter()
                .map(|l| {
                    let mut rgb = [0f32; 3];
                    let m = &materials[usize::from(l.material)];
                    decoders[usize::from(l.material)]
                        .sample(m, &request(l, mips), &mut rgb)
                        .map(|_| rgb)
                })
                .collect::<std::result::Result<_, _>>()?;
            direct_ms = Some(ms(start));
            identical = Some(direct == image);
        }
        let stages = Some([mark_ms, decode_ms, resolve_ms]);
        let cached_ms = mark_ms + decode_ms + resolve_ms;
        rows.push(Row { stats, stages, cached_ms, direct_ms, identical });
        last = image;
    }
    Ok((rows, last))
}
