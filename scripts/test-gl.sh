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
. scripts/lib.sh
need_packages "Mesa's OpenGL ES through EGL, for wgpu's GL backend" \
  libegl1 libegl-mesa0 libgles2 libgl1-mesa-dri
# As scripts/test.sh: a private XDG_RUNTIME_DIR, llvmpipe compiling without LLVM's optimizations.
mesa_environment
export WGPU_BACKEND=gl
cargo test -p nmat-wgpu --locked "$@"
