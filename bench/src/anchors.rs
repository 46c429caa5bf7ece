//! Measures the reference codecs on a material exactly the way `nmat eval` measures nmat: every map
//! of every mip of the chain `nmat_encode::texset::load` builds, PSNR over all channels and mips,
//! BPPC = all compressed bits / (width · height · channels of mip 0 that vary).
//!
//! Maps are handed to the codecs as an engine would: the colour part (3 channels) as RGB, every
//! other channel (gray maps, alphas) as its own gray image. Fixed-rate formats count their block
//! payload (BC1/BC4: 64 bits per 4×4 block; ASTC: 128 bits per block); JPEG XL and AVIF count
//! their whole files. For JPEG XL and AVIF the quality is searched (one setting for the whole
//! material) so the BPPC is the largest not above each `--match` target.
//!
//! Usage: nmat-anchors MATERIAL_DIR [--match LABEL=BPPC]... [--sweep] [--matched-only] > rows.csv
//! (`--matched-only` skips BC1/BC4 and ASTC, whose rates do not depend on nmat's; `--sweep` adds
//! JPEG XL and AVIF at seven settings each, from about 0.05 to 2 BPPC: the curves `nmat eval
//! --report --anchors rows.csv` draws.)
//! Rows: material,codec,setting,bppc,psnr_db,seconds; matched rows are named `jpegxl@LABEL`. Needs nvcompress/nvdecompress (libnvtt-bin),
//! astcenc, cjxl/djxl (libjxl-tools), avifenc/avifdec (libavif-bin) on PATH.

use nmat_encode::texset::{self, LoadOptions, TextureSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// One image handed to a codec: unit values, 1 or 3 components, and the material channels.
struct Part {
    mip: usize,
    width: u32,
    height: u32,
    channels: Vec<usize>,
}

fn parts(set: &TextureSet) -> Vec<Part> {
    let mut out = Vec::new();
    for (mip, m) in set.mips.iter().enumerate() {
        for map in &set.maps {
            let chans: Vec<usize> =
                (map.first_channel..map.first_channel + map.channel_count).collect();
            let (color, rest) =
                if chans.len() >= 3 { chans.split_at(3) } else { chans.split_at(0) };
            if !color.is_empty() {
                out.push(Part { mip, width: m.width, height: m.height, channels: color.to_vec() });
            }
            for &c in rest {
                out.push(Part { mip, width: m.width, height: m.height, channels: vec![c] });
            }
        }
    }
    out
}

fn pixels(set: &TextureSet, p: &Part) -> Vec<u8> {
    let m = &set.mips[p.mip];
    let c = set.channel_count();
    (0..(p.width * p.height) as usize)
        .flat_map(|i| p.channels.iter().map(move |&k| (m.data[i * c + k] * 255.0).round() as u8))
        .collect()
}

fn save_png(path: &Path, p: &Part, px: Vec<u8>) {
    let ok = if p.channels.len() == 3 {
        image::RgbImage::from_raw(p.width, p.height, px).map(|i| i.save(path))
    } else {
        image::GrayImage::from_raw(p.width, p.height, px).map(|i| i.save(path))
    };
    ok.expect("buffer size").expect("write png");
}

/// Decoded unit values of a part, read back from a codec's output image.
fn load_back(path: &Path, p: &Part) -> Vec<f32> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let img = image::imageops::crop_imm(&img.to_rgb8(), 0, 0, p.width, p.height).to_image();
    let n = p.channels.len();
    img.pixels().flat_map(|px| (0..n).map(move |k| f32::from(px.0[k]) / 255.0)).collect()
}

