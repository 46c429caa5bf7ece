# Shell functions the test scripts share; sourced (`. scripts/lib.sh`), not run.

# need_packages WHY PACKAGE...: installs those of the Debian packages that are missing (apt, as
# root; idempotent: nothing happens when all are present), saying why on stderr. Where it cannot
# install (not root, no apt) it names the command to run and returns 1.
need_packages() {
  local why=$1
  shift
  dpkg -s "$@" >/dev/null 2>&1 && return 0
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing $* (apt): $why" >&2
    apt-get update -qq && apt-get install -y -qq "$@" >/dev/null
  else
    echo "missing: sudo apt-get install $* ($why)" >&2
    return 1
  fi
}

# mesa_environment: what Mesa's CPU drivers (lavapipe for Vulkan, llvmpipe for OpenGL) need to run
# the GPU tests quietly and sooner. They print "XDG_RUNTIME_DIR is invalid or not set" without
# one (e.g. as root in a container): a private one is made, and removed on exit. They spend most
# of the tests' time compiling shaders (LLVM, each kernel once per network shape), not running
# them: GALLIVM_PERF=nopt compiles without LLVM's optimization passes (only lavapipe and llvmpipe
# read it; a GPU's driver ignores it; a value already set is kept).
mesa_environment() {
  if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
    XDG_RUNTIME_DIR=$(mktemp -d)
    export XDG_RUNTIME_DIR
    trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
  fi
  export GALLIVM_PERF="${GALLIVM_PERF-nopt}"
}
