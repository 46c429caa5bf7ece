//! Decodes a given number of texels of a `.nmat` file with a given kernel and prints a checksum:
//! the workload of `bench/insn_count.sh`, which counts the instructions the decoder executes per
//! texel under emulation (docs/PERFORMANCE.md, "Phones"). It times nothing.
//!
//! Usage: decode_texels FILE KERNEL MODE TEXELS
//!   KERNEL  scalar | avx2 | avx512-vnni | neon | neon-dotprod (`Kernel::name`)
//!   MODE    region (rows of mip 0 from the top left, `decode_span_u8`) or texel (single texels
//!           on a scattered walk, `decode_texel_u8`); all channels, 8-bit codes.

use std::process::ExitCode;

use nmat_core::{ChannelMask, Container, Decoder, Kernel};

fn main() -> ExitCode {
    match run() {
        Ok(sum) => {
            println!("checksum {sum}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("decode_texels: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<u64, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [file, kernel, mode, texels] = args.as_slice() else {
        return Err("usage: decode_texels FILE KERNEL region|texel TEXELS".into());
    };
    let bytes = std::fs::read(file).map_err(|e| format!("{file}: {e}"))?;
    let m = Container::parse(&bytes).map_err(|e| format!("{file}: {e}"))?;
    let kernel = Kernel::ALL
        .into_iter()
        .find(|k| k.name() == kernel)
        .ok_or_else(|| format!("KERNEL: no kernel named {kernel:?}"))?;
    let d = Decoder::with_kernel(&m, kernel).map_err(|e| format!("KERNEL {kernel:?}: {e}"))?;
    let texels: u64 = texels.parse().map_err(|e| format!("TEXELS {texels:?}: {e}"))?;
    let (w, h) = (u64::from(m.width()), u64::from(m.height()));
    let n = m.channel_count();
    let mut sum = 0u64;
    match mode.as_str() {
        "region" => {
            let mut row = vec![0u8; w as usize * n];
            let mut left = texels;
            for y in (0..h).cycle() {
                if left == 0 {
                    break;
                }
                let count = left.min(w) as usize;
                let all = ChannelMask::ALL;
                d.decode_span_u8(&m, 0, y as i64, 0, count, all, &mut row[..count * n])
                    .map_err(|e| e.to_string())?;
                sum += row[..count * n].iter().map(|&v| u64::from(v)).sum::<u64>();
                left -= count as u64;
            }
        }
        "texel" => {
            let mut out = vec![0u8; n];
            for i in 0..texels {
                // A walk that lands on scattered texels (odd multipliers mod the size).
                let (x, y) = ((i * 7919) % w, (i * 104_729) % h);
                d.decode_texel_u8(&m, x as i64, y as i64, 0, ChannelMask::ALL, &mut out)
                    .map_err(|e| e.to_string())?;
                sum += out.iter().map(|&v| u64::from(v)).sum::<u64>();
            }
        }
        other => return Err(format!("MODE: {other:?} is neither region nor texel")),
    }
    Ok(sum)
}
