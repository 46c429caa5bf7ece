#!/usr/bin/env bash
# The rate each profile's nominal layout lands on for each material, from the solver alone (`nmat
# encode --fixed-rate --dry-run`: no training; file sizes are exact; a packed file is trained to
# the nominal rate on disk instead), as a Markdown table: docs/ENCODING.md.
# Usage: bench/rates.sh [DEV_DIR]   (default ~/.cache/nmat-dev)
set -euo pipefail
cd "$(dirname "$0")/.."
dev=${1:-$HOME/.cache/nmat-dev}
profiles="nbc-0.05 nbc-0.1 nbc-0.2 ntc-0.2 nbc-0.5 ntc-0.5 ntc-1.0 ntc-2.25"
cargo build --release -q -p nmat
printf '| material | size | channels |'; for p in $profiles; do printf ' %s |' "$p"; done; echo
printf '|---|---|---:|'; for p in $profiles; do printf -- '---:|'; done; echo
for m in $(ls "$dev"); do
  row=""
  for p in $profiles; do
    plan=$(target/release/nmat encode "$dev/$m" -o /dev/null --profile "$p" --fixed-rate --dry-run | head -2)
    head=$(echo "$plan" | head -1)
    size=$(echo "$head" | sed -E 's/^[^:]*: ([0-9]+×[0-9]+), .*/\1/')
    chans=$(echo "$head" | sed -E 's/.*, ([0-9]+) channels.*/\1/')
    # The second line of the fixed-rate (nominal) layout: "this file X BPPC (±z %)".
    rate=$(echo "$plan" | tail -1 | sed -E 's/.*this file ([0-9.]+) BPPC \(([^)]*)\).*/\1 (\2)/')
    row="$row $rate |"
  done
  echo "| $m | $size | $chans |$row"
done
