#!/usr/bin/env bash
# The trainer's speed-up over the one before its SIMD and memory work (commit 00a4eca), one
# thread each, measured with both running at once: the old trainer pinned to one CPU and
# `nmat bench-train` to another, swapped every round, so both see the same neighbours on a shared
# host (docs/PERFORMANCE.md, "Training"). Prints each round's steps per second and their ratio,
# then the median ratio. Needs two CPUs and `taskset` (util-linux).
#
# Usage: bench/trainer_speedup.sh MATERIAL_DIR [PROFILE] [ROUNDS]
# Environment: KERNEL (default: avx512 where the CPU has AVX-512F, else avx2), PHASES (the new
# trainer's phase mix as JOINT,QAT; 80,5 is the old one's, so both do the same work per step;
# default: the encoder's), OLD_STEPS (default 200) and NEW_STEPS (default 1000): steps per run,
# chosen so that both run about as long.
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:?usage: bench/trainer_speedup.sh MATERIAL_DIR [PROFILE] [ROUNDS]}
profile=${2:-ntc-0.2}
rounds=${3:-6}
kernel=${KERNEL:-$(grep -qw avx512f /proc/cpuinfo && echo avx512 || echo avx2)}
phases=()
[ -n "${PHASES:-}" ] && phases=(--phases "$PHASES")
old=$(BUILD_ONLY=1 bench/old_trainer.sh "$dir" "$profile")
cargo build --release -q -p nmat
new=target/release/nmat
echo "material $dir, profile $profile, kernel $kernel, phases ${PHASES:-default}, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2-)"
echo "| round | old on CPU | 00a4eca steps/s | new steps/s | × 00a4eca | % of FMA peak |"
echo "|---:|---:|---:|---:|---:|---:|"
ratios=()
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for r in $(seq "$rounds"); do
    co=$(((r + 1) % 2)) cn=$((r % 2))
    taskset -c "$co" "$old" "$dir" "$profile" "${OLD_STEPS:-200}" 1 1 >"$out/old" &
    taskset -c "$cn" "$new" bench-train "$dir" --profile "$profile" --steps "${NEW_STEPS:-1000}" \
        --threads 1 --kernel "$kernel" --runs 1 "${phases[@]}" >"$out/new"
    wait
    o=$(awk -F'|' '/00a4eca/ {gsub(/ /, "", $4); print $4}' "$out/old")
    read -r n p < <(awk -F'|' -v k="$kernel" '$2 ~ " "k" " {gsub(/ /, "", $4); gsub(/ /, "", $7); print $4, $7}' "$out/new")
    ratio=$(echo "scale=2; $n / $o" | bc)
    ratios+=("$ratio")
    echo "| $r | $co | $o | $n | $ratio | $p |"
done
median=$(printf '%s\n' "${ratios[@]}" | sort -n | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}')
echo "median × 00a4eca over $rounds rounds: $median"
