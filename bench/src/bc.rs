//! The core's BC encoders against two reference encoders on the same pixels: `nvcompress`
//! (NVIDIA Texture Tools 2.0, Debian's libnvtt-bin) and Intel's ISPC texture compressor
//! (`intel_tex_2`). PSNR of each over the format's channels against the input image, and the
//! encode times (one thread; the ISPC kernels are SIMD, nvcompress's includes its file I/O and is
//! not reported).
//!
//! Usage: nmat-bc FORMAT IMAGE...   (FORMAT: bc1 = RGB, bc4 = the first channel, bc5 = the first
//! two, bc7 = RGB). For BC7 the reference is ISPC's `basic` profile (its second best of five;
//! NVTT 2.0 has no BC7, so that column is empty). Prints one row per image:
//! image,format,nmat_psnr_db,nvcompress_psnr_db,intel_psnr_db,nmat_ms,intel_ms. All blocks are
//! decoded with the core's decoders (which agree with `bcdec`), so the columns differ only by
//! encoder.

use nmat_core::bc::{self, BcFormat as Format};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// The 16 pixels (RGBA, alpha 255) of block (bx, by), edge pixels repeated past the image, and
/// its mask.
fn block(img: &image::RgbImage, bx: u32, by: u32) -> ([[u8; 4]; 16], u16) {
    let (w, h) = img.dimensions();
    let px = std::array::from_fn(|i| {
        let (x, y) = ((4 * bx + i as u32 % 4).min(w - 1), (4 * by + i as u32 / 4).min(h - 1));
        let [r, g, b] = img.get_pixel(x, y).0;
        [r, g, b, 255]
    });
    (px, bc::valid_mask(bx, by, w, h))
}

fn encode(img: &image::RgbImage, f: Format) -> Vec<u8> {
    let (w, h) = img.dimensions();
    let mut out = Vec::new();
    for by in 0..h.div_ceil(4) {
        for bx in 0..w.div_ceil(4) {
            let (px, valid) = block(img, bx, by);
            let mut b = [0u8; 16];
            bc::encode_block(f, &px, valid, &mut b);
            out.extend(&b[..f.block_bytes()]);
        }
    }
    out
}

/// Squared error summed over the format's channels and the image's pixels, and the count.
fn error(img: &image::RgbImage, f: Format, blocks: &[u8]) -> (f64, f64) {
    let (w, h) = img.dimensions();
    let (mut sse, mut n) = (0f64, 0f64);
    for (k, b) in blocks.chunks_exact(f.block_bytes()).enumerate() {
        let (bx, by) = (k as u32 % w.div_ceil(4), k as u32 / w.div_ceil(4));
        let decoded = bc::decode_block(f, b);
        for (i, d) in decoded.iter().enumerate() {
            let (x, y) = (4 * bx + i as u32 % 4, 4 * by + i as u32 / 4);
            if x < w && y < h {
                let s = img.get_pixel(x, y).0;
                for c in 0..f.components() {
                    let e = f64::from(s[c]) - f64::from(d[c]);
                    sse += e * e;
                    n += 1.0;
                }
            }
        }
    }
    (sse, n)
}

fn psnr((sse, n): (f64, f64)) -> f64 {
    10.0 * (255.0 * 255.0 / (sse / n).max(1e-12)).log10()
}

/// nvcompress's blocks for the same pixels (its BC4 reads the alpha channel: the value goes in
/// all four).
fn nvcompress(img: &image::RgbImage, f: Format, dir: &Path) -> Option<Vec<u8>> {
    if f == Format::Bc7Rgb {
        return None;
    }
    let (src, dds) = (dir.join("in.png"), dir.join("out.dds"));
    let rgba = image::RgbaImage::from_fn(img.width(), img.height(), |x, y| {
        let [r, g, b] = img.get_pixel(x, y).0;
        image::Rgba(if f == Format::Bc4 { [r, r, r, r] } else { [r, g, b, 255] })
    });
    rgba.save(&src).expect("write png");
    let flag = format!("-{}", f.name());
    let out = Command::new("nvcompress")
        .args(["-silent", "-nomips", &flag])
        .arg(&src)
        .arg(&dds)
        .output()
        .expect("run nvcompress");
    assert!(out.status.success(), "nvcompress: {}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&dds).expect("dds written");
    let at = if bytes.get(84..88) == Some(b"DX10") { 148 } else { 128 };
    Some(bytes[at..].to_vec())
}

/// Intel's ISPC encoder on the same pixels (its default, and only, quality for these formats).
fn intel(img: &image::RgbImage, f: Format) -> Vec<u8> {
    let (w, h) = img.dimensions();
    let rgb = img.as_raw();
    let plane =
        |n: usize| -> Vec<u8> { rgb.chunks_exact(3).flat_map(|p| p[..n].to_vec()).collect() };
    let rgba: Vec<u8> = rgb.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
    let surface = intel_tex_2::RgbaSurface { data: &rgba, width: w, height: h, stride: 4 * w };
    match f {
        Format::Bc1 => intel_tex_2::bc1::compress_blocks(&surface),
        Format::Bc7Rgb => {
            intel_tex_2::bc7::compress_blocks(&intel_tex_2::bc7::opaque_basic_settings(), &surface)
        }
        Format::Bc4 => {
            let r = plane(1);
            intel_tex_2::bc4::compress_blocks(&intel_tex_2::RSurface {
                data: &r,
                width: w,
                height: h,
                stride: w,
            })
        }
        _ => {
            // BC5 (the only other format `main` accepts)
            let rg = plane(2);
            let s = intel_tex_2::RgSurface { data: &rg, width: w, height: h, stride: 2 * w };
            intel_tex_2::bc5::compress_blocks(&s)
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((format, images)) = args.split_first() else {
        eprintln!("usage: nmat-bc bc1|bc4|bc5|bc7 IMAGE...");
        std::process::exit(2);
    };
    let f = match format.as_str() {
        "bc1" => Format::Bc1,
        "bc4" => Format::Bc4,
        "bc5" => Format::Bc5,
        "bc7" => Format::Bc7Rgb,
        other => panic!("FORMAT {other:?}: bc1, bc4, bc5 or bc7"),
    };
    let dir = std::env::temp_dir().join(format!("nmat-bc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    println!("image,format,nmat_psnr_db,nvcompress_psnr_db,intel_psnr_db,nmat_ms,intel_ms");
    for path in images {
        let img = image::open(path).unwrap_or_else(|e| panic!("{path}: {e}")).to_rgb8();
        let start = Instant::now();
        let ours = encode(&img, f);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let start = Instant::now();
        let isp = intel(&img, f);
        let intel_ms = start.elapsed().as_secs_f64() * 1e3;
        let nv = nvcompress(&img, f, &dir);
        let blocks = ours.len();
        println!(
            "{path},{format},{:.3},{},{:.3},{ms:.1},{intel_ms:.1}",
            psnr(error(&img, f, &ours)),
            nv.map_or(String::new(), |nv| format!(
                "{:.3}",
                psnr(error(&img, f, &nv[..blocks.min(nv.len())]))
            )),
            psnr(error(&img, f, &isp)),
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
