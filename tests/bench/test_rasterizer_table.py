"""The README rasterizer table is built from a pytest-benchmark JSON: ratios, memory, target verdicts."""

from __future__ import annotations

from bench.rasterizer import cuda_markdown, markdown


def bench(test, n, res, backward, backend, median_s, peak=None, single_pass=True):
    info = {"n": n, "res": res, "backward": backward, "backend": backend, "single_pass": single_pass}
    if peak is not None and backend == "cuda":
        info.update(peak_cuda_allocated_mb=peak, device_name="Test GPU", versions="torch 9, gsplat 9")
    elif peak is not None:
        info.update(rss_before_mb=100.0, peak_rss_mb=100.0 + peak)
    return {"name": f"{test}[x]", "extra_info": info, "stats": {"median": median_s}}


def test_table_reports_ratios_memory_and_verdicts():
    data = {
        "datetime": "2026-11-23T10:00:00",
        "machine_info": {"cpu": {"brand_raw": "Test CPU"}},
        "benchmarks": [
            bench("test_rasterize", 5000, 128, True, "torch", 0.40),
            bench("test_rasterize", 5000, 128, True, "cpu", 0.05, peak=20.0),
            bench("test_rasterize", 20000, 256, True, "torch", 1.0),
            bench("test_rasterize", 20000, 256, True, "cpu", 0.5, peak=40.0),
            bench("test_rasterize", 100000, 512, False, "cpu", 0.9, peak=650.0),
            bench("test_three_experts", 5000, 128, False, "cpu", 0.02, single_pass=True),
            bench("test_three_experts", 5000, 128, False, "cpu", 0.04, single_pass=False),
            bench("test_three_experts", 5000, 128, True, "cpu", 0.10, single_pass=True),
            bench("test_three_experts", 5000, 128, True, "cpu", 0.12, single_pass=False),
            bench("test_gsplat_torch_reference", 20000, 256, True, "gsplat-torch-reference", 4.0),
        ],
    }
    text = markdown(data)
    assert "| 5k Gaussians, 128², fwd+bwd | 400.0 | 50.0 | 8.0× | 20.0 | ≥ 3×: met |" in text
    assert "| 20k Gaussians, 256², fwd+bwd | 1000.0 | 500.0 | 2.0× | 40.0 | ≥ 3×: MISSED |" in text
    assert "| 100k Gaussians, 512², fwd | – | 900.0 | – | 650.0 | < 500 MB: MISSED |" in text
    assert (
        "| 5k each, 128², fwd (rendering) | 40.0 | 20.0 | 25 → 50 | 2.00× | ≥ 1.5×: met; paper: 1.67×" in text
    )
    assert (
        "| 5k each, 128², fwd+bwd (training) | 120.0 | 100.0 | 8 → 10 | 1.20× | none (router training" in text
    )
    assert "compiled CPU |" in text and "CUDA" not in text
    assert "| 20k Gaussians, 256², fwd+bwd | 4000.0 | 500.0 | 8.0× | ≥ 15×: MISSED |" in text
    assert "Test CPU (2026-11-23)" in text


def test_cuda_table_reports_gsplat_renders_and_single_pass_per_size():
    data = {
        "datetime": "2026-11-26T10:00:00",
        "benchmarks": [
            bench("test_rasterize", 20000, 256, False, "cuda", 0.002, peak=30.0),
            bench("test_rasterize", 20000, 256, False, "cpu", 0.05),  # ignored: not CUDA
            bench("test_three_experts", 5000, 128, False, "cuda", 0.001, single_pass=True),
            bench("test_three_experts", 5000, 128, False, "cuda", 0.003, single_pass=False),
            bench("test_three_experts", 300000, 1024, False, "cuda", 0.010, single_pass=True),
            bench("test_three_experts", 300000, 1024, False, "cuda", 0.012, single_pass=False),
            bench("test_three_experts", 5000, 128, False, "cpu", 0.02, single_pass=True),
            bench("test_three_experts", 5000, 128, False, "cpu", 0.01, single_pass=False),
        ],
    }
    text = cuda_markdown(data)
    assert "| 20k Gaussians, 256², fwd | 2.0 | 30.0 |" in text
    assert "| 5k each, 128², fwd (rendering) | 3.0 | 1.0 | 333 → 1000 | 3.00× | ≥ 1.5×: met" in text
    assert "| 300k each, 1024², fwd (rendering) | 12.0 | 10.0 | 83 → 100 | 1.20× | ≥ 1.5×: MISSED" in text
    assert "gsplat, CUDA" in text and "compiled CPU" not in text and "50.0" not in text
    assert "on Test GPU (2026-11-26; torch 9, gsplat 9)" in text


def test_cuda_table_shows_repeat_runs_speedups():
    def run(single_s, separate_s):
        return {
            "benchmarks": [
                bench("test_three_experts", 5000, 128, False, "cuda", single_s, single_pass=True),
                bench("test_three_experts", 5000, 128, False, "cuda", separate_s, single_pass=False),
            ]
        }

    text = cuda_markdown(run(0.001, 0.002), [run(0.001, 0.004), {"benchmarks": []}])
    assert "| speed-up | speed-up, run 2 | speed-up, run 3 | target |" in text
    assert (
        "| 5k each, 128², fwd (rendering) | 2.0 | 1.0 | 500 → 1000 | 2.00× | 4.00× | – | ≥ 1.5×: met" in text
    )
    assert "Later runs: speed-ups only." in text
    # a run below the target shows in the verdict, whichever run it was
    text = cuda_markdown(run(0.001, 0.002), [run(0.001, 0.0013)])
    assert "| 2.00× | 1.30× | ≥ 1.5×: MISSED in run 2 of 2; paper" in text
