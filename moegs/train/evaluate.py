"""Score renders on held-out views: the one evaluation every command, the MoE-GS router and the bench use.

Every view is scored on the full image and, when it has a mask (``View.mask()``: a stand-in's ground-truth
dynamic mask, D-NeRF's object alpha, Panoptic's foreground segmentation), on its **dynamic** region
(mask > 0.5) and its **static** complement: PSNR over the region's pixels, SSIM and LPIPS as the
region-weighted means of their spatial maps. Keys: ``psnr``, ``ssim``, ``lpips`` and
``<metric>_dynamic`` / ``<metric>_static``; ``motion_r2``, over the test cameras seen at several times,
says how much of the dynamic region's change over time the renders reproduce (``moegs.metrics.motion``).
Views with named regions (``View.regions()``: a stand-in's motion regimes) also get ``psnr_regions``, the
PSNR of each region over the squared error pooled across every pixel of it in every view (a region that
some views do not show, such as a transient object, still gets one value).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import View
from moegs.experts.base import Expert
from moegs.metrics import evaluate_images
from moegs.metrics.motion import MotionCapture

METRICS = ("psnr", "ssim", "lpips")
REGIONS = ("dynamic", "static")
KEYS = METRICS + tuple(f"{m}_{r}" for r in REGIONS for m in METRICS)
"""Every score of a view: the full image, then each region."""


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
    index = torch.linspace(0, len(views) - 1, max_views, device="cpu").round().long().tolist()
    return [views[i] for i in index]


@torch.no_grad()
def score_image(image: Tensor, target: Tensor, mask: Tensor | None, profile: str = "moegs") -> dict[str, Any]:
    """``KEYS`` of one render ``[H, W, 3]`` (region keys only with a ``mask [H, W]``; a region without
    pixels scores None), plus ``lpips_unavailable`` and ``profile``."""
    scores = evaluate_images(image, target, profile)
    out: dict[str, Any] = {k: scores[k] for k in METRICS}
    out.update(lpips_unavailable=scores["lpips_unavailable"], profile=scores["profile"])
    if mask is not None:
        dynamic = (mask > 0.5).to(image.dtype)
        for name, region in zip(REGIONS, (dynamic, 1.0 - dynamic), strict=True):
            r = evaluate_images(image, target, profile, mask=region) if bool(region.any()) else {}
            out.update({f"{m}_{name}": r.get(m) for m in METRICS})
    return out


def mean_scores(rows: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """Mean of each ``KEYS`` entry over the rows that have it (None when none has it, or when some view
    has no full-image value, e.g. LPIPS without weights)."""
    out: dict[str, float | None] = {}
    for key in KEYS:
        values = [r.get(key) for r in rows]
        if key in METRICS and any(v is None for v in values):
            out[key] = None
            continue
        present = [v for v in values if v is not None]
        out[key] = sum(present) / len(present) if present else None
    return out


class RegionErrors:
    """Squared error and pixel count per named region, pooled over views; ``psnr()`` per region (peak 1)."""

    def __init__(self) -> None:
        self.sums: dict[str, float] = {}
        self.counts: dict[str, float] = {}

    def add(self, image: Tensor, target: Tensor, regions: dict[str, Tensor]) -> None:
        """One render ``[H, W, C]``, its target and the view's region masks ``{name: [H, W]}``."""
        if not regions:
            return
        error = (image - target).square().sum(-1).double()  # [H, W], summed over channels (raw, as psnr)
        for name, mask in regions.items():
            if mask.shape != error.shape:
                raise ValueError(f"region {name!r}: mask {list(mask.shape)} != image {list(error.shape)}")
            self.sums[name] = self.sums.get(name, 0.0) + float((error * mask).sum())
            self.counts[name] = self.counts.get(name, 0.0) + float(mask.sum()) * image.shape[-1]

    def psnr(self) -> dict[str, float | None]:
        """``{name: PSNR}`` of the pooled mean squared error (None for a region no view shows)."""
        out: dict[str, float | None] = {}
        for name in sorted(self.sums):
            n = self.counts[name]
            out[name] = -10.0 * math.log10(max(self.sums[name] / n, 1e-12)) if n > 0 else None
        return out


Rendered = Tensor | tuple[Tensor, dict[str, Tensor]]
"""What a renderer under evaluation returns: an image ``[H, W, 3]``, or the image and named component
images (e.g. each expert of a mixture), scored against the same target and masks."""


@torch.no_grad()
def evaluate_renderer(
    render: Callable[[Camera], Rendered], views: Sequence[View], profile: str = "moegs", regions: bool = True
) -> dict[str, Any]:
    """Mean ``KEYS`` of ``render(camera)`` (see ``Rendered``) over ``views`` and the per-view values.

    Returns:
        ``{**KEYS, "motion_r2", "psnr_regions", "lpips_unavailable", "profile", "num_views", "region_masks",
        "per_view": [{"key", "camera", "time", **KEYS}], "components": {name: mean KEYS}}``: ``camera`` is
        the view's ``camera_id``; ``motion_r2`` the temporal R² of the dynamic region
        (``moegs.metrics.motion``; None without a camera seen at several times with masks);
        ``psnr_regions`` the pooled PSNR of each named region (empty without ``View.regions``);
        ``region_masks`` says whether any view had a mask; ``components`` is there only when ``render``
        returns component images too.
    """
    if not views:
        raise ValueError("evaluate_renderer needs at least one view")
    per_view, unavailable, prof, motion, pooled = [], None, None, MotionCapture(), RegionErrors()
    components: dict[str, list[dict[str, Any]]] = {}
    for view in views:
        image, parts = _split(render(view.camera))
        target, mask = view.image(), view.mask() if regions else None
        scores = score_image(image, target, mask, profile)
        for name, part in parts.items():
            components.setdefault(name, []).append(score_image(part, target, mask, profile))
        if mask is not None:
            motion.add(view.camera, image, target, mask)
        if regions:
            pooled.add(image, target, view.regions())
        unavailable, prof = scores.pop("lpips_unavailable"), scores.pop("profile")
        per_view.append(
            {"key": view.key, "camera": view.camera.camera_id, "time": float(view.camera.time), **scores}
        )
    return {
        **mean_scores(per_view),
        "motion_r2": motion.value(),
        "psnr_regions": pooled.psnr(),
        "lpips_unavailable": unavailable,
        "profile": prof,
        "num_views": len(views),
        "region_masks": any("psnr_dynamic" in r for r in per_view),
        "per_view": per_view,
        **(
            {"components": {name: mean_scores(rows) for name, rows in components.items()}}
            if components
            else {}
        ),
    }


def _split(rendered: Rendered) -> tuple[Tensor, dict[str, Tensor]]:
    return rendered if isinstance(rendered, tuple) else (rendered, {})


def evaluate(
    expert: Expert,
    views: list[View],
    background: Tensor | None,
    profile: str = "moegs",
    backend: str = "auto",
) -> dict[str, Any]:
    """:func:`evaluate_renderer` of one expert (its training render path, without gradients)."""
    return evaluate_renderer(
        lambda camera: render_view(expert, camera, background, backend)[0], views, profile
    )
