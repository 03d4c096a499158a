"""Rasterizer benchmarks (pytest-benchmark; skipped unless ``--benchmark-enable``, e.g. ``tox -e bench``).

Scenes and render calls: ``bench.raster_cases`` (shared with ``bench.single_pass``). "fwd" runs under
``no_grad``; "fwd+bwd" includes the projection and the backward to means, quats, scales, opacities and
colours.

Each case also records, in ``benchmark.extra_info``, the peak RSS of one render in a fresh
subprocess (``VmHWM``, see ``proc_status_mb``; tracemalloc misses torch's allocator) and the RSS
just before rendering, so the difference is what the render itself needs. On CUDA it records
``torch.cuda.max_memory_allocated`` instead.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from bench.raster_cases import case_renderer, make_scene, run_once
from moegs.render._torch import _bbox_pixels
from moegs.render.projection import covariance_3d, project

pytestmark = pytest.mark.benchmark

SIZES = [(5_000, 128), (20_000, 256), (100_000, 512)]
# K = 3 experts, Gaussians per expert and image side: the CPU case, then scales near the paper's scenes
# (N3V at 1352 x 1014 with a few hundred thousand Gaussians per expert), CUDA only.
THREE_EXPERT_SIZES = [(5_000, 128), (100_000, 512), (300_000, 1024)]
ROUNDS, WARMUP = 5, 1
RATIO_ROUNDS = 25  # the K = 3 cases are compared with each other: more rounds, steadier medians
# The torch reference holds every (pixel, Gaussian) pair of the bounding-box rule at once. Its peak RSS
# above the idle process, measured on these scenes at 100k / 512² (17.9M pairs): 2.9 GB forward
# (160 B/pair), 3.6 GB forward+backward (200 B/pair). Cases whose estimate exceeds the budget are
# skipped: with the default 3 GB that is torch fwd+bwd at 100k / 512².
TORCH_BYTES_PER_PAIR = {False: 160, True: 200}
TORCH_BUDGET_MB = float(os.environ.get("MOEGS_BENCH_TORCH_MB", 3072))


def torch_memory_mb(n: int, res: int, backward: bool) -> float:
    """Estimated extra RSS (MB) of the torch reference for this scene: pairs x bytes per pair."""
    frame, camera = make_scene(n, res)
    proj = project(frame.means, covariance_3d(frame.quats, frame.scales), frame.opacities, camera)
    x0, x1, y0, y1 = _bbox_pixels(proj.means2d, proj.radii, res, res)
    pairs = ((x1 - x0 + 1).clamp(min=0) * (y1 - y0 + 1).clamp(min=0))[proj.radii > 0].sum()
    return float(pairs) * TORCH_BYTES_PER_PAIR[backward] / 2**20


def backends() -> list:
    """Every backend that can run here, each a pytest param (unavailable ones skip with the reason)."""
    from moegs.render import _cuda
    from moegs.render.pipeline import _cpu_kernel

    cpu_reason = _cpu_kernel()[1]
    cuda_reason = None if _cuda.is_available() else "needs CUDA and gsplat"
    return [
        "torch",
        pytest.param("cpu", marks=pytest.mark.skipif(bool(cpu_reason), reason=cpu_reason or "")),
        pytest.param("cuda", marks=pytest.mark.skipif(cuda_reason is not None, reason=str(cuda_reason))),
    ]


_MEMORY_SCRIPT = textwrap.dedent(
    """
    import json, sys, torch
    sys.path.insert(0, {here!r})
    import test_bench_render as b
    case = json.loads(sys.argv[1])
    torch.set_num_threads(case.pop("threads"))
    render, frame = b.case_renderer(**case)
    before = b.proc_status_mb("VmRSS")
    b.run_once(render, frame, case["backward"])
    print(json.dumps({{"rss_before_mb": before, "peak_rss_mb": b.proc_status_mb("VmHWM")}}))
    """
)


def proc_status_mb(key: str) -> float:
    """``VmRSS`` (current) or ``VmHWM`` (peak) resident memory of this process in MB (Linux).

    Used instead of ``resource.getrusage(...).ru_maxrss``: on Linux that value survives fork + exec,
    so a child starts with its parent's peak, while ``VmHWM`` belongs to the exec'd address space.
    """
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) / 1024
    raise KeyError(f"{key} not in /proc/self/status")


def peak_memory(**case) -> dict[str, float]:
    """Peak RSS (MB) of one render of ``case`` in a fresh subprocess, and the RSS just before it.

    On CUDA it reports ``torch.cuda.max_memory_allocated`` instead (RSS says nothing about GPU memory).
    """
    if case["device"] == "cuda":
        torch.cuda.reset_peak_memory_stats()
        render, frame = case_renderer(**case)
        run_once(render, frame, case["backward"])
        return {"peak_cuda_allocated_mb": torch.cuda.max_memory_allocated() / 2**20}
    if not Path("/proc/self/status").exists():
        return {}  # not Linux: no per-process peak we can trust
    script = _MEMORY_SCRIPT.format(here=str(Path(__file__).parent))
    arg = json.dumps({**case, "threads": torch.get_num_threads()})
    done = subprocess.run([sys.executable, "-c", script, arg], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _bench(benchmark, rounds: int = ROUNDS, **case) -> None:
    device = "cuda" if case["backend"] == "cuda" else "cpu"
    render, frame = case_renderer(device=device, **case)
    benchmark.extra_info.update(case)
    benchmark.extra_info.update(peak_memory(device=device, **case))
    if device == "cuda":
        import gsplat

        benchmark.extra_info["device_name"] = torch.cuda.get_device_name()
        benchmark.extra_info["versions"] = f"torch {torch.__version__}, gsplat {gsplat.__version__}"
    benchmark.pedantic(run_once, args=(render, frame, case["backward"]), rounds=rounds, warmup_rounds=WARMUP)


@pytest.mark.parametrize("backend", backends())
@pytest.mark.parametrize("backward", [False, True], ids=["fwd", "fwd+bwd"])
@pytest.mark.parametrize(("n", "res"), SIZES, ids=[f"{n // 1000}k-{r}px" for n, r in SIZES])
def test_rasterize(benchmark, n, res, backward, backend):
    if backend == "torch" and (need := torch_memory_mb(n, res, backward)) > TORCH_BUDGET_MB:
        pytest.skip(
            f"torch reference would need ~{need:.0f} MB > {TORCH_BUDGET_MB:.0f} MB (MOEGS_BENCH_TORCH_MB)"
        )
    _bench(benchmark, n=n, res=res, backend=backend, backward=backward)


@pytest.mark.parametrize(("n", "res"), SIZES, ids=[f"{n // 1000}k-{r}px" for n, r in SIZES])
def test_gsplat_torch_reference(benchmark, n, res, monkeypatch):
    """gsplat's own pure-PyTorch rasterization (``tests/helpers/gsplat_reference.py``) on the same scenes,
    fwd+bwd, through our CUDA glue on CPU tensors: compare with ``test_rasterize[cpu-fwd+bwd]`` of the same
    run. It holds every (pixel, Gaussian) pair at once, like our torch reference, so the same budget
    applies."""
    from helpers import gsplat_reference

    if (need := torch_memory_mb(n, res, True)) > TORCH_BUDGET_MB:
        pytest.skip(f"gsplat's reference would need ~{need:.0f} MB > {TORCH_BUDGET_MB:.0f} MB")
    gsplat_reference.install_cpu_glue(monkeypatch)
    render, frame = case_renderer(n=n, res=res, backend="cuda", backward=True)
    benchmark.extra_info.update(n=n, res=res, backend="gsplat-torch-reference", backward=True)
    benchmark.pedantic(run_once, args=(render, frame, True), rounds=ROUNDS, warmup_rounds=WARMUP)


@pytest.mark.parametrize("backend", backends())
@pytest.mark.parametrize("backward", [False, True], ids=["fwd", "fwd+bwd"])
@pytest.mark.parametrize("single_pass", [True, False], ids=["single-pass", "separate"])
@pytest.mark.parametrize(
    ("n", "res"), THREE_EXPERT_SIZES, ids=[f"{n // 1000}k-{r}px" for n, r in THREE_EXPERT_SIZES]
)
def test_three_experts(benchmark, n, res, single_pass, backward, backend):
    """K = 3 experts of ``n`` Gaussians each at ``res``²: one ``rasterize_multi`` vs three ``rasterize``.

    fwd is rendering (the paper's FPS, Table XII); fwd+bwd is a router training step. The sizes past
    the first run on CUDA only (the paper's scale; on a CPU they would only repeat the first's answer
    at many times the cost).
    """
    if (n, res) != THREE_EXPERT_SIZES[0] and backend != "cuda":
        pytest.skip("the larger K = 3 cases run on CUDA only")
    _bench(
        benchmark,
        rounds=RATIO_ROUNDS,
        n=n,
        res=res,
        backend=backend,
        backward=backward,
        experts=3,
        single_pass=single_pass,
    )
