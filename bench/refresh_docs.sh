#!/usr/bin/env bash
# Regenerates the README's measured decode table ("Measured so far") on this machine, so it does
# not drift from the code: encodes one development material at each profile (decode speed depends
# on the network a profile builds, not on the training steps, so a short training is enough), runs
# `nmat bench` on each file, and rewrites the lines between the markers
# `<!-- refresh_docs:decode:begin -->` and `<!-- refresh_docs:decode:end -->` in README.md,
# naming the CPU, the date and the command. Review the diff before committing it.
#
# Usage: bench/refresh_docs.sh [DEV_DIR]
#   DEV_DIR   materials from bench/dev-materials.sh (default ~/.cache/nmat-dev)
# Environment: MATERIAL (default bigplate), PROFILES (default: ntc-0.2 ntc-0.5 ntc-1.0 nbc-0.1),
# RUNS (timed runs per row, the median is reported; default 5), OUT_DIR (default target/refresh).
set -euo pipefail
cd "$(dirname "$0")/.."
dev=${1:-$HOME/.cache/nmat-dev}
material=${MATERIAL:-bigplate}
profiles=${PROFILES:-"ntc-0.2 ntc-0.5 ntc-1.0 nbc-0.1"}
runs=${RUNS:-5}
out=${OUT_DIR:-target/refresh}
[ -d "$dev/$material" ] || { echo "no $dev/$material: run bench/dev-materials.sh first" >&2; exit 1; }

cargo build --release -q -p nmat
mkdir -p "$out"
for p in $profiles; do
  file="$out/$material-$p.nmat"
  [ -f "$file" ] || target/release/nmat encode "$dev/$material" -o "$file" --profile "$p" \
    --steps 1000 > "$out/$material-$p.encode.log"
  echo "benchmarking $file" >&2
  target/release/nmat bench "$file" --runs "$runs" > "$out/$material-$p.bench.txt"
done

python3 - "$out" "$material" "$runs" $profiles <<'PY'
import datetime, re, sys
out, material, runs, profiles = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]

def rows(text):
    """mode → (ns/texel, %roofline) from `nmat bench`'s table (the last 6 columns are values)."""
    table = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) > 6 and parts[-4].endswith('%'):
            try:
                table[' '.join(parts[:-6])] = (float(parts[-6]), float(parts[-4][:-1]))
            except ValueError:
                pass
    return table

cpu, lines = None, []
for p in profiles:
    text = open(f"{out}/{material}-{p}.bench.txt").read()
    cpu = cpu or re.search(r'^machine: (.*)$', text, re.M).group(1)
    # "(0.200 BPPC)", or for an entropy-coded file "(0.200 BPPC; 0.300 in memory)": the disk rate.
    head = re.search(r'\((\d+\.\d+) BPPC[^)]*\).*kernel (\S+)', text)
    bppc, kernel = head.group(1), head.group(2)
    chans = re.search(r'(\d+) channels', text).group(1)
    t = rows(text)
    region = t[f"integer {kernel} region, all {chans} ch, 1 thread"]
    random = t[f"integer {kernel} random access per texel, all {chans} ch"]
    definition = t[f"integer per-texel definition (Material), all {chans} ch"]
    lines.append(f"| `{p}` | {bppc} | {region[0]:.0f} ns/texel ({kernel}) | "
                 f"{random[0] / region[0]:.1f}× | {definition[0]:.0f} ns | {region[1]:.1f} % |")

date = datetime.date.today().isoformat()
block = [
    f"Decode cost on one thread of {cpu}, `nmat bench` (median of {runs} runs per row) on the "
    f"`{material}` development material at each profile, {date}; regenerate with "
    "`bench/refresh_docs.sh` (full tables, commands and a reading guide in "
    "[`docs/PERFORMANCE.md`](docs/PERFORMANCE.md)):",
    "",
    "| profile | BPPC | region decode (`Decoder`, 1 thread) | random texel ÷ region | "
    "per-texel definition (`Material`) | % of roofline (region) |",
    "|---|---:|---:|---:|---:|---:|",
    *lines,
]
readme = open("README.md").read()
begin, end = "<!-- refresh_docs:decode:begin -->", "<!-- refresh_docs:decode:end -->"
a, b = readme.index(begin) + len(begin), readme.index(end)
open("README.md.tmp", "w").write(readme[:a] + "\n" + "\n".join(block) + "\n" + readme[b:])
PY
mv README.md.tmp README.md
echo "refresh_docs.sh: README.md updated in ${SECONDS} s; review with git diff README.md" >&2
