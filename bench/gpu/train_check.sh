#!/usr/bin/env bash
# Training on CUDA in one go, on a GPU machine with torch, after bench/gpu/prepare.sh (run from the
# repository root): install the carried wheels, build moegs' CPU kernel (the CPU side of parity) and gsplat's
# CUDA extension (61-73 s), then python -m bench.gpu_train: every expert, MoDE, the router and a
# distillation trained on CUDA against the CPU, host syncs per step, and training speed at the paper's
# sizes (see bench/gpu_train.py). D-NeRF mutant is prepare.sh's copy in .gpu/data. About 8 minutes on one
# H100; the report is written after every run, so a run cut short keeps what finished.
#   bash bench/gpu/train_check.sh [OUT_DIR [bench.gpu_train arguments, e.g. --experts fourdgs,router]]
# Everything goes to OUT_DIR (default $OUT, else gpu-out/): 2 files, train_check.log and train_check.json.
export PYTHONUNBUFFERED=1
out="${1:-${OUT:-gpu-out}}"
shift || true
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/moegs-site .gpu/whl/*.whl || exit 1
export PYTHONPATH="$PWD/.gpu/site:/tmp/moegs-site:$PWD"
export MOEGS_DATA="$PWD/.gpu/data"
export TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}" MAX_JOBS="${MAX_JOBS:-16}"
log="$out/train_check.log"
{
  nvidia-smi -L
  python3 -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
  [ -f "$MOEGS_DATA/dnerf/mutant/transforms_train.json" ] || echo "no D-NeRF mutant in $MOEGS_DATA: run prepare.sh"
  t=$SECONDS
  if python3 -m moegs.kernels build > /dev/null 2>&1; then
    echo "moegs CPU kernel $((SECONDS - t)) s"
  else
    echo "moegs CPU kernel: build failed (the CPU runs fall back to the torch reference)"
  fi
  t=$SECONDS
  python3 -c "from gsplat.cuda._backend import _C; assert _C is not None" && echo "gsplat build $((SECONDS - t)) s"
} > "$log" 2>&1
timeout "${TRAIN_TIMEOUT_S:-420}" python3 -m bench.gpu_train --device cuda --json "$out/train_check.json" "$@" \
  >> "$log" 2>&1
echo "bench.gpu_train exit $?" >> "$log"
grep -v "it/s" "$log" | tail -40
[ -f "$out/train_check.json" ] && python3 -m bench.gpu_train --summary "$out/train_check.json"
