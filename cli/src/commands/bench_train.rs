//! `nmat bench-train`: the trainer's throughput (docs/PERFORMANCE.md, "Training"). For every
//! matrix-product kernel this CPU runs and every thread count asked for, a fixed number of
//! optimizer steps on one material and profile: steps and samples per second, the MLP's useful
//! GFLOP/s (`train::mlp_flops_per_sample`) and its share of the f32 FMA peak measured in the same
//! run with the same number of threads.

use crate::args::BenchTrainArgs;
use crate::common::{Result, check_threads, profile_named};
use nmat_cli::stats::median;
use nmat_core::AddressMode;
use nmat_encode::internals::{Model, mlp_flops_per_sample};
use nmat_encode::texset::TextureSet;
use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::{Profile, TrainKernel, TrainOptions, configure, shape_of};
use std::hint::black_box;
use std::time::Instant;

pub fn run(args: BenchTrainArgs) -> Result<()> {
    let BenchTrainArgs { inputs, profile, steps, threads, kernel, runs, phases, memory } = args;
    if steps == 0 || runs == 0 {
        return Err("--steps and --runs must be at least 1".into());
    }
    let defaults = TrainOptions::default();
    let (joint_percent, qat_percent) = match phases.as_deref() {
        None => (defaults.joint_percent, defaults.qat_percent),
        Some(&[joint, qat]) if joint + qat <= 100 => (joint, qat),
        Some(p) => {
            return Err(format!(
                "--phases {p:?}: give JOINT,QAT, two percents summing to at most 100"
            )
            .into());
        }
    };
    for &t in &threads {
        check_threads(t)?;
    }
    let kernels = if kernel.iter().any(|k| k == "all") {
        TrainKernel::ALL.into_iter().filter(|k| k.is_available()).collect()
    } else {
        kernel
            .iter()
            .map(|name| {
                let k = TrainKernel::by_name(name).ok_or_else(|| {
                    let names: Vec<&str> = TrainKernel::ALL.iter().map(|k| k.name()).collect();
                    format!("--kernel {name}: unknown; choose all or any of {}", names.join(", "))
                })?;
                if !k.is_available() {
                    return Err(format!("--kernel {name}: this CPU cannot run it"));
                }
                Ok(k)
            })
            .collect::<std::result::Result<Vec<_>, _>>()?
    };
    let (set, label) = if inputs.is_empty() {
        (nmat_encode::demo::bricks(1024), "the bundled procedural material".to_string())
    } else {
        let files = texset::collect_inputs(&inputs)?;
        let roles = texset::assign_roles(&files, &[])?;
        let label = inputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ");
        let options = LoadOptions { max_memory: memory.bytes(), ..LoadOptions::default() };
        (texset::load(&roles, &options)?, label)
    };
    measure(&Options {
        set,
        label,
        profile: profile_named(&profile)?,
        steps,
        threads,
        kernels,
        runs,
        joint_percent,
        qat_percent,
    })
}

/// What to measure.
struct Options {
    pub set: TextureSet,
    /// Shown in the header: where the material came from.
    pub label: String,
    pub profile: Profile,
    pub steps: usize,
    pub threads: Vec<usize>,
    pub kernels: Vec<TrainKernel>,
    /// Timed runs per row; the median is reported.
    pub runs: usize,
    /// The phase mix ([`TrainOptions::joint_percent`], [`TrainOptions::qat_percent`]).
    pub joint_percent: u32,
    pub qat_percent: u32,
}

/// f32 FMA peak of `kernel` on `threads` threads running its probe at once, in FLOP/s (2 per
/// fused multiply-add; median of 5).
fn fma_peak(kernel: TrainKernel, threads: usize) -> f64 {
    let rounds = 200_000_000 / kernel.probe_fmas_per_round().max(1);
    median((0..5).map(|_| {
        let start = Instant::now();
        std::thread::scope(|s| {
            for _ in 0..threads {
                s.spawn(|| black_box(kernel.probe(black_box(rounds))));
            }
        });
        (threads as u64 * rounds * kernel.probe_fmas_per_round() * 2) as f64
            / start.elapsed().as_secs_f64()
    }))
}

/// The table of `o`.
fn measure(o: &Options) -> Result<()> {
    let start = Instant::now();
    let cfg = configure(o.profile, &shape_of(&o.set));
    let base = TrainOptions {
        steps: o.steps,
        joint_percent: o.joint_percent,
        qat_percent: o.qat_percent,
        ..TrainOptions::default()
    };
    let batch = base.batch;
    let flops: u64 = (0..o.steps)
        .map(|s| mlp_flops_per_sample(&cfg, base.latents_train(s)) * batch as u64)
        .sum();
    println!(
        "material: {} ({}×{}, {} channels), profile {}, network {} → {:?} → {}, batch {batch}, {} steps per run ({} % joint, {} % quantization-aware), median of {}",
        o.label,
        o.set.width,
        o.set.height,
        o.set.channel_count(),
        o.profile.name(),
        cfg.input_width(),
        cfg.hidden,
        cfg.outputs,
        o.steps,
        base.joint_percent,
        base.qat_percent,
        o.runs
    );
    println!(
        "MLP work: {:.1} kFLOP per sample on average ({} GFLOP per run)",
        flops as f64 / (o.steps * batch) as f64 / 1e3,
        flops / 1_000_000_000
    );
    let best = TrainKernel::best();
    let peaks: Vec<(usize, f64)> = o.threads.iter().map(|&t| (t, fma_peak(best, t))).collect();
    for (t, p) in &peaks {
        println!(
            "f32 FMA peak ({} probe, {t} thread{}): {:.1} GFLOP/s",
            best.name(),
            if *t == 1 { "" } else { "s" },
            p / 1e9
        );
    }
    println!();
    println!("| kernel | threads | steps/s | samples/s | MLP GFLOP/s | % of FMA peak |");
    println!("|---|---:|---:|---:|---:|---:|");
    for &kernel in &o.kernels {
        for &(threads, peak) in &peaks {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
            let opts = TrainOptions { kernel: Some(kernel), ..base.clone() };
            let times: Vec<f64> = (0..o.runs)
                .map(|_| {
                    let mut model = Model::new(&o.set, &cfg, AddressMode::Wrap, &opts);
                    let start = Instant::now();
                    pool.install(|| model.train(&opts, &mut |_| {}));
                    black_box(&model.latents);
                    start.elapsed().as_secs_f64()
                })
                .collect();
            let t = median(times);
            let gflops = flops as f64 / t / 1e9;
            println!(
                "| {} | {threads} | {:.1} | {:.0} | {:.1} | {:.1} |",
                kernel.name(),
                o.steps as f64 / t,
                (o.steps * batch) as f64 / t,
                gflops,
                100.0 * gflops * 1e9 / peak
            );
        }
    }
    println!("\nmeasured in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}
