#!/usr/bin/env bash
# The test suite, as a newcomer and CI run it: installs what the tests need that cargo cannot
# (the lavapipe software Vulkan driver for the GPU tests, NVIDIA Texture Tools' nvdecompress as an
# independent reader of the DDS files `nmat transcode` writes, libjpeg-turbo's djpeg as the one of
# indexed JPEG streams, Ninja to run the build files `nmat build --emit ninja` writes; idempotent,
# skipped when present),
# then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
packages=(mesa-vulkan-drivers libvulkan1 libnvtt-bin libjpeg-turbo-progs ninja-build)
if ! dpkg -s "${packages[@]}" >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing ${packages[*]} (apt): the GPU tests run on lavapipe, a Vulkan driver on" \
      "the CPU, when the machine has no GPU; nvdecompress reads the DDS files of the transcode test," \
      "djpeg the JPEG files of the indexed-JPEG test, ninja runs the build file of the build test" >&2
    apt-get update -qq && apt-get install -y -qq "${packages[@]}" >/dev/null
  else
    echo "some tests need: sudo apt-get install ${packages[*]}" >&2
  fi
fi
# Mesa's drivers print "XDG_RUNTIME_DIR is invalid or not set" without one (e.g. as root in a
# container); give them a private one so a passing run prints no error lines.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  export XDG_RUNTIME_DIR
  trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
fi
# On lavapipe the GPU tests spend most of their time compiling shaders (LLVM, each kernel once per
# network shape), not running them: compile without LLVM's optimization passes (only lavapipe and
# llvmpipe read this; a GPU's driver ignores it). Set GALLIVM_PERF to keep another value.
export GALLIVM_PERF="${GALLIVM_PERF-nopt}"
cargo test --workspace --locked "$@"
# The CLI's GPU paths exist only in a `--features gpu` build: run its GPU tests there too. With
# `--workspace` the dependencies keep the features they were just built with, so only the `nmat`
# crate is compiled again (`-p nmat` alone would rebuild some 40 dependencies).
cargo test --workspace --features nmat/gpu --locked --test cli gpu
