//! The output layer refit on the decoder's own hidden activations: once a network is trained and
//! stored, each learned channel's row of the last layer (int8 weights, row scale, bias) is solved
//! again by least squares against the source over every texel of the chain, with the hidden
//! activations the integer decoder computes (docs/ENCODING.md, "The output layer refit").
//!
//! Training fits the layer to float activations, to texels drawn at random (more of them where the
//! error is, weighted back) and, in its quantization-aware phase, to weights rounded at every
//! step; the stored file is judged on every texel of the chain through the integer decoder. The
//! refit closes that gap for the one layer whose loss is a plain quadratic: its output is a linear
//! function of the exact hidden activations.

use crate::texset::TextureSet;
use nmat_core::internals::input_vector;
use nmat_core::{Layer, Material, MlpSpec};
use rayon::prelude::*;

/// Rows of texels summed apart, in parallel.
const BAND: u32 = 16;
/// Sweeps of the integer coordinate descent after rounding (each tries ±1 on every weight).
const SWEEPS: usize = 8;

/// Sums over the chain of `x·xᵀ` and `x·t` for `x` = the hidden activations (unit scale) and a
/// constant 1, `t` each refitted channel's target.
struct Normal {
    /// Inputs of the output layer plus the bias.
    n: usize,
    /// `n × n`, upper triangle filled.
    g: Vec<f64>,
    /// `[row][n]`.
    c: Vec<f64>,
}

impl Normal {
    fn new(n: usize, rows: usize) -> Normal {
        Normal { n, g: vec![0.0; n * n], c: vec![0.0; rows * n] }
    }

    fn add(&mut self, other: &Normal) {
        self.g.iter_mut().zip(&other.g).for_each(|(a, b)| *a += b);
        self.c.iter_mut().zip(&other.c).for_each(|(a, b)| *a += b);
    }

    /// One texel: its activations `x` (the 1 last) and each row's target.
    fn add_sample(&mut self, x: &[f64], targets: impl Iterator<Item = f64>) {
        let n = self.n;
        for (i, &xi) in x.iter().enumerate() {
            for (g, &xj) in self.g[i * n..(i + 1) * n].iter_mut().zip(x).skip(i) {
                *g += xi * xj;
            }
        }
        for (c, t) in self.c.chunks_mut(n).zip(targets) {
            c.iter_mut().zip(x).for_each(|(c, &xj)| *c += xj * t);
        }
    }

    fn full(&self) -> Vec<f64> {
        let n = self.n;
        let mut g = self.g.clone();
        for i in 0..n {
            for j in 0..i {
                g[i * n + j] = g[j * n + i];
            }
        }
        g
    }
}

