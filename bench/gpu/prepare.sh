#!/usr/bin/env bash
# Prepare .gpu/ (git-ignored) for a GPU machine with no network, run from this checkout's venv:
#   - gsplat's sources from this venv, cut to the kernels' channel counts moegs renders (<= 17: RGB or
#     STG features, depth and the contribution channel), so its JIT build takes about a minute;
#   - the wheels a CUDA image with torch usually lacks: plyfile and av (the stand-ins' loaders), for the
#     device's Python (DEVICE_PYTHON, default 3.12). Generating the N3V stand-in with its sparse points
#     also needs pycolmap (about 38 MB; EXTRA_WHEELS=pycolmap); bench.gpu_train generates it without them
#     (its loader reads the dense, depth-backprojected cloud first), so it needs none;
#   - D-NeRF mutant for bench/gpu/train_check.sh, from this checkout's data root (MOEGS_DATA) into
#     .gpu/data: every MUTANT_EVERY-th (default 3rd) training view and every 4th test view, about 10 MiB,
#     since only the repository travels, 64 MiB in all (the whole scene is 37 MB, the av wheel 34 MB).
# Then, on the GPU machine, from the repository root: bash bench/gpu/check.sh [OUT_DIR] or
# bash bench/gpu/train_check.sh [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
py="${DEVICE_PYTHON:-3.12}"
mkdir -p .git/info
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
rm -rf .gpu && mkdir -p .gpu/site .gpu/whl
src="$(python -c 'import gsplat, os; print(os.path.dirname(gsplat.__file__))')"
cp -r "$src" .gpu/site/
find .gpu/site/gsplat -name __pycache__ -prune -exec rm -rf {} +
glm=.gpu/site/gsplat/cuda/csrc/third_party/glm
find "$glm" -mindepth 1 -maxdepth 1 ! -name glm -exec rm -rf {} +  # headers only
wide='(32|33|64|65|128|129|256|257|512|513)'
sed -i -E "/^__INS__\\($wide\\)/d" .gpu/site/gsplat/cuda/csrc/*.cu
sed -i -E "/__LAUNCH_KERNEL__\\($wide\\)/d" .gpu/site/gsplat/cuda/csrc/*.cpp
for name in plyfile av ${EXTRA_WHEELS:-}; do
  version="$(python -m pip show "$name" | sed -n 's/^Version: //p')"
  python -m pip download -q --no-deps --only-binary=:all: --python-version "$py" --implementation cp \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux_2_28_x86_64 \
    -d .gpu/whl "$name==$version"
done
mutant="$(python -c 'from moegs.paths import data_root; print(data_root())')/dnerf/mutant"
if [ -f "$mutant/transforms_train.json" ]; then
  python -m bench.gpu_train --stage-dnerf "$mutant" .gpu/data/dnerf/mutant
else
  echo "no D-NeRF mutant at $mutant: train_check.sh's parity and D-NeRF speed runs will fail"
fi
du -sh .gpu
tracked="$({ git ls-files -z | xargs -0 stat -c %s 2>/dev/null || true; } | awk '{s += $1} END {print s + 0}')"
echo "travels: about $(( (tracked + $(du -sb .gpu | cut -f1)) >> 20 )) MiB of 64 (tracked files and .gpu)"
