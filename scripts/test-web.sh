#!/usr/bin/env bash
# nmat-wgpu in a browser: runtime-wgpu/tests/web.rs built for wasm32-unknown-unknown and run by
# wasm-bindgen-test in Debian's headless Chromium, whose WebGPU runs on SwiftShader (Chromium's
# Vulkan on the CPU; no GPU needed). There nothing may block, so it checks the calls that never
# block (`upload_async`, `wait_async`) against the CPU, every kernel the browser runs
# (docs/GPU.md, "Without blocking"). Installs what is missing (idempotent): Chromium and its
# WebDriver (Debian), the wasm32 target, and wasm-bindgen-cli at the version of wasm-bindgen in
# Cargo.lock (built from crates.io: minutes, once). Arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
need_packages "Chromium and its WebDriver, for the browser test" chromium chromium-driver
rustup target add wasm32-unknown-unknown >/dev/null 2>&1
version=$(grep -A1 '^name = "wasm-bindgen"$' Cargo.lock | sed -n 's/^version = "\(.*\)"$/\1/p')
if ! wasm-bindgen-test-runner --version 2>/dev/null | grep -qF "$version"; then
  echo "installing wasm-bindgen-cli $version (cargo install): the browser test's runner" >&2
  cargo install -q wasm-bindgen-cli --version "$version"
fi
# Chromium's flags (beside the runner's own headless, no-sandbox): WebGPU on, on SwiftShader.
caps=$(mktemp)
trap 'rm -f "$caps"' EXIT
cat > "$caps" <<'JSON'
{"goog:chromeOptions": {"args": ["enable-unsafe-webgpu", "use-webgpu-adapter=swiftshader"]}}
JSON
export WASM_BINDGEN_TEST_WEBDRIVER_JSON=$caps
export CHROMEDRIVER=${CHROMEDRIVER:-$(command -v chromedriver)}
export CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_RUNNER=wasm-bindgen-test-runner
# SwiftShader compiles every kernel's shader on the CPU: more than the runner's default 20 s.
export WASM_BINDGEN_TEST_TIMEOUT=${WASM_BINDGEN_TEST_TIMEOUT:-900}
cargo test -p nmat-wgpu --target wasm32-unknown-unknown --locked --test web "$@"
