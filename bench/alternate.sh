#!/usr/bin/env bash
# Compares two commands' speed on a shared machine: runs A then B, back to back, ROUNDS times,
# and prints the median of the B ÷ A time ratios (with the quartiles) and each side's median.
# Each command must print its time per texel as the second field of its first line, as
# `span_profile` does. Two runs measured minutes apart can differ by 2× on a shared host; a pair
# run back to back sees about the same load, so the ratio of a pair is what to compare builds or
# files with. Run the same command as A and B to see the noise floor.
#
# Usage: bench/alternate.sh ROUNDS "COMMAND A" "COMMAND B"
#   e.g. (two builds of span_profile, random access on one file, one call a texel):
#   bench/alternate.sh 30 "old/span_profile f.nmat 3 avx512-vnni random" \
#                         "target/release/examples/span_profile f.nmat 3 avx512-vnni random"
set -euo pipefail
usage='usage: bench/alternate.sh ROUNDS "COMMAND A" "COMMAND B"'
rounds=${1:?$usage}
a=${2:?$usage}
b=${3:?$usage}
time_of() {
  # shellcheck disable=SC2086 # a command line, split into words on purpose
  local t
  t=$($1 | awk 'NR == 1 { print $2 }')
  [[ $t =~ ^[0-9.]+$ ]] || { echo "no time in the output of: $1" >&2; exit 1; }
  echo "$t"
}
times=""
for _ in $(seq "$rounds"); do
  ta=$(time_of "$a") || exit 1
  tb=$(time_of "$b") || exit 1
  times+="$ta $tb"$'\n'
done
printf '%s' "$times" | python3 -c '
import statistics, sys
pairs = [tuple(map(float, line.split())) for line in sys.stdin]
r = sorted(b / a for a, b in pairs)
n = len(r)
print("B/A time: median %.3f (quartiles %.3f, %.3f) of %d pairs; A median %.1f, B median %.1f ns/texel"
      % (statistics.median(r), r[n // 4], r[(3 * n) // 4], n,
         statistics.median(a for a, _ in pairs), statistics.median(b for _, b in pairs)))
'
