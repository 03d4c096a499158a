"""Score any renderer on a scene's test views: image metrics, region metrics, speed, model size.

``render(camera) -> image [H, W, 3]`` is called under ``torch.no_grad``. Metrics use the preset's
``moegs.metrics`` profile; region metrics use the views' masks (synthetic stand-ins: ground-truth
dynamic mask; Panoptic: foreground segmentation) as the dynamic region and their complement as the
static region. Speed follows ``moegs.metrics.speed.measure_render`` (render call only, warm-up,
median per view).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bench.presets import BenchPreset

_VIEW_KEYS = ("psnr", "ssim", "lpips", "psnr_dynamic", "ssim_dynamic", "psnr_static", "ssim_static")


def module_megabytes(*modules: Any) -> float:
    """Size of the parameters and buffers of ``modules`` in MiB (the 'Memory' column)."""
    total = 0
    for m in modules:
        for t in [*m.parameters(), *m.buffers()]:
            total += t.numel() * t.element_size()
    return total / 2**20


def _mean(rows: list[dict[str, Any]], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return sum(vals) / len(vals) if vals else None


def evaluate_renderer(
    render: Callable[[Any], Any], scene: Any, preset: BenchPreset, *, speed: bool = True, regions: bool = True
) -> dict[str, Any]:
    """``{"metrics", "per_view", "details"}`` of ``render`` on ``scene``'s test views under ``preset``."""
    import torch

    from moegs.metrics import evaluate_images, measure_render
    from moegs.train.evaluate import eval_views

    views = eval_views(scene.test, preset.test_views)
    if not views:
        raise ValueError(f"scene {scene.name} has no test views")
    profile, per_view = None, []
    lpips_unavailable = None
    with torch.no_grad():
        for view in views:
            image, target = render(view.camera), view.image()
            scores = evaluate_images(image, target, preset.metric_profile)
            profile, lpips_unavailable = scores["profile"], scores["lpips_unavailable"]
            row = {
                "key": view.key,
                "time": float(view.camera.time),
                **{k: scores[k] for k in ("psnr", "ssim", "lpips")},
            }
            mask = view.mask() if regions else None
            if mask is not None:
                dynamic = (mask > 0.5).float()
                for name, region in (("dynamic", dynamic), ("static", 1.0 - dynamic)):
                    if float(region.sum()) > 0:
                        r = evaluate_images(image, target, preset.metric_profile, mask=region)
                        row[f"psnr_{name}"], row[f"ssim_{name}"] = r["psnr"], r["ssim"]
            per_view.append(row)
    metrics = {k: _mean(per_view, k) for k in _VIEW_KEYS}
    metrics = {k: v for k, v in metrics.items() if v is not None or k in ("psnr", "ssim", "lpips")}
    details: dict[str, Any] = {
        "num_views": len(views),
        "lpips_unavailable": lpips_unavailable,
        "region_masks": any("psnr_dynamic" in r for r in per_view),
    }
    if speed:
        cams = [v.camera for v in views[: max(1, preset.speed_views)]]

        def timed(cam: Any) -> Any:
            with torch.no_grad():
                return render(cam)

        sp = measure_render(timed, cams, warmup=preset.speed_warmup, repeats=preset.speed_repeats)
        metrics["fps"] = sp.fps_median
        details["speed"] = {k: v for k, v in sp.to_dict().items() if k != "samples_ms"}
    return {"metrics": metrics, "per_view": per_view, "details": details, "metric_profile": profile}
