#!/usr/bin/env bash
# Sweeps the trainer's knobs on part of the development set (docs/ENCODING.md, "Tuning"): each
# variant changes one knob from the defaults; nmat-sweep prints per-material rows and a summary
# (mean ΔPSNR against the defaults at the same rate, wins, losses, seconds). Resumable: rows are
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
  steps-x2=steps=20000
  steps-x4=steps=40000
  batch-1024=batch=1024
  batch-4096=batch=4096
  lr-mlp-0.005=lr_mlp=0.005
  lr-mlp-0.02=lr_mlp=0.02
  lr-latents-0.01=lr_latents=0.01
  lr-latents-0.04=lr_latents=0.04
  joint-70=joint_percent=70
  joint-90=joint_percent=90,qat_percent=3
  qat-10=qat_percent=10
  mips-uniform-0.1=mip_uniform_share=0.1
  mips-uniform-0.5=mip_uniform_share=0.5
  init-spread-0.05=latent_init_spread=0.05
  init-spread-0.5=latent_init_spread=0.5
"}

cargo build --release -q -p nmat-bench
mkdir -p "$out"
args=(--threads "$threads" --csv "$out/sweep.csv")
for p in $profiles; do args+=(--profile "$p"); done
for v in $variants; do args+=(--variant "$v"); done
dirs=()
for m in $materials; do dirs+=("$dev/$m"); done
target/release/nmat-sweep "${args[@]}" "${dirs[@]}" | tee "$out/sweep.md"