/// Decodes the BC1 or BC4 payload of a DDS file (nvdecompress writes TGAs the image crate cannot
/// read, so the blocks are decoded here, following the BC1/BC4 definitions).
fn decode_dds(dds: &[u8], p: &Part) -> Vec<f32> {
    let mut at = 128;
    if dds.get(84..88) == Some(b"DX10") {
        at += 20;
    }
    let (bw, bh) = (p.width.div_ceil(4) as usize, p.height.div_ceil(4) as usize);
    let n = p.channels.len();
    let mut out = vec![0f32; (p.width * p.height) as usize * n];
    for by in 0..bh {
        for bx in 0..bw {
            let block = &dds[at + 8 * (by * bw + bx)..][..8];
            let texels: [[u8; 3]; 16] =
                if n == 3 { bc1_block(block) } else { bc4_block(block).map(|v| [v; 3]) };
            for (t, rgb) in texels.iter().enumerate() {
                let (x, y) = (bx * 4 + t % 4, by * 4 + t / 4);
                if x < p.width as usize && y < p.height as usize {
                    for k in 0..n {
                        out[(y * p.width as usize + x) * n + k] = f32::from(rgb[k]) / 255.0;
                    }
                }
            }
        }
    }
    out
}

fn bc1_block(b: &[u8]) -> [[u8; 3]; 16] {
    let c = [u16::from_le_bytes([b[0], b[1]]), u16::from_le_bytes([b[2], b[3]])];
    let rgb = |v: u16| {
        let (r, g, bl) = ((v >> 11) as u32, ((v >> 5) & 63) as u32, (v & 31) as u32);
        [(r << 3) | (r >> 2), (g << 2) | (g >> 4), (bl << 3) | (bl >> 2)]
    };
    let (a, z) = (rgb(c[0]), rgb(c[1]));
    let mix =
        |wa: u32, wz: u32, d: u32| [0, 1, 2].map(|k| ((wa * a[k] + wz * z[k] + d / 2) / d) as u8);
    let palette = if c[0] > c[1] {
        [a.map(|v| v as u8), z.map(|v| v as u8), mix(2, 1, 3), mix(1, 2, 3)]
    } else {
        [a.map(|v| v as u8), z.map(|v| v as u8), mix(1, 1, 2), [0, 0, 0]]
    };
    let idx = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
    std::array::from_fn(|t| palette[((idx >> (2 * t)) & 3) as usize])
}

fn bc4_block(b: &[u8]) -> [u8; 16] {
    let (a0, a1) = (u32::from(b[0]), u32::from(b[1]));
    let mut pal = [0u32; 8];
    pal[0] = a0;
    pal[1] = a1;
    if a0 > a1 {
        for k in 1..7 {
            pal[k + 1] = ((7 - k) as u32 * a0 + k as u32 * a1 + 3) / 7;
        }
    } else {
        for k in 1..5 {
            pal[k + 1] = ((5 - k) as u32 * a0 + k as u32 * a1 + 2) / 5;
        }
        pal[6] = 0;
        pal[7] = 255;
    }
    let bits = b[2..8].iter().rev().fold(0u64, |acc, &v| (acc << 8) | u64::from(v));
    std::array::from_fn(|t| pal[((bits >> (3 * t)) & 7) as usize] as u8)
}

fn run(cmd: &mut Command) {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(out.status.success(), "{cmd:?}: {}", String::from_utf8_lossy(&out.stderr));
}

#[derive(Clone, Copy, Debug)]
enum Codec {
    Bc,
    Astc(u32),
    Jxl(u32),
    Avif(u32),
}

impl Codec {
    fn name(self) -> String {
        match self {
            Codec::Bc => "bc1/bc4".into(),
            Codec::Astc(b) => format!("astc{b}x{b}"),
            Codec::Jxl(_) => "jpegxl".into(),
            Codec::Avif(_) => "avif".into(),
        }
    }
    fn setting(self) -> String {
        match self {
            Codec::Bc | Codec::Astc(_) => "-".into(),
            Codec::Jxl(q) => format!("q{q}"),
            Codec::Avif(q) => format!("quantizer{q}"),
        }
    }

