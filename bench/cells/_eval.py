"""A cell's evaluation: the preset's test views and metric profile, scored by the library's one evaluation,
plus render speed and model size.

``render(camera) -> image [H, W, 3]`` is called under ``torch.no_grad``. Scores come from
``moegs.train.evaluate.evaluate_renderer`` (this module adds no metric of its own): full image,
dynamic region and static region (synthetic stand-ins: ground-truth dynamic mask; D-NeRF: object alpha;
Panoptic: foreground segmentation). Speed follows ``moegs.metrics.speed.measure_render`` (render call
only, warm-up, median per view).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bench.presets import BenchPreset


def module_megabytes(*modules: Any) -> float:
    """Size of the parameters and buffers of ``modules`` in MiB (the 'Memory' column)."""
    total = 0
    for m in modules:
        for t in [*m.parameters(), *m.buffers()]:
            total += t.numel() * t.element_size()
    return total / 2**20


def evaluate_cell(
    render: Callable[[Any], Any], scene: Any, preset: BenchPreset, *, speed: bool = True, regions: bool = True
) -> dict[str, Any]:
    """``{"metrics", "per_view", "details"}`` of ``render`` on ``scene``'s test views under ``preset``."""
    import torch

    from moegs.metrics import measure_render
    from moegs.train.evaluate import eval_views, evaluate_renderer

    views = eval_views(scene.test, preset.test_views)
    if not views:
        raise ValueError(f"scene {scene.name} has no test views")
    scores = evaluate_renderer(render, views, preset.metric_profile, regions=regions)
    per_view = scores.pop("per_view")
    profile = scores.pop("profile")
    details: dict[str, Any] = {
        "num_views": scores.pop("num_views"),
        "lpips_unavailable": scores.pop("lpips_unavailable"),
        "region_masks": scores.pop("region_masks"),
    }
    metrics = {k: v for k, v in scores.items() if v is not None or k in ("psnr", "ssim", "lpips")}
    if speed:
        cams = [v.camera for v in views[: max(1, preset.speed_views)]]

        def timed(cam: Any) -> Any:
            with torch.no_grad():
                return render(cam)

        sp = measure_render(timed, cams, warmup=preset.speed_warmup, repeats=preset.speed_repeats)
        metrics["fps"] = sp.fps_median
        details["speed"] = {k: v for k, v in sp.to_dict().items() if k != "samples_ms"}
    return {"metrics": metrics, "per_view": per_view, "details": details, "metric_profile": profile}
