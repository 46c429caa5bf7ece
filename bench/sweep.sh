#!/usr/bin/env bash
# Sweeps the trainer's knobs on part of the development set (docs/ENCODING.md, "Tuning"): each
# variant changes one knob from the defaults (the list brackets today's values); nmat-sweep
# prints per-material rows and a summary (mean ΔPSNR against the defaults at the same rate, wins,
# losses, seconds). Resumable: rows are
# appended to OUT_DIR/sweep.csv and not measured again.
#
# Usage: bench/sweep.sh [DEV_DIR] [OUT_DIR]
#   DEV_DIR   materials from bench/dev-materials.sh (default ~/.cache/nmat-dev)
#   OUT_DIR   default target/sweep
# Environment: MATERIALS (default: two 1024² and three 512² materials, 2–4 maps each), PROFILES
# (default: ntc-0.2 nbc-0.1), THREADS (default 2), VARIANTS (default: the list below).
set -euo pipefail
cd "$(dirname "$0")/.."
dev=${1:-$HOME/.cache/nmat-dev}
out=${2:-target/sweep}
materials=${MATERIALS:-"bigplate cretefloor grass rock largebrick"}
profiles=${PROFILES:-"ntc-0.2 nbc-0.1"}
threads=${THREADS:-2}
variants=${VARIANTS:-"
  steps-x2=steps=60000
  batch-4096=batch=4096
  lr-mlp-0.005=lr_mlp=0.005
  lr-mlp-0.02=lr_mlp=0.02
  lr-latents-0.02=lr_latents=0.02
  lr-latents-0.08=lr_latents=0.08
  joint-80=joint_percent=80,qat_percent=5
  joint-95=joint_percent=95,qat_percent=2
  mips-uniform-0=mip_uniform_share=0
  mips-uniform-0.2=mip_uniform_share=0.2
  init-spread-0.02=latent_init_spread=0.02
  init-spread-0.2=latent_init_spread=0.2
"}

cargo build --release -q -p nmat-bench
mkdir -p "$out"
args=(--threads "$threads" --csv "$out/sweep.csv")
for p in $profiles; do args+=(--profile "$p"); done
for v in $variants; do args+=(--variant "$v"); done
dirs=()
for m in $materials; do dirs+=("$dev/$m"); done
target/release/nmat-sweep "${args[@]}" "${dirs[@]}" | tee "$out/sweep.md"
echo "sweep.sh: done in ${SECONDS} s" >&2
