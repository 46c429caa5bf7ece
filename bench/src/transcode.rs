//! Load-time transcoding against the usual path, on one material (docs/PERFORMANCE.md,
//! docs/QUALITY.md). Usage: nmat-transcode-bench MATERIAL.nmat SOURCE_DIR [RUNS]
//!
//! Speed (median of RUNS, default 5): milliseconds from the .nmat file in memory to the BC blocks
//! of every texture of the default layout and every mip (as `nmat transcode` runs it:
//! `Decoder::transcode_textures`, all textures in one network pass, block rows in parallel) with 1
//! and 2 threads; and the usual path from the same maps stored as PNG: PNG
//! decode, a 2×2 box-filtered mip chain, and Intel's ISPC BC encoder (fast, SIMD) on every mip,
//! with 1 and 2 threads (maps in parallel).
//!
//! Quality, per texture over the whole chain (the encoder's Lanczos mips of the source maps): PSNR
//! of the BC blocks transcoded from nmat, of BC blocks encoded by the same core encoder from the
//! source maps, and of nmat's own decode, against the source; with the bytes each needs stored
//! (the .nmat file for all textures; BC of the whole chain per texture).

use nmat_cli::stats::median;
use nmat_core::bc::{self, BcFormat, BcTexture};
use nmat_core::{Container, Decoder, Material, SectionKind};
use nmat_encode::texset::{self, LoadOptions, Role, TextureSet};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The source maps the material was encoded from, in its channel order.
fn load_source(m: &Material<'_>, dir: &Path) -> TextureSet {
    let section = m.optional_section(SectionKind(nmat_encode::source_maps::SECTION_KIND));
    let maps = section.and_then(nmat_encode::source_maps::decode).expect("a SOURCE_MAPS section");
    let roles: Vec<(Role, PathBuf)> =
        maps.iter().map(|s| (s.role, dir.join(&s.file_name))).collect();
    let set = texset::load(&roles, &LoadOptions::default()).expect("source maps");
    assert_eq!(set.channel_count(), m.channel_count(), "the source maps give other channels");
    set
}

/// 8-bit codes of `texture`'s components at every texel of source mip `mip` (row-major).
fn source_codes(set: &TextureSet, mip: usize, texture: &BcTexture) -> (u32, u32, Vec<[u8; 4]>) {
    let img = &set.mips[mip];
    let n = set.channel_count();
    let list = texture.channel_list();
    let px = img
        .data
        .chunks_exact(n)
        .map(|t| {
            std::array::from_fn(|k| {
                list.get(k)
                    .map_or(255, |&c| (t[usize::from(c)] * 255.0).round().clamp(0.0, 255.0) as u8)
            })
        })
        .collect();
    (img.width, img.height, px)
}

/// BC blocks of an image of `w` × `h` pixels by the core's encoder.
fn encode(format: BcFormat, w: u32, h: u32, px: &[[u8; 4]]) -> Vec<u8> {
    let mut out = Vec::new();
    for by in 0..h.div_ceil(4) {
        for bx in 0..w.div_ceil(4) {
            let block = std::array::from_fn(|i| {
                let (x, y) =
                    ((4 * bx + i as u32 % 4).min(w - 1), (4 * by + i as u32 / 4).min(h - 1));
                px[(y * w + x) as usize]
            });
            let mut b = [0u8; 16];
            bc::encode_block(format, &block, bc::valid_mask(bx, by, w, h), &mut b);
            out.extend(&b[..format.block_bytes()]);
        }
    }
    out
}

/// Squared error and count of `blocks` (decoded) against `px` over the texture's components.
fn error(format: BcFormat, w: u32, h: u32, px: &[[u8; 4]], blocks: &[u8]) -> (f64, f64) {
    let (mut sse, mut n) = (0.0, 0.0);
    for (k, b) in blocks.chunks_exact(format.block_bytes()).enumerate() {
        let (bx, by) = (k as u32 % w.div_ceil(4), k as u32 / w.div_ceil(4));
        for (i, d) in bc::decode_block(format, b).iter().enumerate() {
            let (x, y) = (4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
            if x < w && y < h {
                let s = px[(y * w + x) as usize];
                for c in 0..format.components() {
                    sse += (f64::from(s[c]) - f64::from(d[c])).powi(2);
                    n += 1.0;
                }
            }
        }
    }
    (sse, n)
}

fn psnr((sse, n): (f64, f64)) -> f64 {
    10.0 * (255.0f64 * 255.0 / (sse / n).max(1e-12)).log10()
}

fn add(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0 + b.0, a.1 + b.1)
}

/// Every texture, every mip, transcoded as `nmat transcode` does it (all textures in one network
/// pass per block row, block rows in parallel).
fn transcode_all(m: &Material<'_>, d: &Decoder, layout: &[BcTexture]) -> Vec<Vec<Vec<u8>>> {
    let images = nmat_cli::transcode::transcode(m, d, layout, &mut |_| {}).expect("transcode");
    images.into_iter().map(|image| image.levels).collect()
}

