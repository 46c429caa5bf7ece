#!/usr/bin/env bash
# The test suite, as a newcomer and CI run it: installs what the tests need that cargo cannot
# (the lavapipe software Vulkan driver for the GPU tests, NVIDIA Texture Tools' nvdecompress as an
# independent reader of the DDS files `nmat transcode` writes, libjpeg-turbo's djpeg as the one of
# indexed JPEG streams, Ninja to run the build files `nmat build --emit ninja` writes; idempotent,
# skipped when present),
# then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
# Without them the tests that need them fail, saying what is missing.
need_packages "the GPU tests run on lavapipe, a Vulkan driver on the CPU, when the machine has \
no GPU; nvdecompress reads the DDS files of the transcode test, djpeg the JPEG files of the \
indexed-JPEG test, ninja runs the build file of the build test" \
  mesa-vulkan-drivers libvulkan1 libnvtt-bin libjpeg-turbo-progs ninja-build || true
# A private XDG_RUNTIME_DIR and GALLIVM_PERF=nopt (set GALLIVM_PERF to keep another value).
mesa_environment
cargo test --workspace --locked "$@"
# The CLI's GPU paths exist only in a `--features gpu` build: run its GPU tests there too (the
# integration tests and the binary's own, whose names all contain `gpu`). With `--workspace` the
# dependencies keep the features they were just built with, so only the `nmat` crate is compiled
# again (`-p nmat` alone would rebuild some 40 dependencies).
cargo test --workspace --features nmat/gpu --locked --test cli --bin nmat gpu