/// The rows of `material`'s output layer refitted by least squares against `set`'s chain, written
/// into `mlp` (the spec of the same file). Returns whether any row changed. Targets at an end of
/// their range (0 or 1) that the current output passes are not pulled back: the decoder clamps
/// there, so such an output costs nothing.
pub(crate) fn refit_output_layer(
    mlp: &mut MlpSpec,
    material: &Material<'_>,
    set: &TextureSet,
) -> bool {
    let Some(neural) = material.neural() else { return false };
    let layers = neural.mlp().layers();
    let Some((last, hidden)) = layers.split_last() else { return false };
    let inputs = last.inputs();
    let lsb = 2f64.powi(-i32::from(last.in_frac_bits()));
    let rows: Vec<usize> = (0..last.outputs()).filter(|&o| last.scale(o) > 0.0).collect();
    if rows.is_empty() || set.channel_count() != last.outputs() {
        return false;
    }
    let n = inputs + 1;
    let c = set.channel_count();
    let mut normal = Normal::new(n, rows.len());
    for (mip, image) in set.mips.iter().enumerate() {
        // Bands of rows in parallel, summed in band order: the same sums for any thread count.
        let bands: Vec<Normal> = (0..image.height.div_ceil(BAND))
            .into_par_iter()
            .map(|band| {
                let mut acc = Normal::new(n, rows.len());
                let mut x = vec![0f64; n];
                for y in band * BAND..((band + 1) * BAND).min(image.height) {
                    for tx in 0..image.width {
                        let Some(h) = hidden_of(material, hidden, tx, y, mip as u32) else {
                            continue;
                        };
                        for (xi, &v) in x.iter_mut().zip(&h[..inputs]) {
                            *xi = f64::from(v) * lsb;
                        }
                        x[inputs] = 1.0;
                        let texel = (y as usize * image.width as usize + tx as usize) * c;
                        let targets = rows.iter().map(|&o| {
                            let t = f64::from(image.data[texel + o]);
                            let now =
                                f64::from(last.accumulate(o, &h)) * f64::from(last.scale(o)) * lsb;
                            if (t <= 0.0 && now < 0.0) || (t >= 1.0 && now > 1.0) { now } else { t }
                        });
                        acc.add_sample(&x, targets);
                    }
                }
                acc
            })
            .collect();
        bands.iter().for_each(|b| normal.add(b));
    }
    let g = normal.full();
    let Some(chol) = cholesky(&g, n) else { return false };
    let Some(layer) = mlp.layers.last_mut() else { return false };
    let min_scale = crate::train::min_row_scale(last.in_frac_bits(), last.out_frac_bits());
    let bias_limit = crate::train::bias_limit(inputs);
    let mut changed = false;
    for (k, &o) in rows.iter().enumerate() {
        let rhs = &normal.c[k * n..(k + 1) * n];
        let a = solve(&chol, n, rhs);
        let (w, bias_real, scale) = rounded(&g, rhs, &a, inputs, last.in_frac_bits(), min_scale);
        let bias =
            (bias_real / (f64::from(scale) * lsb)).round().clamp(-bias_limit, bias_limit) as i32;
        let row = &mut layer.weights_i8[o * inputs..(o + 1) * inputs];
        changed |= row != w.as_slice() || layer.scales[o] != scale || layer.bias[o] != bias;
        row.copy_from_slice(&w);
        layer.scales[o] = scale;
        layer.bias[o] = bias;
    }
    changed
}

/// The output layer's inputs at texel (x, y) of `mip`: the integer decoder's hidden activations.
fn hidden_of(
    material: &Material<'_>,
    hidden: &[Layer<'_>],
    x: u32,
    y: u32,
    mip: u32,
) -> Option<[i16; nmat_core::limits::MAX_WIDTH]> {
    let mut io = input_vector(material, i64::from(x), i64::from(y), mip)?;
    let mut next = [0i16; nmat_core::limits::MAX_WIDTH];
    for layer in hidden {
        next.iter_mut().for_each(|v| *v = 0);
        for (o, slot) in next.iter_mut().enumerate().take(layer.outputs()) {
            *slot = layer.row_int(o, &io);
        }
        io = next;
    }
    Some(io)
}

/// Weights `a` (unit scale, the bias last) rounded onto int8 with a row scale, then moved by ±1
/// while that lowers the quadratic loss of `g`, `rhs`; the bias re-solved after each sweep.
/// Returns the int8 weights, the bias (unit scale) and the scale.
fn rounded(
    g: &[f64],
    rhs: &[f64],
    a: &[f64],
    inputs: usize,
    in_frac: u8,
    min_scale: f32,
) -> (Vec<i8>, f64, f32) {
    let n = inputs + 1;
    let weights: Vec<f32> = a[..inputs].iter().map(|&v| v as f32).collect();
    let scale = crate::train::row_scale(&weights, a[inputs] as f32, in_frac, min_scale);
    let s = f64::from(scale);
    let mut w: Vec<i32> =
        a[..inputs].iter().map(|&v| (v / s).round().clamp(-127.0, 127.0) as i32).collect();
    // p: the parameters in unit scale; r = G·p − rhs, the half-gradient of the loss.
    let mut p: Vec<f64> = w.iter().map(|&v| f64::from(v) * s).chain([a[inputs]]).collect();
    let mut r: Vec<f64> = (0..n).map(|i| dot(&g[i * n..(i + 1) * n], &p) - rhs[i]).collect();
    let shift = |p: &mut Vec<f64>, r: &mut Vec<f64>, j: usize, d: f64| {
        p[j] += d;
        for (ri, gi) in r.iter_mut().zip(g.iter().skip(j).step_by(n)) {
            *ri += d * gi;
        }
    };
    for _ in 0..SWEEPS {
        let mut moved = false;
        for j in 0..inputs {
            for step in [1i32, -1] {
                while (w[j] + step).abs() <= 127 {
                    let d = f64::from(step) * s;
                    if 2.0 * d * r[j] + d * d * g[j * n + j] >= 0.0 {
                        break;
                    }
                    w[j] += step;
                    shift(&mut p, &mut r, j, d);
                    moved = true;
                }
            }
        }
        let gbb = g[inputs * n + inputs];
        if gbb > 0.0 {
            let d = -r[inputs] / gbb;
            shift(&mut p, &mut r, inputs, d);
        }
        if !moved {
            break;
        }
    }
    (w.iter().map(|&v| v as i8).collect(), p[inputs], scale)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Lower Cholesky factor of `g + λ·I` (λ a small ridge for activations that never fire), or `None`.
fn cholesky(g: &[f64], n: usize) -> Option<Vec<f64>> {
    let top = (0..n).map(|i| g[i * n + i]).fold(0.0f64, f64::max);
    if top <= 0.0 {
        return None;
    }
    let ridge = top * 1e-9;
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let mut sum = g[i * n + j] + if i == j { ridge } else { 0.0 };
            for k in 0..j {
                sum -= l[i * n + k] * l[j * n + k];
            }
            if i == j {
                if sum <= 0.0 {
                    return None;
                }
                l[i * n + i] = sum.sqrt();
            } else {
                l[i * n + j] = sum / l[j * n + j];
            }
        }
    }
    Some(l)
}

