#!/usr/bin/env bash
# The GPU tests (`nmat-wgpu`) on wgpu's OpenGL ES backend instead of Vulkan: on a machine without
# a GPU that is Mesa's llvmpipe through EGL, the GL twin of lavapipe. Not part of CI (a cold run
# takes over an hour on 2 vCPUs, nearly all of it the GL driver compiling shaders); run it after
# changing a shader, since GLSL, which naga writes for this backend, leaves some operations
# undefined that WGSL defines (docs/GPU.md, "Known problems"). Installs Mesa's EGL and GLES
# drivers when missing (idempotent), then runs the tests with WGPU_BACKEND=gl; arguments go to
# `cargo test` (e.g. a test name, or `--test transcode`).
set -euo pipefail
cd "$(dirname "$0")/.."
packages=(libegl1 libegl-mesa0 libgles2 libgl1-mesa-dri)
if ! dpkg -s "${packages[@]}" >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing ${packages[*]} (apt): Mesa's OpenGL ES through EGL, for wgpu's GL backend" >&2
    apt-get update -qq && apt-get install -y -qq "${packages[@]}" >/dev/null
  else
    echo "the GL tests need: sudo apt-get install ${packages[*]}" >&2
  fi
fi
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  export XDG_RUNTIME_DIR
  trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
fi
# As scripts/test.sh: llvmpipe compiles without LLVM's optimization passes.
export GALLIVM_PERF="${GALLIVM_PERF-nopt}"
export WGPU_BACKEND=gl
cargo test -p nmat-wgpu --locked "$@"