/// The usual path for one map stored as PNG: decode it, box-filter its mips, ISPC-encode each.
fn usual_path(png: &[u8], format: BcFormat) -> usize {
    let img = image::load_from_memory_with_format(png, image::ImageFormat::Png).expect("png");
    let mut level = img.to_rgba8();
    let mut bytes = 0;
    loop {
        let (w, h) = level.dimensions();
        let (w4, h4) = (w.div_ceil(4) * 4, h.div_ceil(4) * 4);
        // ISPC wants whole blocks: pad by repeating the edge.
        let padded =
            image::RgbaImage::from_fn(w4, h4, |x, y| *level.get_pixel(x.min(w - 1), y.min(h - 1)));
        let raw = padded.as_raw();
        let plane =
            |n: usize| -> Vec<u8> { raw.chunks_exact(4).flat_map(|p| p[..n].to_vec()).collect() };
        bytes += match format {
            BcFormat::Bc1 => {
                let s =
                    intel_tex_2::RgbaSurface { data: raw, width: w4, height: h4, stride: 4 * w4 };
                intel_tex_2::bc1::compress_blocks(&s).len()
            }
            BcFormat::Bc5 => {
                let rg = plane(2);
                let s = intel_tex_2::RgSurface { data: &rg, width: w4, height: h4, stride: 2 * w4 };
                intel_tex_2::bc5::compress_blocks(&s).len()
            }
            _ => {
                let r = plane(1);
                let s = intel_tex_2::RSurface { data: &r, width: w4, height: h4, stride: w4 };
                intel_tex_2::bc4::compress_blocks(&s).len()
            }
        };
        if w == 1 && h == 1 {
            return bytes;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        level = image::RgbaImage::from_fn(nw, nh, |x, y| {
            let at = |dx: u32, dy: u32| {
                level.get_pixel((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1)).0
            };
            let (a, b, c, d) = (at(0, 0), at(1, 0), at(0, 1), at(1, 1));
            image::Rgba(std::array::from_fn(|k| {
                ((u32::from(a[k]) + u32::from(b[k]) + u32::from(c[k]) + u32::from(d[k]) + 2) / 4)
                    as u8
            }))
        });
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(file), Some(dir)) = (args.first(), args.get(1)) else {
        eprintln!("usage: nmat-transcode-bench MATERIAL.nmat SOURCE_DIR [RUNS]");
        std::process::exit(2);
    };
    let runs: usize = args.get(2).map_or(5, |r| r.parse().expect("RUNS"));
    let bytes = std::fs::read(file).expect("read the .nmat file");
    let m = Container::parse(&bytes).expect("a .nmat file");
    let set = load_source(&m, Path::new(dir));
    let layout: Vec<BcTexture> = bc::default_layout(&m).into_iter().collect();
    let d = Decoder::new(&m);

    // Quality over the whole chain.
    let transcoded = transcode_all(&m, &d, &layout);
    println!("texture,format,bc_bytes,nmat_to_bc_db,source_to_bc_db,nmat_db");
    let mut total_bc = 0;
    for (t, levels) in layout.iter().zip(&transcoded) {
        let (mut via_nmat, mut via_source, mut plain) = ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0));
        for (mip, blocks) in levels.iter().enumerate() {
            let (w, h, px) = source_codes(&set, mip, t);
            via_nmat = add(via_nmat, error(t.format, w, h, &px, blocks));
            via_source = add(via_source, error(t.format, w, h, &px, &encode(t.format, w, h, &px)));
            let mut codes = vec![0u8; (w * h) as usize * m.channel_count()];
            for y in 0..h {
                let row = &mut codes[(y * w) as usize * m.channel_count()..]
                    [..w as usize * m.channel_count()];
                d.decode_span_u8(
                    &m,
                    0,
                    y.into(),
                    mip as u32,
                    w as usize,
                    nmat_core::ChannelMask::ALL,
                    row,
                )
                .expect("decode");
            }
            let list = t.channel_list();
            for (texel, s) in codes.chunks_exact(m.channel_count()).zip(&px) {
                for (k, &c) in list.iter().enumerate() {
                    let v = m.channels()[usize::from(c)]
                        .constant_code()
                        .unwrap_or(texel[usize::from(c)]);
                    plain = add(plain, ((f64::from(v) - f64::from(s[k])).powi(2), 1.0));
                }
            }
        }
        let bc_bytes: usize = levels.iter().map(Vec::len).sum();
        total_bc += bc_bytes;
        let names: Vec<&str> =
            t.channel_list().iter().map(|&c| m.channels()[usize::from(c)].name).collect();
        println!(
            "{},{}{},{bc_bytes},{:.2},{:.2},{:.2}",
            names.join(" "),
            t.format.name(),
            if t.srgb { " srgb" } else { "" },
            psnr(via_nmat),
            psnr(via_source),
            psnr(plain)
        );
    }
    println!("storage: .nmat {} bytes, BC (all textures, all mips) {total_bc} bytes", bytes.len());

    // Speed: the usual path's PNGs are made once (untimed).
    let pngs: Vec<(Vec<u8>, BcFormat)> = layout
        .iter()
        .map(|t| {
            let (w, h, px) = source_codes(&set, 0, t);
            let img = image::RgbaImage::from_raw(w, h, px.concat()).expect("image");
            let mut out = std::io::Cursor::new(Vec::new());
            img.write_to(&mut out, image::ImageFormat::Png).expect("png");
            (out.into_inner(), t.format)
        })
        .collect();
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let ours = median((0..runs).map(|_| {
            let start = Instant::now();
            pool.install(|| transcode_all(&m, &d, &layout));
            start.elapsed().as_secs_f64() * 1e3
        }));
        let usual = median((0..runs).map(|_| {
            let start = Instant::now();
            pool.install(|| pngs.par_iter().map(|(png, f)| usual_path(png, *f)).sum::<usize>());
            start.elapsed().as_secs_f64() * 1e3
        }));
        println!(
            "threads {threads}: nmat transcode {ours:.1} ms, PNG decode + mips + ISPC {usual:.1} ms"
        );
    }
}