    /// Compresses and decompresses one part: (bits, decoded unit values).
    fn roundtrip(self, dir: &Path, set: &TextureSet, p: &Part) -> (u64, Vec<f32>) {
        let src = dir.join("in.png");
        save_png(&src, p, pixels(set, p));
        let blocks = |b: u32| u64::from(p.width.div_ceil(b)) * u64::from(p.height.div_ceil(b));
        match self {
            Codec::Bc => {
                let dds = dir.join("out.dds");
                let format = if p.channels.len() == 3 { "-bc1" } else { "-bc4" };
                if p.channels.len() == 1 {
                    // This nvcompress (nvtt 2) compresses BC4 from the alpha channel: hand it the
                    // value in all four channels.
                    let rgba = pixels(set, p).iter().flat_map(|&v| [v, v, v, v]).collect();
                    image::RgbaImage::from_raw(p.width, p.height, rgba)
                        .expect("size")
                        .save(&src)
                        .expect("png");
                }
                run(Command::new("nvcompress")
                    .args(["-silent", "-nomips", format])
                    .arg(&src)
                    .arg(&dds));
                let bytes = std::fs::read(&dds).expect("dds written");
                (blocks(4) * 64, decode_dds(&bytes, p))
            }
            Codec::Astc(b) => {
                let out = dir.join("out.png");
                run(Command::new("astcenc")
                    .arg("-tl")
                    .arg(&src)
                    .arg(&out)
                    .arg(format!("{b}x{b}"))
                    .args(["-medium", "-silent"]));
                (blocks(b) * 128, load_back(&out, p))
            }
            Codec::Jxl(q) => {
                let (enc, dec) = (dir.join("out.jxl"), dir.join("out.png"));
                run(Command::new("cjxl").arg(&src).arg(&enc).args([
                    "-q",
                    &q.to_string(),
                    "--quiet",
                ]));
                run(Command::new("djxl").arg(&enc).arg(&dec).arg("--quiet"));
                (std::fs::metadata(&enc).map_or(0, |m| m.len()) * 8, load_back(&dec, p))
            }
            Codec::Avif(q) => {
                let (enc, dec) = (dir.join("out.avif"), dir.join("out.png"));
                let q = q.to_string();
                run(Command::new("avifenc")
                    .args(["--min", &q, "--max", &q, "-s", "6", "-y", "444"])
                    .arg(&src)
                    .arg(&enc));
                run(Command::new("avifdec").arg(&enc).arg(&dec));
                (std::fs::metadata(&enc).map_or(0, |m| m.len()) * 8, load_back(&dec, p))
            }
        }
    }
}

/// (bppc, psnr) of a codec over the whole chain.
fn measure(codec: Codec, dir: &Path, set: &TextureSet, parts: &[Part]) -> (f64, f64) {
    let (mut bits, mut sq, mut n) = (0u64, 0f64, 0f64);
    for p in parts {
        let (b, decoded) = codec.roundtrip(dir, set, p);
        bits += b;
        let m = &set.mips[p.mip];
        let c = set.channel_count();
        let mut part_sq = 0.0;
        for (i, v) in decoded.iter().enumerate() {
            let (texel, k) = (i / p.channels.len(), p.channels[i % p.channels.len()]);
            let e = f64::from(v - m.data[texel * c + k]);
            part_sq += e * e;
        }
        if std::env::var_os("NMAT_ANCHORS_VERBOSE").is_some() {
            let psnr = -10.0 * (part_sq / decoded.len().max(1) as f64).log10();
            eprintln!("{codec:?} mip {} channels {:?}: {psnr:.2} dB", p.mip, p.channels);
        }
        sq += part_sq;
        n += decoded.len() as f64;
    }
    // Over the channels that vary, as nmat's BPPC counts them (a constant channel carries no
    // information; what a codec spends on it still counts in `bits`).
    let channels = set.learned_channels().len().max(1) as f64;
    let bppc = bits as f64 / (f64::from(set.width) * f64::from(set.height) * channels);
    (bppc, -10.0 * (sq / n).log10())
}

const USAGE: &str = "usage: nmat-anchors MATERIAL_DIR [--match LABEL=BPPC]... [--sweep] [--matched-only] > rows.csv";

