#!/usr/bin/env bash
# Runs on the lent GPU what scripts/gpu-prepare.sh built (docs/GPU.md, "On a lent GPU"): unpacks the
# Vulkan loaders of .gl/, warms the GPU up, runs every nmat-wgpu test executable with the
# cooperative-matrix and dot4 kernels required, then `nmat bench --gpu --region 1024` on each
# carried material, `nmat walk --gpu` at 1080p and `nmat transcode` on the GPU and the CPU. Every
# step under a timeout (a shader can hang); outputs in $OUT (default /tmp/gpu-run). Exit status:
# the number of steps that failed.
set -uo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-/tmp/gpu-run}
mkdir -p "$out"
failed=0
step() { # NAME SECONDS COMMAND...: runs it, output in $out/NAME.txt, and says how it ended
  local name=$1 limit=$2
  shift 2
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
# The tests fail where a fast kernel is missing (REQUIRE_KERNELS=0: note it and go on, e.g. on
# lavapipe, which has no cooperative matrices).
if [ "${REQUIRE_KERNELS:-1}" = 1 ]; then
  export NMAT_REQUIRE_MATRIX=1 NMAT_REQUIRE_DOT4=1
fi
# --nocapture: what the tests print (the adapter, the pipeline cache's size and timings, the
# kernels rejected) is kept in each test's file.
for t in .devcarry/tests/*; do
  step "test-$(basename "$t")" 300 "$t" --test-threads 1 --nocapture
done
for m in .devcarry/materials/*.nmat; do
  [ -f "$m" ] || continue
  step "bench-$(basename "$m" .nmat)" 300 .devcarry/nmat bench "$m" --gpu --region 1024 --runs 5
done
# The tiled kernels with fewer texels per workgroup (more workgroups per core) on the first
# neural material: does occupancy hold them back? (docs/GPU.md, "The kernels, and how upload
# picks one")
for m in .devcarry/materials/*.nmat; do
  case "$m" in *jpeg*) continue ;; esac
  [ -f "$m" ] || continue
  for p in 16 32; do
    NMAT_WGPU_TILED_TEXELS=$p step "bench-texels-$p" 120 .devcarry/nmat bench "$m" --gpu \
      --region 1024 --runs 3
  done
  break
done
# The matrix kernel's layouts on the first neural material, each a `--kernel matrix` bench (its
# rows and parts only): the products' round trip split or paired (with the pads that keep 4
# subgroups in 48 KiB), two texel blocks a subgroup, more batches, and the weights read from a
# storage buffer instead of staged (which frees workgroup memory: more workgroups per core, two
# texel blocks a subgroup, or one-subgroup workgroups that stage nothing) (docs/GPU.md, "The
# matrix kernel"; the bench's kernel line gives the texels a workgroup each layout got).
for m in .devcarry/materials/*.nmat; do
  case "$m" in *jpeg*) continue ;; esac
  [ -f "$m" ] || continue
  while read -r name vars; do
    step "matrix-$name" 120 env $vars .devcarry/nmat bench "$m" --gpu --kernel matrix \
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
  break
done
# A frame through the GPU tile cache (mark, decode and resolve timed apart: docs/PERFORMANCE.md,
# "The same walk on the GPU") with up to four carried neural materials, and with the JPEG ones;
# BC transcoding of the first neural material on the GPU against the CPU on every core (the same
# files, compared), its default layout and every map in BC7.
# (WALK_SIZE and WALK_FRAMES make the walk smaller for a dry run on a software adapter.)
walk_size=${WALK_SIZE:-1920x1080} walk_frames=${WALK_FRAMES:-30}
neural=() jpeg=()
for m in .devcarry/materials/*.nmat; do
  [ -f "$m" ] || continue
  case "$(basename "$m")" in *jpeg*) jpeg+=("$m") ;; *) neural+=("$m") ;; esac
done
if [ "${#neural[@]}" -gt 0 ]; then
  step walk 300 .devcarry/nmat walk "${neural[@]:0:4}" --gpu --threads "$(nproc)" \
    --size "$walk_size" --frames "$walk_frames" --direct-every 15 --csv "$out/walk.csv"
  step transcode-gpu 120 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-gpu" --gpu
  step transcode-cpu 120 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-cpu"
  step transcode-same 30 diff -r "$out/transcode-gpu" "$out/transcode-cpu"
  # Every map in BC7: the encoder where a GPU should gain most on the CPU.
  step transcode-bc7-gpu 120 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-bc7-gpu" \
    --format bc7 --gpu
  step transcode-bc7-cpu 300 .devcarry/nmat transcode "${neural[0]}" -o "$out/transcode-bc7-cpu" \
    --format bc7
  step transcode-bc7-same 30 diff -r "$out/transcode-bc7-gpu" "$out/transcode-bc7-cpu"
fi
if [ "${#jpeg[@]}" -gt 0 ]; then
  step walk-jpeg 300 .devcarry/nmat walk "${jpeg[@]:0:4}" --gpu --threads "$(nproc)" \
    --size "$walk_size" --frames "$walk_frames" --direct-every 0 --csv "$out/walk-jpeg.csv"
fi
echo "failed steps: $failed" | tee -a "$out/summary.txt"
exit "$failed"
