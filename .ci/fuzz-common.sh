# Sourced by .ci/fuzz (the bounded CI run) and .ci/fuzz-long (the long measured run): the target
# list, the tools and each target's seed folders, in one place.

fuzz_targets=(parse decode roundtrip ffi cli jpeg unpack)

# One thread per fuzzer: `cli` transcodes small materials through rayon, whose worker threads
# would take the other fuzzers' cores (the jobs are already one per core) and add a hand-off per
# block row; the bytes do not depend on the thread count.
export RAYON_NUM_THREADS=1

# Nightly and cargo-fuzz, installed when missing (idempotent, fast when present).
fuzz_install_tools() {
  rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
  command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --version 0.13.2 --locked
}

# fuzz_seeds TARGET: the seed folders of TARGET, one a line, relative to fuzz/. libFuzzer reads
# seed folders recursively: the .nmat fixtures include tests/fixtures/jpeg/. `roundtrip` takes a
# structured input, so .nmat files would be noise there.
fuzz_seeds() {
  echo "regressions/$1"
  case $1 in
    roundtrip) ;;
    jpeg) echo ../tests/fixtures/jpeg ;;
    *) echo ../tests/fixtures ;;
  esac
}