/// Ends the process with `why` (and the usage line) on stderr, exit status 2.
fn refuse(why: &str) -> ! {
    eprintln!("nmat-anchors: {why}\n{USAGE}");
    std::process::exit(2)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let material = match args.next() {
        Some(a) if a == "--help" || a == "-h" => {
            println!("{USAGE}");
            return;
        }
        Some(a) => PathBuf::from(a),
        None => refuse("no material folder given"),
    };
    let mut targets = Vec::new();
    let mut fixed_rate = true;
    let mut sweep = false;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--match" => {
                let v = args.next().unwrap_or_default();
                let target = v.split_once('=').and_then(|(label, bppc)| {
                    bppc.parse::<f64>().ok().filter(|b| *b > 0.0).map(|b| (label.to_string(), b))
                });
                targets.push(target.unwrap_or_else(|| {
                    refuse(&format!("--match {v:?}: expected LABEL=BPPC with BPPC > 0"))
                }));
            }
            "--matched-only" => fixed_rate = false,
            "--sweep" => sweep = true,
            other => refuse(&format!("unknown argument {other:?}")),
        }
    }
    // The loader's errors name the file or folder at fault.
    let fail = |e: &dyn std::fmt::Display| -> ! { refuse(&e.to_string()) };
    let files =
        texset::collect_inputs(std::slice::from_ref(&material)).unwrap_or_else(|e| fail(&e));
    let roles = texset::assign_roles(&files, &[]).unwrap_or_else(|e| fail(&e));
    let set = texset::load(&roles, &LoadOptions::default()).unwrap_or_else(|e| fail(&e));
    let parts = parts(&set);
    let name = material.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let work = std::env::temp_dir().join(format!("nmat-anchors-{}", std::process::id()));
    std::fs::create_dir_all(&work).expect("temp dir");
    let report = |codec: Codec, label: &str, t: Instant, (bppc, psnr): (f64, f64)| {
        let secs = t.elapsed().as_secs_f64();
        println!(
            "{name},{}{label},{},{bppc:.4},{psnr:.3},{secs:.1}",
            codec.name(),
            codec.setting()
        );
    };
    let fixed: &[Codec] =
        if fixed_rate { &[Codec::Bc, Codec::Astc(12), Codec::Astc(8)] } else { &[] };
    for &codec in fixed {
        let t = Instant::now();
        report(codec, "", t, measure(codec, &work, &set, &parts));
    }
    if sweep {
        let jxl = [20, 40, 60, 75, 85, 92, 97].map(Codec::Jxl);
        let avif = [56, 48, 40, 32, 24, 16, 8].map(Codec::Avif);
        for codec in jxl.into_iter().chain(avif) {
            let t = Instant::now();
            report(codec, "", t, measure(codec, &work, &set, &parts));
        }
    }
    for (label, target) in &targets {
        let (label, target) = (format!("@{label}"), *target);
        // One quality setting for the material; the rate grows with the setting (JXL q 15..99:
        // below 15 cjxl's distance would exceed its limit of 25 and it refuses) or shrinks with
        // it (AVIF quantizer 0..63). Bisect for the best rate ≤ target.
        for make in [Codec::Jxl as fn(u32) -> Codec, Codec::Avif] {
            let t = Instant::now();
            let increasing = matches!(make(0), Codec::Jxl(_));
            let (mut lo, mut hi) = if increasing { (15u32, 99u32) } else { (0u32, 63u32) };
            let mut best: Option<(Codec, (f64, f64))> = None;
            while lo <= hi {
                let mid = (lo + hi) / 2;
                let codec = make(mid);
                let r = measure(codec, &work, &set, &parts);
                let fits = r.0 <= target;
                if fits && best.as_ref().is_none_or(|b| r.0 > b.1.0) {
                    best = Some((codec, r));
                }
                // Move toward a larger rate if it fits, a smaller one otherwise.
                match (fits, increasing) {
                    (true, true) | (false, false) => lo = mid + 1,
                    _ => {
                        if mid == 0 {
                            break;
                        }
                        hi = mid - 1;
                    }
                }
            }
            match best {
                Some((codec, r)) => report(codec, &label, t, r),
                None => eprintln!("{name}: {} cannot go as low as {target} BPPC", make(0).name()),
            }
        }
    }
    let _ = std::fs::remove_dir_all(&work);
}
