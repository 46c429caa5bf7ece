//! Decodes mip 0 (or the mip given last) of a .nmat file through `Decoder` spans, repeatedly: a steady load to attach a
//! profiler to (`perf record cargo run --release -p nmat-tests --example span_profile -- FILE`). An
//! optional kernel name (`Kernel::name`: `scalar`, `avx2`, `avx512-vnni`, `neon`, …) picks the
//! kernel, e.g. to count instructions under valgrind, which lacks AVX-512; `texel` after it decodes
//! each row texel by texel in a scattered order instead (`row`: the spans, the default); `random`
//! decodes the scattered texels of `nmat bench`'s random access (16 384 of them spread over the
//! whole mip, one call each) in place of a pass over the rows, `random256` the same texels 256 a
//! call (`decode_texels_u8`). A mip number after the mode decodes that mip instead of mip 0.
//! Prints the mean time per texel of the passes, and the fastest and median time of one row (or
//! of 256 random texels): single rows are short enough that the fastest one is rarely disturbed
//! by other work on a shared machine. To compare two builds, run them in turn many times
//! (`bench/alternate.sh`).

use nmat_core::{ChannelMask, Container, Decoder, Kernel, Material, TexelAt};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let usage =
        "usage: span_profile FILE.nmat [PASSES [KERNEL [row|texel|random|random256 [MIP]]]]";
    let path = std::env::args().nth(1).ok_or(usage)?;
    let passes: usize = std::env::args().nth(2).map_or(Ok(5), |s| s.parse())?;
    let kernel = match std::env::args().nth(3) {
        None => Kernel::best(),
        Some(name) => Kernel::ALL.into_iter().find(|k| k.name() == name).ok_or(usage)?,
    };
    let raw = std::fs::read(&path)?;
    let bytes = nmat_core::unpack(&raw, Default::default())?;
    let m = Container::parse(&bytes)?;
    let d = Decoder::with_kernel(&m, kernel)?;
    let mip: u32 = std::env::args().nth(5).map_or(Ok(0), |s| s.parse())?;
    if mip >= m.mip_count() {
        return Err(format!("{path} has {} mips; mip {mip} asked", m.mip_count()).into());
    }
    let texel_by_texel = match std::env::args().nth(4).as_deref() {
        None | Some("row") => false,
        Some("texel") => true,
        Some("random") => return random(&path, (&m, &d), (passes, mip), 1),
        Some("random256") => return random(&path, (&m, &d), (passes, mip), 256),
        Some(_) => return Err(usage.into()),
    };
    let (w, h) = m.mip_size(mip);
    let mut row = vec![0u8; w as usize * m.channel_count()];
    let mut rows = Vec::with_capacity(passes * h as usize);
    let start = Instant::now();
    for _ in 0..passes {
        for y in 0..h {
            let row_start = Instant::now();
            if texel_by_texel {
                let n = m.channel_count();
                for (i, texel) in row.chunks_exact_mut(n).enumerate() {
                    // A stride coprime with the (power-of-two or odd) width scatters the order.
                    let x = (i as u64 * 97 % u64::from(w)) as i64;
                    d.decode_texel_u8(&m, x, i64::from(y), mip, ChannelMask::ALL, texel)?;
                }
            } else {
                let mask = ChannelMask::ALL;
                d.decode_span_u8(&m, 0, i64::from(y), mip, w as usize, mask, &mut row)?;
            }
            rows.push(row_start.elapsed().as_secs_f64() * 1e9 / f64::from(w));
        }
    }
    let texels = f64::from(w) * f64::from(h) * passes as f64;
    report(&path, start.elapsed().as_secs_f64() * 1e9 / texels, d.kernel(), ("one row", rows));
    Ok(())
}

/// `passes` passes over `nmat bench`'s scattered texels of `mip`, `batch` a call.
fn random(
    path: &str,
    (m, d): (&Material<'_>, &Decoder),
    (passes, mip): (usize, u32),
    batch: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = m.mip_size(mip);
    let n = w as usize * h as usize;
    // `nmat bench`'s order: a stride near 7919 coprime with the texel count.
    let mut stride = 7919 % n.max(1);
    while stride > 1 && gcd(stride, n) != 1 {
        stride += 1;
    }
    let texels: Vec<TexelAt> = (0..n.min(16384))
        .map(|i| {
            let t = i * stride.max(1) % n;
            TexelAt { x: (t % w as usize) as i64, y: (t / w as usize) as i64, mip }
        })
        .collect();
    let mut out = vec![0u8; batch * m.channel_count()];
    let mut groups = Vec::with_capacity(passes * texels.len().div_ceil(256));
    let start = Instant::now();
    for _ in 0..passes {
        for group in texels.chunks(256) {
            let group_start = Instant::now();
            for call in group.chunks(batch) {
                if batch == 1 {
                    let t = call[0];
                    d.decode_texel_u8(m, t.x, t.y, t.mip, ChannelMask::ALL, &mut out)?;
                } else {
                    d.decode_texels_u8(m, call, ChannelMask::ALL, &mut out)?;
                }
            }
            groups.push(group_start.elapsed().as_secs_f64() * 1e9 / group.len() as f64);
        }
    }
    let mean = start.elapsed().as_secs_f64() * 1e9 / (passes * texels.len()).max(1) as f64;
    report(path, mean, d.kernel(), ("256 texels", groups));
    Ok(())
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Prints the mean time per texel, and the fastest and median of the parts (ns per texel).
fn report(path: &str, mean: f64, kernel: Kernel, (part, mut parts): (&str, Vec<f64>)) {
    parts.sort_by(f64::total_cmp);
    println!(
        "{}: {:.1} ns/texel ({}); {}: fastest {:.1}, median {:.1} ns/texel",
        path,
        mean,
        kernel.name(),
        part,
        parts.first().copied().unwrap_or(0.0),
        parts.get(parts.len() / 2).copied().unwrap_or(0.0),
    );
}
