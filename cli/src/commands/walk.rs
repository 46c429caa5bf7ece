//! `nmat walk`: a headless walk down a textured corridor (docs/PERFORMANCE.md, "Tile cache"),
//! to measure what the tile cache saves a renderer: the scene is `corridor`'s; here the CPU walk
//! with one cache per thread count, direct decoding to compare, and the reports.

use crate::args::WalkArgs;
use crate::common::{Result, check_threads, mib, parse};
use crate::corridor::{Lookup, Options, Row, gbuffer, request};
use nmat_cli::output;
use nmat_cli::stats::median;
use nmat_core::{Decoder, Material, Slot, TileCache, TileKey};
use rayon::prelude::*;
use std::time::Instant;

pub fn run(args: WalkArgs) -> Result<()> {
    let WalkArgs {
        inputs,
        size,
        frames,
        threads,
        tiles,
        direct_every,
        mips,
        csv,
        image,
        gpu,
        memory,
    } = args;
    if frames == 0 || tiles == 0 || inputs.len() > 4 {
        return Err("--frames and --tiles must be at least 1, and at most 4 inputs".into());
    }
    for &n in &threads {
        check_threads(n)?;
    }
    // The outputs are checked before the walk (minutes at the defaults) starts.
    let outputs = [("--csv", &csv), ("--image", &image)];
    for (option, path) in outputs {
        if let Some(path) = path {
            output::check_output_file(option, path, &inputs)?;
        }
    }
    if let (Some(c), Some(i)) = (&csv, &image)
        && c == i
    {
        return Err(format!("--csv and --image both name {}", c.display()).into());
    }
    walk_all(&Options {
        inputs,
        width: size.0,
        height: size.1,
        frames,
        threads,
        tiles,
        direct_every,
        mips: mips.map_or(vec![true, false], |m| vec![m]),
        csv,
        image,
        gpu,
        max_memory: memory.bytes(),
    })
}

/// Every walk `opts` asks for, reported as a table (and the CSV and PNG).
fn walk_all(opts: &Options) -> Result<()> {
    let files: Vec<nmat_cli::input::Loaded> = opts
        .inputs
        .iter()
        .map(|p| nmat_cli::input::read_nmat(p).map_err(Into::into))
        .collect::<Result<_>>()?;
    let materials: Vec<Material> =
        files.iter().zip(&opts.inputs).map(|(b, p)| parse(b, p)).collect::<Result<_>>()?;
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
        output::write_atomic(path, csv.as_bytes())
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
            mib(need),
            mib(cache),
            opts.tiles,
            mib(frames),
            opts.width,
            opts.height,
            mib(opts.max_memory)
        )
        .into());
    }
    Ok(())
}

/// The walk on the GPU, reported like the CPU's (threads "GPU").
fn gpu_walk(
    opts: &Options,
    materials: &[Material<'_>],
    mips: bool,
    csv: &mut String,
    whole: u64,
) -> Result<()> {
    let walk = crate::gpu::walk(opts, materials, mips)?;
    println!(
        "| | GPU: {}{}, {}; tiles decoded by: {} | | | | | | | | | | | | |",
        walk.adapter,
        if walk.software { ", a software rasterizer on the CPU: not a GPU's numbers" } else { "" },
        walk.clock,
        walk.tile_kernels.join(", ")
    );
    report(csv, &walk.rows, mips, "GPU", whole)
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
    output::write_atomic(path, &png).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
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
        if v.is_empty() { "—".to_string() } else { format!("{:.1}", median(v)) }
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
