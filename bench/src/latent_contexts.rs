//! What other context models would make of trained latents: the coding cost (Σ −log2 p of every
//! binary decision, what an ideal arithmetic coder spends) of each grid channel under the model of
//! docs/FORMAT.md §12.2–12.3 and under richer ones, relative to that model — to argue which
//! contexts the packed format should have (docs/FORMAT.md §12.4).
//!
//! Usage: nmat-latent-contexts FILE.nmat...   (packed or fixed-rate neural materials)
//!
//! Every model codes a code as §12.2 does — its bits from the most significant down along a
//! binary tree, one adaptive 12-bit probability per (context, node), reset per grid channel — and
//! differs only in the context or in how probabilities adapt. The first column, the format's own
//! model simulated, is checked against the real coder's output (`coded_latents_len`).

use nmat_core::{Container, Material, ParseOptions};
use std::process::ExitCode;

/// A grid's codes, cell-major with channels innermost (docs/FORMAT.md §4.1).
struct Grid {
    width: usize,
    height: usize,
    channels: usize,
    bits: u32,
    codes: Vec<u8>,
}

impl Grid {
    fn at(&self, x: usize, y: usize, c: usize) -> u32 {
        u32::from(self.codes[(y * self.width + x) * self.channels + c])
    }
}

/// The format's neighbour class (§12.2): the two most significant bits; 4 for no neighbour.
fn class(code: Option<u32>, bits: u32) -> usize {
    match code {
        None => 4,
        Some(u) if bits > 2 => (u >> (bits - 2)) as usize,
        Some(u) => u as usize,
    }
}

#[derive(Clone, Copy)]
enum Model {
    /// The format's: classes of the left and upper neighbours.
    Format,
    /// + the upper-left neighbour's class.
    UpLeft,
    /// + the upper-left and upper-right neighbours' classes.
    UpLeftRight,
    /// + the class of the same cell's previous channel.
    PreviousChannel,
    /// The left and upper neighbours' codes themselves (their 4 most significant bits).
    FullNeighbours,
    /// + whether the four causal neighbours are equal (a flat area).
    Flat,
    /// The format's contexts, each probability the mean of a fast (shift 4) and a slow (shift 7)
    /// estimate.
    TwoRates,
}

const MODELS: [(Model, &str); 7] = [
    (Model::Format, "format (left, up)"),
    (Model::UpLeft, "+ up-left"),
    (Model::UpLeftRight, "+ up-left, up-right"),
    (Model::PreviousChannel, "+ previous channel"),
    (Model::FullNeighbours, "left, up: 4 bits each"),
    (Model::Flat, "+ flat neighbourhood"),
    (Model::TwoRates, "two adaptation rates"),
];

fn context(model: Model, g: &Grid, x: usize, y: usize, c: usize) -> usize {
    let b = g.bits;
    let left = (x > 0).then(|| g.at(x - 1, y, c));
    let up = (y > 0).then(|| g.at(x, y - 1, c));
    let up_left = (x > 0 && y > 0).then(|| g.at(x - 1, y - 1, c));
    let up_right = (y > 0 && x + 1 < g.width).then(|| g.at(x + 1, y - 1, c));
    let pair = class(left, b) * 5 + class(up, b);
    match model {
        Model::Format | Model::TwoRates => pair,
        Model::UpLeft => pair * 5 + class(up_left, b),
        Model::UpLeftRight => (pair * 5 + class(up_left, b)) * 5 + class(up_right, b),
        Model::PreviousChannel => pair * 5 + class((c > 0).then(|| g.at(x, y, c - 1)), b),
        Model::FullNeighbours => {
            let top4 = |u: Option<u32>| u.map_or(16, |u| (u >> b.saturating_sub(4)) as usize);
            top4(left) * 17 + top4(up)
        }
        Model::Flat => {
            let flat = left.is_some() && [up, up_left, up_right].iter().all(|&n| n == left);
            pair * 2 + usize::from(flat)
        }
    }
}

/// Bits an ideal coder spends on `g` under `model`.
fn cost(model: Model, g: &Grid) -> f64 {
    const ONE: f64 = 4096.0;
    let nodes = 1usize << g.bits;
    let mut total = 0.0;
    for c in 0..g.channels {
        // (fast, slow) probabilities of a 0, in 1/65536, per (context, node); the format's model
        // uses the first as its 12-bit probability (in units of 16).
        let mut p: Vec<[u32; 2]> = vec![[2048 << 4; 2]; 8192 * nodes];
        for y in 0..g.height {
            for x in 0..g.width {
                let ctx = context(model, g, x, y, c);
                let v = g.at(x, y, c);
                let mut node = 1usize;
                for k in (0..g.bits).rev() {
                    let bit = (v >> k) & 1;
                    let slot = &mut p[ctx * nodes + node];
                    let p0 = match model {
                        Model::TwoRates => {
                            let mean = f64::from(slot[0] + slot[1]) / 2.0 / 65536.0;
                            mean.clamp(31.0 / ONE, 4065.0 / ONE)
                        }
                        _ => f64::from(slot[0] >> 4) / ONE,
                    };
                    total -= if bit == 0 { p0 } else { 1.0 - p0 }.log2();
                    match model {
                        Model::TwoRates => {
                            for (s, shift) in slot.iter_mut().zip([4, 7]) {
                                if bit == 0 {
                                    *s += (65535 - *s) >> shift
                                } else {
                                    *s -= *s >> shift
                                }
                            }
                        }
                        _ => {
                            // §12.3 exactly: 12-bit p, shift 5.
                            let mut q = slot[0] >> 4;
                            if bit == 0 {
                                q += (4096 - q) >> 5
                            } else {
                                q -= q >> 5
                            }
                            slot[0] = q << 4;
                        }
                    }
                    node = 2 * node + bit as usize;
                }
            }
        }
    }
    total
}

