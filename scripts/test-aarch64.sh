#!/usr/bin/env bash
# The core's and the decoder's tests on 64-bit ARM, the architecture of phones, from an x86-64
# machine: cross-compiled for aarch64-unknown-linux-gnu and run under qemu's user-mode emulator
# (docs/ROBUSTNESS.md). Installs what it needs where it can (rustup target; the Debian packages
# qemu-user and gcc-aarch64-linux-gnu as root; idempotent, skipped when present). Emulation says
# whether the code is right on ARM, not how fast it is. Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
target=aarch64-unknown-linux-gnu
rustup target list --installed | grep -qx "$target" || rustup target add "$target" >/dev/null
. scripts/lib.sh
if ! command -v qemu-aarch64 >/dev/null || ! command -v aarch64-linux-gnu-gcc >/dev/null; then
  need_packages "the ARM tests run under emulation (qemu-aarch64, aarch64-linux-gnu-gcc)" \
    qemu-user gcc-aarch64-linux-gnu
fi
# The cross linker and the emulator for this target only, so nothing else (a native ARM host, the
# Android and iOS builds) sees them.
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L /usr/aarch64-linux-gnu"
cargo test -p nmat-core -p nmat-tests --target "$target" --locked "$@"
# qemu emulates a CPU with every extension; the kernel tests again on one without the dot-product
# extension (Cortex-A53, ARMv8.0), where the plain NEON kernel must be the one chosen.
if [ $# = 0 ]; then
  QEMU_CPU=cortex-a53 cargo test -p nmat-core --lib --target "$target" --locked -q decoder::kernel
fi
