#!/usr/bin/env bash
# The CUDA checks in one go, on a GPU machine with torch, after bench/gpu/prepare.sh (run from the
# repository root): build moegs' CPU kernel and gsplat's CUDA extension, run the CUDA and gsplat-reference
# tests, time single pass against separate renders in paired rounds (twice), run the rasterizer benchmark
# suite, and time MoE-GS end to end at the quick size and at the paper's scale on the D-NeRF stand-in.
# Everything goes to OUT_DIR (default $OUT, else gpu-out/): at most 8 files.
export PYTHONUNBUFFERED=1
out="${1:-${OUT:-gpu-out}}"
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/moegs-site .gpu/whl/*.whl || exit 1
export PYTHONPATH="$PWD/.gpu/site:/tmp/moegs-site:$PWD"
log="$out/check.log"
{
  nvidia-smi -L
  python3 -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
  python3 -m moegs.kernels build > /dev/null 2>&1 || echo "moegs CPU kernel: build failed"
  t=$SECONDS
  TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}" MAX_JOBS="${MAX_JOBS:-16}" \
    python3 -c "from gsplat.cuda._backend import _C; assert _C is not None" && echo "gsplat build $((SECONDS - t)) s"
  python3 -m pytest -p no:cacheprovider -rA -q tests/render/test_gsplat_reference.py tests/render/test_rasterize.py \
    tests/metrics/test_speed.py -k "cuda or reference or padded" 2>&1 | tail -30
} > "$log" 2>&1
for run in 1 2; do
  python3 -m bench.single_pass --backend cuda --rounds 100 --warmup 10 --json "$out/single_pass_run$run.json" >> "$log" 2>&1
done
python3 -m bench.rasterizer --backend cuda --out /tmp/moegs-rasterizer >> "$log" 2>&1 \
  && cp /tmp/moegs-rasterizer-cuda/benchmark.json "$out/benchmark_cuda.json"
scene="--scene synthetic:dnerf_like --experts fourdgs,ed3dgs,ex4dgs --views 2"
python3 -m bench.moe_fps --device cuda $scene --json "$out/moe_fps.json" >> "$log" 2>&1
python3 -m bench.moe_fps --device cuda $scene --gaussians 300000 --scale 8 --json "$out/moe_fps_300k.json" >> "$log" 2>&1
grep -v "img/s" "$log" | tail -60