fn grids(material: &Material<'_>) -> Option<Vec<Grid>> {
    let neural = material.neural()?;
    Some(
        neural
            .grids()
            .iter()
            .map(|g| {
                let (w, h, ch) = (g.width() as usize, g.height() as usize, g.channels());
                let mut codes = Vec::with_capacity(w * h * ch);
                for y in 0..h {
                    for x in 0..w {
                        for c in 0..ch {
                            codes.push(g.code(x as u32, y as u32, c));
                        }
                    }
                }
                Grid { width: w, height: h, channels: ch, bits: g.bits_per_latent(), codes }
            })
            .collect(),
    )
}

/// What the packed format's coder writes for `grids` (docs/FORMAT.md §12.3), in bytes.
fn coded_len(grids: &[Grid]) -> usize {
    let grids: Vec<(u32, u32, u32, u32, &[u8])> = grids
        .iter()
        .map(|g| (g.width as u32, g.height as u32, g.channels as u32, g.bits, &g.codes[..]))
        .collect();
    nmat_core::internals::coded_latents_len(&grids)
}

fn run(path: &str) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let options = ParseOptions::default();
    let unpacked = nmat_core::unpack(&bytes, options).map_err(|e| format!("{path}: {e}"))?;
    let material = Container::parse_with(&unpacked, options).map_err(|e| format!("{path}: {e}"))?;
    let grids = grids(&material).ok_or_else(|| format!("{path}: not a neural material"))?;
    let fixed: usize = grids.iter().map(|g| (g.codes.len() * g.bits as usize).div_ceil(8)).sum();
    let coded = coded_len(&grids);
    let costs: Vec<f64> =
        MODELS.iter().map(|&(m, _)| grids.iter().map(|g| cost(m, g)).sum()).collect();
    let base = costs[0] / 8.0;
    println!(
        "{path}: latents {fixed} bytes fixed-rate, coded {coded} ({:.3}); format's model simulated {base:.0} bytes",
        coded as f64 / fixed as f64
    );
    for (&(_, name), c) in MODELS.iter().zip(&costs) {
        println!("  {name:<24} {:>9.0} bytes  {:.4} of the format's", c / 8.0, c / costs[0]);
    }
    Ok(())
}

fn main() -> ExitCode {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() || paths.iter().any(|p| p == "-h" || p == "--help") {
        eprintln!("usage: nmat-latent-contexts FILE.nmat...");
        return ExitCode::from(2);
    }
    for p in &paths {
        if let Err(e) = run(p) {
            eprintln!("nmat-latent-contexts: {e}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Codes with some structure (runs and a drift), as trained latents have, from a fixed LCG.
    fn grid(width: usize, height: usize, channels: usize, bits: u32, seed: u64) -> Grid {
        let mut s = seed;
        let mut codes = Vec::with_capacity(width * height * channels);
        let max = (1u64 << bits) - 1;
        for i in 0..width * height * channels {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let r = s >> 33;
            let v = if r.is_multiple_of(4) {
                r % (max + 1)
            } else {
                (max / 2 + (i as u64 / 97) % 2).min(max)
            };
            codes.push(v as u8);
        }
        Grid { width, height, channels, bits, codes }
    }

    #[test]
    fn the_formats_model_costs_what_the_coder_writes() {
        let grids = [grid(37, 21, 3, 2, 1), grid(16, 9, 5, 4, 2), grid(5, 7, 2, 8, 3)];
        let coded = coded_len(&grids) as f64;
        let simulated: f64 = grids.iter().map(|g| cost(Model::Format, g)).sum::<f64>() / 8.0;
        // The coder adds its 4-byte start and a byte of flush to the ideal cost.
        assert!((coded - simulated).abs() <= 8.0, "coded {coded} bytes, simulated {simulated:.1}");
        // A richer model is a different number: the comparison can tell them apart.
        let two_rates: f64 = grids.iter().map(|g| cost(Model::TwoRates, g)).sum::<f64>() / 8.0;
        assert!((two_rates - simulated).abs() > 1.0);
    }
}