/// Solves `L·Lᵀ·a = rhs`.
fn solve(l: &[f64], n: usize, rhs: &[f64]) -> Vec<f64> {
    let mut z = vec![0.0; n];
    for i in 0..n {
        let s: f64 = (0..i).map(|k| l[i * n + k] * z[k]).sum();
        z[i] = (rhs[i] - s) / l[i * n + i];
    }
    let mut a = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| l[k * n + i] * a[k]).sum();
        a[i] = (z[i] - s) / l[i * n + i];
    }
    a
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::train::TrainOptions;
    use crate::{EncodeOptions, Profile, demo, layouts, metrics, shape_of, stored};
    use nmat_core::Container;

    /// The loss of `g`, `rhs` (without its constant) at parameters `p`: `pᵀ·G·p − 2·rhsᵀ·p`.
    fn loss(g: &[f64], rhs: &[f64], p: &[f64]) -> f64 {
        let n = p.len();
        (0..n).map(|i| p[i] * (dot(&g[i * n..(i + 1) * n], p) - 2.0 * rhs[i])).sum()
    }

    #[test]
    fn least_squares_solves_the_normal_equations() {
        // G = AᵀA for A with rows (1,0,1), (1,1,1), (2,1,1), (0,3,1); rhs = G·(0.5, −2, 3).
        let rows = [[1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [0.0, 3.0, 1.0]];
        let want = [0.5, -2.0, 3.0];
        let mut g = vec![0.0; 9];
        for r in &rows {
            for i in 0..3 {
                for j in 0..3 {
                    g[i * 3 + j] += r[i] * r[j];
                }
            }
        }
        let rhs: Vec<f64> = (0..3).map(|i| dot(&g[i * 3..i * 3 + 3], &want)).collect();
        let a = solve(&cholesky(&g, 3).unwrap(), 3, &rhs);
        for (got, want) in a.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{a:?}");
        }
        assert!(cholesky(&[0.0; 4], 2).is_none(), "an all-zero system has no solution");
    }

    #[test]
    fn rounded_weights_are_a_local_optimum_of_the_lattice() {
        // A random positive definite system of 6 weights and a bias: no single ±1 step of a
        // weight, and no other bias, lowers the loss of what `rounded` returns.
        let n = 7;
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let samples: Vec<Vec<f64>> = (0..200)
            .map(|_| (0..n).map(|i| if i == n - 1 { 1.0 } else { next() }).collect())
            .collect();
        let mut g = vec![0.0; n * n];
        let mut rhs = vec![0.0; n];
        for x in &samples {
            let t = 0.3 * x[0] - 0.7 * x[3] + 0.05 * x[5] + 0.4 + 0.01 * next();
            for i in 0..n {
                rhs[i] += x[i] * t;
                for j in 0..n {
                    g[i * n + j] += x[i] * x[j];
                }
            }
        }
        let a = solve(&cholesky(&g, n).unwrap(), n, &rhs);
        let (w, bias, scale) = rounded(&g, &rhs, &a, n - 1, 8, 1e-6);
        let s = f64::from(scale);
        let p: Vec<f64> = w.iter().map(|&v| f64::from(v) * s).chain([bias]).collect();
        let at = loss(&g, &rhs, &p);
        for j in 0..n - 1 {
            for step in [-1.0, 1.0] {
                if (f64::from(w[j]) + step).abs() > 127.0 {
                    continue;
                }
                let mut q = p.clone();
                q[j] += step * s;
                assert!(loss(&g, &rhs, &q) >= at - 1e-12, "weight {j} {step:+}");
            }
        }
        for d in [-1e-3, 1e-3] {
            let mut q = p.clone();
            q[n - 1] += d;
            assert!(loss(&g, &rhs, &q) >= at - 1e-12, "bias {d:+}");
        }
        // And the rounding costs little against the float optimum.
        let best = loss(&g, &rhs, &a);
        assert!(at - best < 0.01 * (-best), "{at} against {best}");
    }

    /// `set` trained at `ntc-0.2` for `steps` with `seed`, as training leaves it (before the
    /// refit): its spec and file.
    pub(crate) fn trained_spec(
        set: &TextureSet,
        steps: usize,
        seed: u64,
    ) -> (nmat_core::MaterialSpec, crate::Encoded) {
        let options = EncodeOptions {
            profile: Profile::by_name("ntc-0.2").unwrap(),
            train: TrainOptions { steps, seed, ..TrainOptions::default() },
            ..EncodeOptions::default()
        };
        let layout =
            layouts(options.profile, &shape_of(set), options.storage, 1.0).unwrap().swap_remove(0);
        stored(set, &options, &layout, &options.train, &mut |_| {}).unwrap()
    }

    #[test]
    fn a_refit_recovers_an_output_layer_wiped_out() {
        // A trained material whose output rows are all zeroed decodes to flat ranges; refitted
        // on its hidden activations, it decodes at least as well as the trained layer did (the
        // least-squares layer on the integer decoder's own activations, over the whole chain).
        let set = demo::bricks(32);
        let (mut spec, encoded) = trained_spec(&set, 150, 4);
        let trained = encoded.quality.psnr;
        let last = spec.mlp.layers.last_mut().unwrap();
        last.weights_i8.iter_mut().for_each(|w| *w = 0);
        last.bias.iter_mut().for_each(|b| *b = 0);
        let wiped = spec.to_bytes().unwrap();
        let wiped_db = metrics::chain_quality(&Container::parse(&wiped).unwrap(), &set).psnr;
        let material = Container::parse(&wiped).unwrap();
        assert!(refit_output_layer(&mut spec.mlp, &material, &set));
        let refitted = spec.to_bytes().unwrap();
        let db = metrics::chain_quality(&Container::parse(&refitted).unwrap(), &set).psnr;
        eprintln!("trained {trained:.3} dB, wiped {wiped_db:.3}, refitted {db:.3}");
        assert!(
            wiped_db < trained - 6.0,
            "wiping the layer should cost: {wiped_db} against {trained}"
        );
        assert!(db > trained - 0.02, "refitted {db} dB against the trained layer's {trained}");
    }
}
