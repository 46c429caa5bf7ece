#!/usr/bin/env bash
# The test suite, as a newcomer and CI run it: installs what the tests need that cargo cannot
# (the lavapipe software Vulkan driver for the GPU tests; idempotent), then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! { dpkg -s mesa-vulkan-drivers && dpkg -s libvulkan1; } >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get update -qq && apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    echo "the GPU tests need a Vulkan driver; without a GPU: sudo apt-get install mesa-vulkan-drivers libvulkan1" >&2
  fi
fi
cargo test --workspace --locked "$@"
