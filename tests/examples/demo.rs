//! The README's "main job" until the `nmat` CLI exists: open a bundled `.nmat` material, print
//! what it holds, decode its whole mip chain with both decoders, report how they agree and what a
//! texel costs, and write the decoded mips as PPM/PGM images.
//!
//! `cargo run --release -p nmat-tests --example demo [FILE.nmat] [OUT_DIR]`

use nmat_core::{ChannelMask, Container, Material};
use nmat_tests::{decode_all_u8, fixtures_dir, int_vs_float, texels};
use std::error::Error;
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args_os().skip(1);
    let input = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| fixtures_dir().join("ntc_pbr10_96x80_clamp.nmat"));
    let out_dir =
        args.next().map(PathBuf::from).unwrap_or_else(|| PathBuf::from("target/nmat-demo"));
    let bytes = std::fs::read(&input).map_err(|e| format!("{}: {e}", input.display()))?;
    let m = Container::parse(&bytes).map_err(|e| format!("{}: {e}", input.display()))?;
    describe(&input, &m);

    let agreement = int_vs_float(&m);
    println!(
        "\nfloat vs integer decoder over the whole chain ({} codes): max |Δ| {} code, mean Δ {:+.4}, {:.2}% identical",
        agreement.count,
        agreement.max_abs,
        agreement.mean,
        100.0 * agreement.exact as f64 / agreement.count as f64
    );

    let texel_count = texels(&m).count();
    let mut runs = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        std::hint::black_box(decode_all_u8(&m));
        runs.push(t.elapsed().as_secs_f64() * 1e9 / texel_count as f64);
    }
    runs.sort_by(f64::total_cmp);
    println!(
        "integer decode, one thread: median {:.0} ns/texel over {texel_count} texels (5 runs)",
        runs[2]
    );

    std::fs::create_dir_all(&out_dir)?;
    let written = write_images(&m, &out_dir)?;
    println!("wrote {written} images to {}", out_dir.display());
    Ok(())
}

fn describe(path: &std::path::Path, m: &Material<'_>) {
    println!("{}: {} bytes, format 1.{}", path.display(), m.file_len(), m.version_minor());
    println!(
        "  {}×{} texels, {} mips, {} channels, {:?} addressing, {:.3} bits per pixel per channel",
        m.width(),
        m.height(),
        m.mip_count(),
        m.channel_count(),
        m.address_mode(),
        m.bppc()
    );
    for (i, c) in m.channels().iter().enumerate() {
        println!(
            "  channel {i:2} {:12} {:?} [{}, {}] {:?}",
            c.name, c.semantic, c.range_min, c.range_max, c.color_space
        );
    }
    for (i, g) in m.grids().iter().enumerate() {
        println!(
            "  grid {i:2} {:4}×{:<4} {:2} channels × {} bits = {} bytes",
            g.width(),
            g.height(),
            g.channels(),
            g.bits_per_latent(),
            g.packed_data().len()
        );
    }
    let layers: Vec<String> =
        m.mlp().layers().iter().map(|l| format!("{}→{}", l.inputs(), l.outputs())).collect();
    println!("  MLP {} ({} multiply-adds per texel)", layers.join(", "), m.mlp().macs_per_texel());
}

/// One image per map and mip: 3 consecutive channels named `x.r/x.g/x.b` or `x.x/x.y/x.z` make a
/// PPM, any other channel a PGM.
fn write_images(m: &Material<'_>, dir: &std::path::Path) -> Result<usize, Box<dyn Error>> {
    let mut written = 0;
    let names: Vec<&str> = m.channels().iter().map(|c| c.name).collect();
    let mut c = 0;
    while c < names.len() {
        let stem = names[c].split('.').next().unwrap_or(names[c]);
        let triple = c + 2 < names.len()
            && names[c..c + 3].iter().all(|n| n.starts_with(&format!("{stem}.")));
        let count = if triple { 3 } else { 1 };
        let mask = ChannelMask((((1u32 << count) - 1) << c) as u16);
        for mip in 0..m.mip_count() {
            let (w, h) = m.mip_size(mip);
            let mut pixels = Vec::with_capacity((w * h) as usize * count);
            let mut buf = [0u8; 3];
            for y in 0..h {
                for x in 0..w {
                    m.decode_texel_u8(i64::from(x), i64::from(y), mip, mask, &mut buf)?;
                    pixels.extend_from_slice(&buf[..count]);
                }
            }
            let magic = if triple { "P6" } else { "P5" };
            let mut file = format!("{magic}\n{w} {h}\n255\n").into_bytes();
            file.extend_from_slice(&pixels);
            let path = dir.join(format!("{stem}_mip{mip}.{}", if triple { "ppm" } else { "pgm" }));
            let tmp = path.with_extension("tmp");
            std::fs::write(&tmp, file)?;
            std::fs::rename(&tmp, &path)?;
            written += 1;
        }
        c += count;
    }
    Ok(written)
}
