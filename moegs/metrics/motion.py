"""Motion capture: how much of the ground truth's change over time a model reproduces.

For one fixed camera seen at ``T`` times, with ground truth ``G_t``, renders ``R_t`` and residuals
``D_t = R_t - G_t`` (``[H, W, 3]``), the **temporal R²** over a pixel region ``M`` is

    R² = 1 - sum_{t, p in M} |D_t(p) - mean_t D(p)|² / sum_{t, p in M} |G_t(p) - mean_t G(p)|²,

i.e. one minus the residual's variation over time relative to the ground truth's. A render that does
not change over time scores 0 (up to the static error it shares with every frame), one that follows the
ground truth exactly scores 1, and one that changes in the wrong way scores below 0. PSNR cannot tell a
blurred average of the motion from a model of it; R² can. ``M`` is the union over time of the views'
dynamic masks (mask > 0.5): the pixels that something moving covers at some time.

``MotionCapture`` accumulates per-pixel sums over the views of each camera (float64, one camera's image
size each), so it never holds more than one frame of a sequence.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

MIN_TIMES = 3
"""Fewer distinct views of a camera than this say nothing about motion."""


@dataclass
class _Sums:
    """Per-pixel running sums of one camera: residual and ground truth, first and second moments."""

    residual: Tensor  # [H, W, 3] float64
    residual_sq: Tensor  # [H, W]
    target: Tensor  # [H, W, 3]
    target_sq: Tensor  # [H, W]
    region: Tensor  # [H, W] bool, union of the dynamic masks
    count: int = 0


class MotionCapture:
    """Temporal R² of renders in the dynamic region, over every camera seen at ``MIN_TIMES`` or more
    times (cameras are the same when their intrinsics, pose and size are)."""

    def __init__(self) -> None:
        self._cameras: dict[bytes, _Sums] = {}

    @torch.no_grad()
    def add(self, camera, image: Tensor, target: Tensor, mask: Tensor) -> None:
        """One view: ``image`` and ``target`` ``[H, W, 3]`` in [0, 1] (the render is clamped), ``mask``
        ``[H, W]``."""
        if image.shape != target.shape or image.shape[:2] != mask.shape:
            raise ValueError(
                f"MotionCapture.add: image {list(image.shape)}, target {list(target.shape)} and mask "
                f"{list(mask.shape)} must share [H, W]"
            )
        g = target.detach().to("cpu", torch.float64)
        d = image.detach().to("cpu", torch.float64).clamp(0.0, 1.0) - g
        key = camera.pose_key()
        sums = self._cameras.get(key)
        if sums is None:
            plane = torch.zeros(g.shape[:2], dtype=torch.float64, device="cpu")
            region = torch.zeros(g.shape[:2], dtype=torch.bool, device="cpu")
            sums = _Sums(torch.zeros_like(g), plane, torch.zeros_like(g), plane.clone(), region)
            self._cameras[key] = sums
        sums.residual += d
        sums.residual_sq += (d * d).sum(-1)
        sums.target += g
        sums.target_sq += (g * g).sum(-1)
        sums.region |= mask.detach().to("cpu") > 0.5
        sums.count += 1

    def value(self) -> float | None:
        """The temporal R², or None when no camera has ``MIN_TIMES`` views with a moving region."""
        residual = variation = 0.0
        for s in self._cameras.values():
            if s.count < MIN_TIMES or not bool(s.region.any()):
                continue
            m = s.region
            residual += float((s.residual_sq - (s.residual * s.residual).sum(-1) / s.count)[m].sum())
            variation += float((s.target_sq - (s.target * s.target).sum(-1) / s.count)[m].sum())
        if variation <= 0.0:
            return None
        return 1.0 - residual / variation
