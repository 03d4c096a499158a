"""A cell's evaluation: the preset's test views and metric profile, scored by the library's one evaluation,
plus render speed and model size.

``render(camera) -> image [H, W, 3]`` is called under ``torch.no_grad``. Scores come from
``moegs.train.evaluate.evaluate_renderer`` (this module adds no metric of its own): full image,
dynamic region and static region (synthetic stand-ins: ground-truth dynamic mask; D-NeRF: object alpha;
Panoptic: foreground segmentation), and on stand-ins each motion regime (``psnr_regime_<category>``, the
pooled PSNR of the pixels of its objects). Below a real scene's native resolution, with ``native`` given
(``Context.native_scene``), the renders are also upsampled (bicubic) to the native test images and
scored there (``psnr_native``: what the paper's resolution would see of this model). Speed follows
``moegs.metrics.speed.measure_render`` (render call only, warm-up, median per view).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bench.presets import BenchPreset

REGIME_PREFIX = "psnr_regime_"
"""Metric key prefix of the PSNR of one named region (a stand-in's motion regime, ``View.regions``)."""


def module_megabytes(*modules: Any) -> float:
    """Size of the parameters and buffers of ``modules`` in MiB (the 'Memory' column)."""
    total = 0
    for m in modules:
        for t in [*m.parameters(), *m.buffers()]:
            total += t.numel() * t.element_size()
    return total / 2**20


def psnr_upsampled(render: Callable[[Any], Any], views: list[Any], native_views: list[Any]) -> float:
    """Mean PSNR of ``render(view.camera)`` upsampled (bicubic) to the image of the matching native view."""
    import torch
    import torch.nn.functional as F

    from moegs.metrics import psnr

    values = []
    with torch.no_grad():
        for view, full in zip(views, native_views, strict=True):
            gt = full.image()
            rgb = render(view.camera).permute(2, 0, 1)[None]
            up = F.interpolate(rgb, size=gt.shape[:2], mode="bicubic", align_corners=False)
            values.append(float(psnr(up[0].permute(1, 2, 0).clamp(0, 1), gt)))
    return sum(values) / len(values)


def evaluate_cell(
    render: Callable[[Any], Any],
    scene: Any,
    preset: BenchPreset,
    *,
    speed: bool = True,
    regions: bool = True,
    native: Any = None,
) -> dict[str, Any]:
    """``{"metrics", "per_view", "details"}`` of ``render`` on ``scene``'s test views under ``preset``
    (``native``: the same scene at native resolution, for ``psnr_native``)."""
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
    regimes = scores.pop("psnr_regions")
    metrics = {k: v for k, v in scores.items() if v is not None or k in ("psnr", "ssim", "lpips")}
    metrics.update({f"{REGIME_PREFIX}{name}": v for name, v in regimes.items() if v is not None})
    if native is not None:
        metrics["psnr_native"] = psnr_upsampled(render, views, eval_views(native.test, preset.test_views))
        details["native_size"] = [native.test[0].camera.width, native.test[0].camera.height]
    if speed:
        cams = [v.camera for v in views[: max(1, preset.speed_views)]]

        def timed(cam: Any) -> Any:
            with torch.no_grad():
                return render(cam)

        sp = measure_render(timed, cams, warmup=preset.speed_warmup, repeats=preset.speed_repeats)
        metrics["fps"] = sp.fps_median
        details["speed"] = {k: v for k, v in sp.to_dict().items() if k != "samples_ms"}
    return {"metrics": metrics, "per_view": per_view, "details": details, "metric_profile": profile}
