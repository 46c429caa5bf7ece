#!/usr/bin/env bash
# Steps per second of the trainer before its SIMD and memory work (commit 00a4eca: per-sample
# axpys, unfused), the reference of `nmat bench-train`'s speed-up (docs/PERFORMANCE.md,
# "Training"). Builds that commit in a temporary worktree with a small timing example — the same
# material loading, rate solver and training options as that commit's encoder — and prints one
# row per thread count: median steps/s of RUNS runs of STEPS steps (batch 2048, seed 1, its
# phase mix: 80 % joint, 15 % frozen latents, 5 % quantization-aware).
#
# Usage: bench/old_trainer.sh MATERIAL_DIR [PROFILE] [STEPS] [THREADS…]
# Environment: RUNS (default 3), OLD_TARGET_DIR (default target/old-trainer; kept between runs),
# BUILD_ONLY=1 (build the timing example, print its path, time nothing: bench/trainer_speedup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:?usage: bench/old_trainer.sh MATERIAL_DIR [PROFILE] [STEPS] [THREADS…]}
profile=${2:-ntc-0.2}
steps=${3:-200}
shift $(($# < 3 ? $# : 3))
threads=("${@:-1 2}")
runs=${RUNS:-3}
target=$(realpath -m "${OLD_TARGET_DIR:-target/old-trainer}")
work=$(mktemp -d)
trap 'git worktree remove --force "$work/src" >/dev/null 2>&1 || true; rm -rf "$work"' EXIT
git worktree add --detach -q "$work/src" 00a4eca
mkdir -p "$work/src/encoder/examples"
cat > "$work/src/encoder/examples/old_trainer.rs" <<'EOF'
use nmat_core::AddressMode;
use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::train::{Model, TrainOptions};
use nmat_encode::{Profile, configure, shape_of};
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let files = texset::collect_inputs(&[std::path::PathBuf::from(&a[1])]).expect("inputs");
    let roles = texset::assign_roles(&files, &[]).expect("roles");
    let set = texset::load(&roles, &LoadOptions::default()).expect("load");
    let cfg = configure(Profile::by_name(&a[2]).expect("profile"), &shape_of(&set));
    let (steps, threads, runs): (usize, usize, usize) =
        (a[3].parse().unwrap(), a[4].parse().unwrap(), a[5].parse().unwrap());
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    let opts = TrainOptions { steps, ..TrainOptions::default() };
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let mut model = Model::new(&set, &cfg, AddressMode::Wrap, opts.seed);
            let start = Instant::now();
            pool.install(|| model.train(&opts, &mut |_| {}));
            std::hint::black_box(&model.latents);
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    println!("| 00a4eca | {threads} | {:.1} |", steps as f64 / times[runs / 2]);
}
EOF
(cd "$work/src" && CARGO_TARGET_DIR="$target" cargo build --release -q -p nmat-encode --example old_trainer)
if [ -n "${BUILD_ONLY:-}" ]; then
    echo "$target/release/examples/old_trainer"
    exit 0
fi
echo "| trainer | threads | steps/s |"
echo "|---|---:|---:|"
for t in ${threads[*]}; do
    "$target/release/examples/old_trainer" "$dir" "$profile" "$steps" "$t" "$runs"
done
