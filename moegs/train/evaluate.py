"""Render an expert and score it on held-out views."""

from __future__ import annotations

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import View
from moegs.experts.base import Expert
from moegs.metrics import evaluate_images


def render_view(
    expert: Expert,
    camera: Camera,
    background: Tensor | None,
    backend: str = "auto",
    return_stats: bool = False,
):
    """``(rgb [H, W, 3], RenderOutput, frame)`` of ``expert`` at the camera's time (with gradients)."""
    return expert.render(camera, background, backend, return_stats)


def eval_views(views: list[View], max_views: int | None) -> list[View]:
    """At most ``max_views`` views, evenly spaced (all when None)."""
    if max_views is None or max_views >= len(views):
        return list(views)
    if max_views < 1:
        raise ValueError(f"max_views must be >= 1, got {max_views}")
    index = torch.linspace(0, len(views) - 1, max_views).round().long().tolist()
    return [views[i] for i in index]


@torch.no_grad()
def evaluate(
    expert: Expert,
    views: list[View],
    background: Tensor | None,
    profile: str = "moegs",
    backend: str = "auto",
) -> dict:
    """Mean PSNR / SSIM / LPIPS over ``views`` plus the per-view values.

    Returns:
        ``{"psnr", "ssim", "lpips", "lpips_unavailable", "profile", "num_views", "per_view": [{"key",
        "time", "psnr", "ssim", "lpips"}]}``; ``lpips`` is None when the weights are unavailable.
    """
    if not views:
        raise ValueError("evaluate() needs at least one view")
    per_view, unavailable, prof = [], None, None
    for view in views:
        rgb, _, _ = render_view(expert, view.camera, background, backend)
        scores = evaluate_images(rgb, view.image(), profile)
        unavailable, prof = scores["lpips_unavailable"], scores["profile"]
        per_view.append(
            {"key": view.key, "time": view.camera.time, **{k: scores[k] for k in ("psnr", "ssim", "lpips")}}
        )

    def mean(key: str) -> float | None:
        values = [v[key] for v in per_view]
        return None if any(x is None for x in values) else sum(values) / len(values)

    return {
        "psnr": mean("psnr"),
        "ssim": mean("ssim"),
        "lpips": mean("lpips"),
        "lpips_unavailable": unavailable,
        "profile": prof,
        "num_views": len(views),
        "per_view": per_view,
    }
