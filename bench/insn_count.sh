#!/usr/bin/env bash
# Instructions the decoder executes per texel, per kernel, counted under QEMU's user-mode emulator
# with a small instruction-counting plugin (bench/qemu-insn-count.c): the NEON kernels on
# AArch64 (qemu-aarch64, whose default CPU has the dot-product extension) against the x86-64 kernels QEMU emulates (qemu-x86_64 -cpu max: AVX2
# and the scalar twin; QEMU 7.2 has no AVX-512). Emulation gives no timings; the count says how
# much work a kernel asks of a CPU (docs/PERFORMANCE.md, "Phones"). Each count is the difference
# between decoding N texels and decoding none, divided by N, so loading and preparing the file
# cancel out.
#
# Usage: bench/insn_count.sh FILE.nmat [N_REGION] [N_TEXEL]
#   N_REGION  texels of the region decode (rows of mip 0; default 8192)
#   N_TEXEL   single-texel decodes (scattered; default 2048)
# Needs qemu-user, gcc-aarch64-linux-gnu and a C compiler (scripts/test-aarch64.sh installs the
# first two), and the rustup target aarch64-unknown-linux-gnu.
set -euo pipefail
cd "$(dirname "$0")/.."
file=${1:?usage: bench/insn_count.sh FILE.nmat [N_REGION] [N_TEXEL]}
n_region=${2:-8192}
n_texel=${3:-2048}
[ -f "$file" ] || { echo "$file: no such file" >&2; exit 1; }
for tool in qemu-aarch64 qemu-x86_64 aarch64-linux-gnu-gcc cc; do
  command -v "$tool" >/dev/null || { echo "needs $tool (see the header of this script)" >&2; exit 1; }
done
plugin=target/insn-count/libinsncount.so
mkdir -p target/insn-count
cc -shared -fPIC -O2 -o "$plugin" bench/qemu-insn-count.c
arm=aarch64-unknown-linux-gnu
CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc \
  cargo build -q --release --locked -p nmat-core --example decode_texels --target "$arm"
cargo build -q --release --locked -p nmat-core --example decode_texels

# count EMULATOR… -- ARGS: guest instructions of one run.
count() {
  "$@" 2>&1 >/dev/null | sed -n 's/^insns //p'
}
per_texel() { # ISA KERNEL MODE N
  local isa=$1 kernel=$2 mode=$3 n=$4 run
  case $isa in
    aarch64) run=(qemu-aarch64 -L /usr/aarch64-linux-gnu -plugin "$plugin"
                  "target/$arm/release/examples/decode_texels") ;;
    x86_64) run=(qemu-x86_64 -cpu max -plugin "$plugin" target/release/examples/decode_texels) ;;
  esac
  local zero full
  zero=$(count "${run[@]}" "$file" "$kernel" "$mode" 0)
  full=$(count "${run[@]}" "$file" "$kernel" "$mode" "$n")
  echo $(( (full - zero) / n ))
}

echo "instructions per texel, $(basename "$file"), all channels, 8-bit codes (one thread)"
printf '| %-8s | %-12s | %12s | %12s |\n' ISA kernel region texel
printf '|---|---|---:|---:|\n'
for row in "aarch64 neon-dotprod" "aarch64 neon" "aarch64 scalar" "x86_64 avx2" "x86_64 scalar"; do
  set -- $row
  printf '| %-8s | %-12s | %12s | %12s |\n' "$1" "$2" \
    "$(per_texel "$1" "$2" region "$n_region")" "$(per_texel "$1" "$2" texel "$n_texel")"
done
