#!/usr/bin/env bash
# Measures nmat's profiles and the reference codecs on the development set, the same way for all
# (whole-chain PSNR, BPPC of mip 0): docs/QUALITY.md. Commits nothing; writes OUT_DIR.
#
# Usage: bench/quality.sh [DEV_DIR] [OUT_DIR]
#   DEV_DIR   materials from bench/dev-materials.sh (default ~/.cache/nmat-dev)
#   OUT_DIR   default target/quality; results.csv is appended to, so runs can be resumed
# Environment: MATERIALS (default: all in DEV_DIR), PROFILES (default: all 8), STEPS (default:
# the encoder's), THREADS (default 2), MATCH (the profiles whose rates AVIF and JPEG XL are
# bisected to, default "ntc-0.2 ntc-1.0"), ANCHORS (default 1; 0 skips every reference codec),
# JPEG (default 1; 0 skips nmat's `--codec jpeg` at the MATCH and BC1/BC4 rates).
# Needs: apt-get install -y astcenc libjxl-tools libavif-bin libnvtt-bin
set -euo pipefail
cd "$(dirname "$0")/.."
dev=${1:-$HOME/.cache/nmat-dev}
out=${2:-target/quality}
profiles=${PROFILES:-"nbc-0.05 nbc-0.1 nbc-0.2 ntc-0.2 nbc-0.5 ntc-0.5 ntc-1.0 ntc-2.25"}
materials=${MATERIALS:-$(ls "$dev")}
threads=${THREADS:-2}
match_profiles=${MATCH:-"ntc-0.2 ntc-1.0"}
steps_arg=()
[ -n "${STEPS:-}" ] && steps_arg=(--steps "$STEPS")

cargo build --release -q -p nmat -p nmat-bench
mkdir -p "$out"
csv="$out/results.csv"
[ -f "$csv" ] || echo "material,codec,setting,bppc,psnr_db,seconds" > "$csv"

done_row() { grep -q "^$1,$2," "$csv"; }

for m in $materials; do
  for p in $profiles; do
    done_row "$m" "nmat-$p" && continue
    start=$(date +%s.%N)
    log=$(target/release/nmat encode "$dev/$m" -o "$out/$m.$p.nmat" --profile "$p" --threads "$threads" "${steps_arg[@]}" 2>/dev/null)
    secs=$(echo "$(date +%s.%N) - $start" | bc)
    line=$(echo "$log" | grep '^overall:')
    psnr=$(echo "$line" | sed -E 's/.*PSNR ([0-9.]+) dB.*/\1/')
    bppc=$(echo "$line" | sed -E 's/.*, ([0-9.]+) bits per pixel.*/\1/')
    echo "$m,nmat-$p,${STEPS:-default},$bppc,$psnr,$secs" | tee -a "$csv"
  done
  if [ "${ANCHORS:-1}" != 0 ]; then
    # Anchors: the fixed-rate codecs once, AVIF and JPEG XL bisected to the rate nmat reached on
    # this material with each profile of MATCH that has a row (skipped where already measured).
    match=()
    for p in $match_profiles; do
      done_row "$m" "avif@$p" && continue
      b=$(grep "^$m,nmat-$p," "$csv" | tail -1 | cut -d, -f4 || true)
      [ -n "$b" ] && match+=(--match "$p=$b")
    done
    if ! done_row "$m" "bc1/bc4"; then
      target/release/nmat-anchors "$dev/$m" "${match[@]}" | tee -a "$csv"
    elif [ ${#match[@]} -gt 0 ]; then
      target/release/nmat-anchors "$dev/$m" "${match[@]}" --matched-only | tee -a "$csv"
    fi
  fi
  [ "${JPEG:-1}" = 0 ] && continue
  # nmat's own indexed JPEG (`encode --codec jpeg --bppc`: the highest quality within the rate)
  # at the rate of each profile of MATCH and of BC1/BC4 (`jpeg@bc1`), where those rows exist.
  for p in $match_profiles bc1; do
    done_row "$m" "jpeg@$p" && continue
    if [ "$p" = bc1 ]; then from="bc1/bc4"; else from="nmat-$p"; fi
    b=$(grep "^$m,$from," "$csv" | tail -1 | cut -d, -f4 || true)
    [ -z "$b" ] && continue
    start=$(date +%s.%N)
    log=$(target/release/nmat encode "$dev/$m" -o "$out/$m.jpeg@$p.nmat" --codec jpeg --bppc "$b" 2>/dev/null)
    secs=$(echo "$(date +%s.%N) - $start" | bc)
    line=$(echo "$log" | grep '^overall:')
    psnr=$(echo "$line" | sed -E 's/.*PSNR ([0-9.]+) dB.*/\1/')
    bppc=$(echo "$line" | sed -E 's/.*, ([0-9.]+) bits per pixel.*/\1/')
    q=$(echo "$log" | sed -nE 's/^jpeg quality ([0-9]+).*/\1/p')
    echo "$m,jpeg@$p,q$q,$bppc,$psnr,$secs" | tee -a "$csv"
  done
done
python3 bench/summarize.py "$csv" | tee "$out/summary.md"
echo "quality.sh: done in ${SECONDS} s" >&2
