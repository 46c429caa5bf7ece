//! The CPU trainer (docs/ENCODING.md): latents and MLP optimized jointly with Adam and a cosine
//! schedule under simulated quantization (uniform noise), then latents frozen at their quantized
//! values while the MLP is fine-tuned, then quantization-aware fine-tuning of the int8 weights
//! (straight-through estimator) so the integer decoder is the trained model.
//!
//! Forward and backward are written by hand (the NTC paper's own trainer was 10× faster than a
//! general framework): a chunk of samples goes through each layer as one matrix product on the
//! SIMD kernels of `gemm` (fixed fma chains: the same bits on every kernel). A step's batch is
//! cut into fixed chunks processed in parallel; their gradients are summed in chunk order, so the
//! result is the same for any number of threads and any kernel.

mod adam;
mod export;
mod latents;
mod layers;
mod model;
mod options;
mod rng;
mod sampler;

pub use export::{bias_limit, export_layer, frac_bits_for, min_row_scale};
pub(crate) use latents::coded_bytes;
pub(crate) use layers::row_scale;
pub use model::Model;
pub use options::{DEFAULT_STEPS, Effort, Phase, Progress, TrainOptions, mlp_flops_per_sample};

/// Fraction bits of the MLP input: latents span ±1.5, fusion chains of 4 grids ±6, within ±8.
pub const INPUT_FRAC_BITS: u8 = 12;
/// Fraction bits of the last layer: outputs are unit values, Q.13 holds ±4.
pub const OUTPUT_FRAC_BITS: u8 = 13;
/// The LOD feature's code (docs/FORMAT.md §6.5): `mip / 2`, the largest scale the Q.12 input
/// holds at every mip. At `mip / 16` (code 1, formats before 2.3) the first layer's weights on
/// the feature grew to the whole int8 range of most rows, leaving the latents' weights 3 bits:
/// the int8 network lost 3–4 dB against the float one on noisy 1024² materials at `ntc-1.0`.
pub const LOD_CODE: u8 = 4;
/// Latents are dequantized onto [−SPAN, SPAN].
const SPAN: f64 = 1.5;
/// Samples per parallel work item (fixed: it, not the thread count, shapes the arithmetic).
const CHUNK: usize = 256;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::memhint::huge_vec;
    use latents::{GridState, LATENT_BUCKETS, LatentBuckets, latent_bucket_edges, split_at_edges};
    use layers::Dense;
    use nmat_core::Activation;

    #[test]
    fn a_row_carried_by_its_bias_survives_export() {
        // Dead weights, a live bias: the int8 scale must still express the bias.
        for (w, b) in [(1e-12f32, 0.7f32), (0.0, -3.0), (0.5, 0.25), (1e-6, 5.0)] {
            let layer = Dense { inputs: 64, outputs: 1, hidden: true, w: vec![w; 64], b: vec![b] };
            for in_frac in [10u8, 12, 14] {
                let spec = export_layer(&layer, in_frac, 12, &[Some(0)], Activation::HardGelu);
                let lsb = 1.0 / f64::from(1u32 << in_frac);
                let real_bias = f64::from(spec.bias[0]) * f64::from(spec.scales[0]) * lsb;
                assert!(
                    (real_bias - f64::from(b)).abs() < 1e-3 * f64::from(b.abs()).max(1.0),
                    "w {w} b {b}: {real_bias}"
                );
                let limit = f64::from(i32::MAX) - 64.0 * 127.0 * 32768.0;
                assert!(f64::from(spec.bias[0]).abs() <= limit);
            }
        }
    }
    fn grid(width: u32, height: u32, channels: usize, base: usize) -> GridState {
        GridState { width, height, channels, bits: 2, base, offset_q: 0, step_q: 1 }
    }

    #[test]
    fn latent_buckets_hold_whole_cells_and_cover_every_latent() {
        // Grids of 9, 5 and 9 channels, small enough to check every latent; the last pair has
        // fewer latents than buckets.
        for sizes in [vec![(17, 13, 9), (9, 7, 5), (1, 1, 9)], vec![(1, 1, 9), (1, 1, 5)]] {
            let mut grids = Vec::new();
            let mut base = 0;
            for (w, h, c) in sizes {
                grids.push(grid(w, h, c, base));
                base += (w * h) as usize * c;
            }
            let buckets = LatentBuckets::new(latent_bucket_edges(&grids));
            let edges = &buckets.edges;
            assert_eq!(edges.len(), LATENT_BUCKETS + 1);
            assert_eq!((edges[0], edges[LATENT_BUCKETS]), (0, base));
            assert!(edges.windows(2).all(|w| w[0] <= w[1]), "{edges:?}");
            for &e in &edges[..LATENT_BUCKETS] {
                let g = grids.iter().rev().find(|g| g.base <= e).unwrap();
                assert_eq!((e - g.base) % g.channels, 0, "edge {e} splits a cell: {edges:?}");
            }
            for latent in 0..base {
                let k = buckets.of(latent as u32);
                assert!(edges[k] <= latent && latent < edges[k + 1], "{latent} in {k}: {edges:?}");
            }
            let mut values: Vec<usize> = (0..base).collect();
            let parts = split_at_edges(&mut values, edges);
            for (k, part) in parts.iter().enumerate() {
                assert_eq!(part.first().copied(), (edges[k] < edges[k + 1]).then_some(edges[k]));
                assert_eq!(part.len(), edges[k + 1] - edges[k]);
            }
        }
    }

    #[test]
    fn effort_trades_a_quarter_or_twice_the_steps() {
        assert_eq!(Effort::Fast.schedule(30_000, 2048), (7_500, 2048));
        assert_eq!(Effort::Fast.schedule(3, 2048), (1, 2048));
        assert_eq!(Effort::Default.schedule(30_000, 2048), (30_000, 2048));
        assert_eq!(Effort::Max.schedule(30_000, 2048), (60_000, 2048));
        assert_eq!(Effort::Max.schedule(usize::MAX, 2048), (usize::MAX, 2048));
    }

    #[test]
    fn the_quantization_aware_phase_has_a_learning_rate_schedule_of_its_own() {
        let o =
            TrainOptions { steps: 1000, joint_percent: 90, qat_percent: 10, ..Default::default() };
        let (lr, start) = (o.lr_mlp, o.qat_start());
        assert_eq!(
            (start, o.phase(start - 1), o.phase(start)),
            (900, Phase::Joint, Phase::QuantizationAware)
        );
        // The phase runs its own cosine from qat_lr · lr_mlp down to 1 % of that; the main
        // schedule never goes below 1 % of lr_mlp.
        assert_eq!(o.mlp_lr(start), o.qat_lr * lr);
        let tail = o.mlp_lr(999);
        assert!(tail < o.mlp_lr(950) && tail < 0.011 * o.qat_lr * lr, "{tail}");
        assert!((0..start).all(|s| o.mlp_lr(s) >= 0.01 * lr));
        // A frozen-latents phase between keeps the main schedule.
        let f = TrainOptions { qat_percent: 3, ..o.clone() };
        assert_eq!((f.qat_start(), f.phase(950)), (970, Phase::FrozenLatents));
        assert!(f.mlp_lr(969) >= 0.01 * lr && f.mlp_lr(970) == f.qat_lr * lr);
        // Latents train in the joint phase, and in the quantization-aware one only when asked
        // to, on a cosine of their own.
        assert!(o.latents_train(start - 1) && !o.latents_train(start));
        let q = TrainOptions { qat_lr_latents: 0.1, ..o.clone() };
        assert!(q.latents_train(start) && !f.latents_train(950));
        assert_eq!(q.latent_lr(start), 0.1 * q.lr_latents);
        assert!(q.latent_lr(999) < 0.011 * 0.1 * q.lr_latents);
    }

    /// `nmat bench-train`'s work count: a step whose latents train also pays the first layer's
    /// input gradients (its input width × first hidden width multiply-adds, 2 flops each), in the
    /// quantization-aware phase too when `qat_lr_latents` > 0.
    #[test]
    fn flops_count_the_first_layers_input_gradients_while_latents_train() {
        use crate::profile::{MaterialShape, Profile, configure};
        let shape = MaterialShape {
            width: 256,
            height: 256,
            mip_count: 9,
            channels: 8,
            learned: 8,
            optional_bytes: 0,
        };
        let cfg = configure(Profile::by_name("ntc-0.2").unwrap(), &shape);
        let first = 2 * (cfg.input_width() * cfg.hidden[0]) as u64;
        assert_eq!(mlp_flops_per_sample(&cfg, true) - mlp_flops_per_sample(&cfg, false), first);
        let o = TrainOptions { steps: 1000, ..TrainOptions::default() };
        let q = TrainOptions { qat_lr_latents: 0.1, ..o.clone() };
        let qat = o.qat_start();
        let per_step = |t: &TrainOptions, s| mlp_flops_per_sample(&cfg, t.latents_train(s));
        assert_eq!(per_step(&o, 0), per_step(&q, qat));
        assert_eq!(per_step(&o, qat) + first, per_step(&q, qat));
    }

    #[test]
    fn int8_weights_run_in_the_last_int8_percent_and_the_quantization_aware_phase() {
        let o = TrainOptions { steps: 1000, ..Default::default() };
        // The default: exactly the quantization-aware phase, whatever its length.
        for qat_percent in [10, 3, 0] {
            let q = TrainOptions { qat_percent, ..o.clone() };
            assert!(
                (0..1000).all(|s| q.int8_weights(s) == (q.phase(s) == Phase::QuantizationAware))
            );
            let short = TrainOptions { int8_percent: 2, ..q.clone() };
            assert_eq!(short.int8_weights(979), q.int8_weights(979));
            assert!(short.int8_weights(980));
        }
        let all = TrainOptions { int8_percent: 100, ..o.clone() };
        assert!((0..1000).all(|s| all.int8_weights(s)));
        let third = TrainOptions { int8_percent: 30, ..o.clone() };
        assert!(!third.int8_weights(699) && third.int8_weights(700));
        assert_eq!(third.phase(700), Phase::Joint);
        // Above 100 is all of them, not an overflow.
        assert!(TrainOptions { int8_percent: 250, ..o }.int8_weights(0));
    }

    #[test]
    fn the_rate_pull_takes_the_latents_the_loss_hardly_feels() {
        // Two cells of a 4-bit grid at 0.8, one with a gradient 1000 times the other's, both
        // pointing away from the middle code (8/15). Adam's first step moves both by its
        // learning rate alike; the pull, scaled back by each latent's √v̂ against a typical
        // 0.01, takes the weak cell to the middle code and hardly slows the strong one.
        let grids = [GridState { bits: 4, ..grid(2, 1, 2, 0) }];
        let center = 8.0 / 15.0;
        let mut state = latents::LatentState::new(4);
        let mut values = vec![0.8f32; 4];
        let mut buckets: Vec<Vec<latents::CellGrad>> = vec![Vec::new(); LATENT_BUCKETS];
        buckets[0] = vec![
            latents::CellGrad { latent: 0, at: 0, channels: 2 },
            latents::CellGrad { latent: 2, at: 2, channels: 2 },
        ];
        let grads = model::Grads {
            w: Vec::new(),
            b: Vec::new(),
            latents: buckets,
            latent_grads: vec![-1.0, -1.0, -1e-3, -1e-3],
            loss: 0.0,
            sample_errors: Vec::new(),
        };
        let (lr, edges) = (0.04f32, [0, 4]);
        let update = model::LatentUpdate {
            inv: 1.0,
            adam: adam::AdamStep::new(lr, 1),
            shrink: lr,
            scale: 0.01,
            centers: &[(0, center)],
        };
        let range = state.split(&mut values, &edges).pop().unwrap();
        update.apply(std::slice::from_ref(&grads), (0, 0), range);
        assert!(values[..2].iter().all(|&v| v > 0.8 + 0.9 * lr), "strong cell: {values:?}");
        assert!(values[2..].iter().all(|&v| v == center), "weak cell: {values:?}");

        // The typical √v̂ is the mean over the latents that had a gradient (here v = g² / 1000
        // after one step, c2 = 1/1000: √v̂ = |g|).
        let mean = state.mean_step_scale(&grids, adam::AdamStep::new(0.0, 1));
        assert!((mean - (1.0 + 1e-3) / 2.0).abs() < 1e-6, "{mean}");
    }

    #[test]
    fn outputs_past_the_end_their_target_sits_at_cost_nothing_within_the_margin() {
        use model::output_error;
        // No margin: the plain error, bit for bit (files trained without it do not change).
        for (y, t) in [(1.3f32, 1.0f32), (0.37, 0.61), (-0.2, 0.0), (0.1 + 0.2, 0.3)] {
            assert_eq!(output_error(y, t, 0.0).to_bits(), (y - t).to_bits());
        }
        let m = 0.02;
        // Past the end the target sits at, within the margin: decoded exactly, no error.
        assert_eq!(output_error(1.01, 1.0, m), 0.0);
        assert_eq!(output_error(-0.015, 0.0, m), 0.0);
        // Beyond the margin: only the excess counts, pulling the output back.
        assert!((output_error(1.05, 1.0, m) - 0.03).abs() < 1e-6);
        assert!((output_error(-0.1, 0.0, m) + 0.08).abs() < 1e-6);
        // A target inside the range: the clamped output's error (what a decoder shows), plus
        // any excess.
        assert!((output_error(1.01, 0.9, m) - 0.1).abs() < 1e-6);
        assert!((output_error(1.1, 0.9, m) - 0.18).abs() < 1e-6);
        // Inside the range the margin changes nothing.
        assert!((output_error(0.4, 0.7, m) + 0.3).abs() < 1e-6);
    }

    #[test]
    fn huge_vectors_hold_their_values() {
        // Large enough to span several 2 MiB blocks, whatever the allocation's alignment.
        let n = (5 << 20) + 3;
        let v = huge_vec(n, 0.25f32);
        assert_eq!(v.len(), n);
        assert!(v.iter().all(|&x| x == 0.25));
    }
}
