#!/usr/bin/env bash
# Prepare .gpu/ (git-ignored) for a GPU machine with no network, run from this checkout's venv:
#   - gsplat's sources from this venv, cut to the kernels' channel counts moegs renders (<= 17: RGB or
#     STG features, depth and the contribution channel), so its JIT build takes about a minute;
#   - the wheels a CUDA image with torch usually lacks: plyfile and av (the stand-ins' loaders), for the
#     device's Python (DEVICE_PYTHON, default 3.12). The N3V stand-in also needs pycolmap (about 38 MB);
#     add it with EXTRA_WHEELS=pycolmap where the transfer budget allows.
# Then, on the GPU machine, from the repository root: bash bench/gpu/check.sh [OUT_DIR]
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
du -sh .gpu
