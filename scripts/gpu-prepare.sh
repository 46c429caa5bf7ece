#!/usr/bin/env bash
# Builds, on this machine, everything a session with a lent GPU runs there (docs/GPU.md, "On a
# lent GPU"): the `nmat` binary with the `gpu` feature and the nmat-wgpu test executables, release
# profile, stripped and compressed, in .devcarry/ (git-ignored through .git/info/exclude), with the path the tests
# were built at (they look for tests/fixtures there) and, if given, the materials to benchmark.
#
# Usage: scripts/gpu-prepare.sh [FILE.nmat ...]
# Then carry .devcarry (and the Vulkan loaders in .gl, docs/GPU.md) and run scripts/gpu-run.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
out=.devcarry
mkdir -p .git/info
grep -qx '/.devcarry/' .git/info/exclude 2>/dev/null || echo '/.devcarry/' >> .git/info/exclude
grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo '/.gl/' >> .git/info/exclude
rm -rf "$out"
mkdir -p "$out/tests" "$out/materials"
cargo build --release --locked -p nmat --features nmat/gpu
cp target/release/nmat "$out/nmat"
# The test executables cargo built, by name (their paths come from cargo's JSON messages).
cargo test --release --locked -p nmat-wgpu --no-run --message-format=json 2>/dev/null |
  python3 -c '
import json, sys, shutil
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["profile"]["test"]:
        shutil.copy(m["executable"], sys.argv[1] + "/tests/" + m["target"]["name"])
' "$out"
strip "$out/nmat" "$out"/tests/*
# Compressed to fit what a run carries (64 MiB with the loaders); scripts/gpu-run.sh unpacks them.
gzip -9 "$out/nmat" "$out"/tests/*
# Numbered, so that gpu-run.sh takes them in the order given (the first neural one is measured
# first and most).
i=0
for f in "$@"; do
  i=$((i + 1))
  cp "$f" "$out/materials/$(printf '%02d' "$i")-$(basename "$f")"
done
pwd > "$out/build-root"
du -sh "$out"
ls "$out/tests"
