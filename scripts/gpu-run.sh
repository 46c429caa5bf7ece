#!/usr/bin/env bash
# Runs on the lent GPU what scripts/gpu-prepare.sh built (docs/GPU.md, "On a lent GPU"): unpacks the
# Vulkan loaders of .gl/, warms the GPU up, then, the figures issue-style targets need first:
# `nmat bench --gpu --region 1024` on the first carried material, `nmat walk --gpu` at 1080p,
# `nmat transcode` on the GPU and the CPU, every nmat-wgpu test executable with the
# cooperative-matrix and dot4 kernels required, the other materials' benches and the kernels'
# variants. Every step under a timeout (a shader can hang), and all of them within BUDGET seconds
# (default 540, under a lent machine's 600 s a command: a step that would start later is skipped,
# one that would end later gets the time left), so that summary.txt is always written; outputs in
# $OUT (default /tmp/gpu-run). Exit status: the number of steps that failed or were skipped.
set -uo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-/tmp/gpu-run}
mkdir -p "$out"
failed=0
budget=${BUDGET:-540}
step() { # NAME SECONDS COMMAND...: runs it, output in $out/NAME.txt, and says how it ended
  local name=$1 limit=$2
  shift 2
  local left=$((budget - SECONDS))
  if [ "$left" -lt 10 ]; then
    echo "$name: skipped, $budget s spent" | tee -a "$out/summary.txt"
    failed=$((failed + 1))
    return
  fi
  [ "$limit" -le "$left" ] || limit=$left
  local start=$SECONDS
  timeout "$limit" "$@" > "$out/$name.txt" 2>&1
  local rc=$?
  echo "$name: rc $rc in $((SECONDS - start)) s" | tee -a "$out/summary.txt"
  [ "$rc" -eq 0 ] || failed=$((failed + 1))
}
if [ -d .gl ] && ! ldconfig -p | grep -q libvulkan; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
for f in .devcarry/nmat.gz .devcarry/tests/*.gz; do
  [ -f "$f" ] && gunzip -f "$f"
done
chmod +x .devcarry/nmat .devcarry/tests/*
# The test executables read tests/fixtures at the path they were built at.
root=$(cat .devcarry/build-root)
if [ ! -e "$root" ]; then
  mkdir -p "$(dirname "$root")"
  ln -s "$PWD" "$root"
fi
nvidia-smi > "$out/nvidia-smi.txt" 2>&1
# A material of the built-in demo, and a throwaway GPU run (a fresh machine's first GPU process
# reads slow).
step demo 300 .devcarry/nmat demo -o "$out/demo"
step warm-up 300 .devcarry/nmat bench "$out/demo/demo.nmat" --gpu --runs 1
# The materials, neural and JPEG (a file name containing `jpeg`), in the order given to
# gpu-prepare.sh (it numbers them).
neural=() jpeg=()
for m in .devcarry/materials/*.nmat; do
  [ -f "$m" ] || continue
  case "$(basename "$m")" in *jpeg*) jpeg+=("$m") ;; *) neural+=("$m") ;; esac
done
bench() { # MATERIAL: every kernel the device runs at a 1024² region, requests and nmat_sample
  step "bench-$(basename "$1" .nmat)" 200 .devcarry/nmat bench "$1" --gpu --region 1024 --runs 5
}
[ "${#neural[@]}" -gt 0 ] && bench "${neural[0]}"
# A frame through the GPU tile cache (mark, decode and resolve timed apart: docs/PERFORMANCE.md,
# "The same walk on the GPU") with up to four carried neural materials; BC transcoding of the
# first neural material on the GPU against the CPU on every core (the same files, compared), its
# default layout and every map in BC7. (WALK_SIZE and WALK_FRAMES make the walk smaller for a dry
# run on a software adapter.)
walk_size=${WALK_SIZE:-1920x1080} walk_frames=${WALK_FRAMES:-30}
if [ "${#neural[@]}" -gt 0 ]; then
  step walk 200 .devcarry/nmat walk "${neural[@]:0:4}" --gpu --threads "$(nproc)" \
    --size "$walk_size" --frames "$walk_frames" --direct-every 15 --csv "$out/walk.csv"
  step transcode-gpu 60 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-gpu" --gpu \
    --kernel-choices "$out/kernel-choices.txt"
  step transcode-cpu 60 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-cpu"
  step transcode-same 30 diff -r "$out/transcode-gpu" "$out/transcode-cpu"
  # Again with the kernel choices the first run wrote: what they save on the upload (stderr,
  # "material uploaded in", against transcode-gpu.txt's).
  step transcode-gpu-again 60 .devcarry/nmat transcode "${neural[0]}" \
    -o "$out/transcode-gpu-again" --gpu --kernel-choices "$out/kernel-choices.txt"
  # Every map in BC7: the encoder where a GPU should gain most on the CPU.
  step transcode-bc7-gpu 60 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-bc7-gpu" \
    --format bc7 --gpu
  step transcode-bc7-cpu 120 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-bc7-cpu" \
    --format bc7
  step transcode-bc7-same 30 diff -r "$out/transcode-bc7-gpu" "$out/transcode-bc7-cpu"
fi
# The tests fail where a fast kernel is missing (REQUIRE_KERNELS=0: note it and go on, e.g. on
# lavapipe, which has no cooperative matrices). --nocapture: what the tests print (the adapter,
# the pipeline cache's size and timings, the kernels rejected) is kept in each test's file.
if [ "${REQUIRE_KERNELS:-1}" = 1 ]; then
  export NMAT_REQUIRE_MATRIX=1 NMAT_REQUIRE_DOT4=1
fi
for t in .devcarry/tests/*; do
  step "test-$(basename "$t")" 120 "$t" --test-threads 1 --nocapture
done
for m in "${neural[@]:1}" "${jpeg[@]}"; do
  bench "$m"
done
if [ "${#jpeg[@]}" -gt 0 ]; then
  step walk-jpeg 200 .devcarry/nmat walk "${jpeg[@]:0:4}" --gpu --threads "$(nproc)" \
    --size "$walk_size" --frames "$walk_frames" --direct-every 0 --csv "$out/walk-jpeg.csv"
fi
# The tiled kernels with fewer texels per workgroup (more workgroups per core) on the first
# neural material: does occupancy hold them back? (docs/GPU.md, "The kernels, and how upload
# picks one")
if [ "${#neural[@]}" -gt 0 ]; then
  for p in 16 32; do
    NMAT_WGPU_TILED_TEXELS=$p step "bench-texels-$p" 120 .devcarry/nmat bench "${neural[0]}" \
      --gpu --region 1024 --runs 3
  done
fi
# The matrix kernel's layouts on the first neural material, each a `--kernel matrix` bench (its
# rows and parts only): the products' round trip split or paired (with the pads that keep 4
# subgroups in 48 KiB), two texel blocks a subgroup, more batches, and the weights read from a
# storage buffer instead of staged (which frees workgroup memory: more workgroups per core, two
# texel blocks a subgroup, or one-subgroup workgroups that stage nothing) (docs/GPU.md, "The
# matrix kernel"; the bench's kernel line gives the texels a workgroup each layout got).
if [ "${#neural[@]}" -gt 0 ]; then
  while read -r name vars; do
    step "matrix-$name" 120 env $vars .devcarry/nmat bench "${neural[0]}" --gpu --kernel matrix \
      --region 1024 --runs 3 < /dev/null
  done <<'LAYOUTS'
split NMAT_WGPU_MATRIX_SUMS=split
paired NMAT_WGPU_MATRIX_SUMS=paired
paired-pad-804 NMAT_WGPU_MATRIX_SUMS=paired NMAT_WGPU_MATRIX_PAD=8,0,4
paired-pad-0 NMAT_WGPU_MATRIX_SUMS=paired NMAT_WGPU_MATRIX_PAD=0,0,0
blocks-2 NMAT_WGPU_MATRIX=4,2,4
batches-8 NMAT_WGPU_MATRIX=4,1,8
storage NMAT_WGPU_MATRIX_WEIGHTS=storage
storage-paired NMAT_WGPU_MATRIX_WEIGHTS=storage NMAT_WGPU_MATRIX_SUMS=paired
storage-blocks-2 NMAT_WGPU_MATRIX_WEIGHTS=storage NMAT_WGPU_MATRIX=4,2,4
storage-1x2 NMAT_WGPU_MATRIX_WEIGHTS=storage NMAT_WGPU_MATRIX=1,2,8
storage-2x2 NMAT_WGPU_MATRIX_WEIGHTS=storage NMAT_WGPU_MATRIX=2,2,8
LAYOUTS
fi
echo "failed or skipped steps: $failed" | tee -a "$out/summary.txt"
exit "$failed"
