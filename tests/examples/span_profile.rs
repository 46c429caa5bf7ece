//! Decodes mip 0 of a .nmat file through `Decoder` spans, repeatedly: a steady load to attach a
//! profiler to (`perf record cargo run --release -p nmat-tests --example span_profile -- FILE`). An
//! optional kernel name (`Kernel::name`: `scalar`, `avx2`, `avx512-vnni`, `neon`, …) picks the
//! kernel, e.g. to count instructions under valgrind, which lacks AVX-512; `texel` after it decodes
//! each row texel by texel in a scattered order instead (random access). Prints the mean time per
//! texel of the passes, and the fastest and median time of one row (single rows are short enough
//! that the fastest one is rarely disturbed by other work on a shared machine: the figure to
//! compare two builds with).

use nmat_core::{ChannelMask, Container, Decoder, Kernel};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let usage = "usage: span_profile FILE.nmat [PASSES [KERNEL [texel]]]";
    let path = std::env::args().nth(1).ok_or(usage)?;
    let passes: usize = std::env::args().nth(2).map_or(Ok(5), |s| s.parse())?;
    let kernel = match std::env::args().nth(3) {
        None => Kernel::best(),
        Some(name) => Kernel::ALL.into_iter().find(|k| k.name() == name).ok_or(usage)?,
    };
    let texel_by_texel = match std::env::args().nth(4).as_deref() {
        None => false,
        Some("texel") => true,
        Some(_) => return Err(usage.into()),
    };
    let bytes = std::fs::read(&path)?;
    let m = Container::parse(&bytes)?;
    let d = Decoder::with_kernel(&m, kernel)?;
    let (w, h) = m.mip_size(0);
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
                    d.decode_texel_u8(&m, x, i64::from(y), 0, ChannelMask::ALL, texel)?;
                }
            } else {
                d.decode_span_u8(&m, 0, i64::from(y), 0, w as usize, ChannelMask::ALL, &mut row)?;
            }
            rows.push(row_start.elapsed().as_secs_f64() * 1e9 / f64::from(w));
        }
    }
    let texels = f64::from(w) * f64::from(h) * passes as f64;
    rows.sort_by(f64::total_cmp);
    println!(
        "{}: {:.1} ns/texel ({}); one row: fastest {:.1}, median {:.1} ns/texel",
        path,
        start.elapsed().as_secs_f64() * 1e9 / texels,
        d.kernel().name(),
        rows.first().copied().unwrap_or(0.0),
        rows.get(rows.len() / 2).copied().unwrap_or(0.0),
    );
    Ok(())
}
