"""STG's error-guided sampling ("ems", ``emsstart``): new Gaussians along the rays of badly fitted pixels.

Written from ``oppo-us-research/SpacetimeGaussians`` @ 427abfc (``train.py:130-147,160-161,203-230,
262-387``; ``thirdparty/gaussian_splatting/scene/oursfull.py:1153-1261``); the steps are described in
``specs`` (audit of 2026-11-24). Per run:

1. **census** (before training): the farthest depth each training camera sees at the first frame with the
   initial model (``far_depths``);
2. **collect** (from ``guided_from``): the SSIM of each camera's first render;
3. **select**: the two cameras with the lowest SSIM below 0.91 (none when fewer than two are);
4. **trigger**: when the last view of a step is a selected camera, more than ``gap`` iterations after the
   previous event, and its SSIM is below 0.88: flag 16x16 patches where more than 85 % of the pixels are
   among the 40 % worst (normalised absolute error), take their pixels with an odd row or column, away
   from a 10 % border, and add one Gaussian per pixel at ``far_depth x r`` (+-5 % jitter) for each ratio
   ``r`` (0.7, 7.5): colour from the ground truth, opacity 0.1, random time centre, 3-NN scale.

Deviations: the census takes the expected depth where alpha >= 0.5 (STG's rasteriser returns the depth
where transmittance first drops below 0.5); new Gaussians get the identity rotation (STG: the zero
quaternion, which its rasteriser turns into the identity; ours normalises rotations).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.points import knn_mean_distance
from moegs.metrics import ssim
from moegs.render.projection import rgb_to_sh0

PATCH = 16
PATCH_FULL = 0.85  # a patch is flagged when more than this share of its pixels is bad
BORDER = 0.1  # rows / columns cleared at each image border


@torch.no_grad()
def far_depth(depth: Tensor, alpha: Tensor) -> float:
    """The census depth of one render: the largest expected depth where ``alpha >= 0.5`` (0 if none)."""
    covered = alpha >= 0.5
    return float(depth[covered].max()) if bool(covered.any()) else 0.0


@torch.no_grad()
def view_ssim(rgb: Tensor, target: Tensor) -> float:
    """3DGS SSIM of a render ``[H, W, 3]`` against its ground truth."""
    return float(ssim(rgb.clamp(0.0, 1.0), target, variant="3dgs"))


@torch.no_grad()
def error_pixels(rgb: Tensor, target: Tensor, quantile: float) -> Tensor:
    """``[P, 2]`` (row, col) pixels to seed: inside flagged patches, odd row or odd column, off the border.

    The error is ``sum_c |rgb / (mean(rgb) + 0.01) - target / (mean(target) + 0.01)|``; bad pixels are
    those above its value at sorted position ``floor(quantile H W)``.
    """
    h, w = target.shape[:2]
    err = (rgb / (rgb.mean() + 0.01) - target / (target.mean() + 0.01)).abs().sum(-1)
    threshold = err.flatten().sort().values[int(quantile * h * w)]
    bad = (err > threshold).float()
    ph, pw = (h // PATCH + 1) * PATCH, (w // PATCH + 1) * PATCH
    padded = torch.nn.functional.pad(bad, (0, pw - w, 0, ph - h))
    counts = padded.view(ph // PATCH, PATCH, pw // PATCH, PATCH).sum((1, 3))  # [ph/16, pw/16]
    flagged = (counts > PATCH_FULL * PATCH * PATCH).repeat_interleave(PATCH, 0).repeat_interleave(PATCH, 1)
    rows = torch.arange(ph, device=bad.device)[:, None] % 2 == 1
    cols = torch.arange(pw, device=bad.device)[None, :] % 2 == 1
    keep = (flagged & (rows | cols))[:h, :w].clone()
    bh, bw = int(h * BORDER), int(w * BORDER)
    keep[:bh], keep[h - bh :], keep[:, :bw], keep[:, w - bw :] = False, False, False, False
    return keep.nonzero()


@torch.no_grad()
def pixel_points(camera: Camera, pixels: Tensor, depth: float, ratios: tuple[float, ...], g=None) -> Tensor:
    """World points ``[len(ratios) * P, 3]`` on the rays of ``pixels [P, 2]`` at camera z
    ``(depth + depth / 10 (U - 0.5)) r`` for each ratio ``r`` (ratio-major order), on the pixels' device;
    ``U`` from ``g`` (on its device), else from the global generator of the pixels' device."""
    k = camera.K.to(pixels.device)
    v = pixels[:, 1].to(k.dtype) + 0.5
    u = pixels[:, 0].to(k.dtype) + 0.5
    rays = torch.stack([(v - k[0, 2]) / k[0, 0], (u - k[1, 2]) / k[1, 1], torch.ones_like(u)], -1)  # z = 1
    c2w = torch.linalg.inv(camera.world_to_camera.to(pixels.device))
    out = []
    for r in ratios:
        noise = torch.rand(
            len(pixels), generator=g, dtype=k.dtype, device=k.device if g is None else g.device
        )
        z = (depth + depth / 10.0 * (noise.to(k) - 0.5)) * r
        cam = rays * z[:, None]
        out.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
    return torch.cat(out)


@torch.no_grad()
def new_rows(params, points: Tensor, rgb: Tensor, trbf_scale: float) -> dict[str, Tensor]:
    """Rows of every per-Gaussian tensor of an STG model for new Gaussians at ``points [M, 3]`` with
    colours ``rgb [M, 3]``; ``KeyError`` names a tensor this function does not know."""
    m = points.shape[0]
    like = params["means"]
    everything = torch.cat([like.detach(), points.to(like)])
    d2 = knn_mean_distance(everything, 3, squared=True, last=m).clamp_min(1e-7)  # the new points' only
    log_scale = torch.log(torch.sqrt(d2)).clamp(-10.0, 1.0)[:, None].repeat(1, 3)
    rgb = rgb.to(like)
    known = {
        "means": points.to(like),
        "scales": log_scale,
        "quats": like.new_tensor([1.0, 0.0, 0.0, 0.0]).repeat(m, 1),
        "opacities": like.new_full((m,), math.log(0.1 / 0.9)),
        "motion": like.new_zeros(m, 9),
        "omega": like.new_zeros(m, 4),
        "trbf_center": torch.rand(m, device=like.device).to(like),
        "trbf_scale": like.new_full((m,), float(trbf_scale)),
        "features": torch.cat([rgb, torch.zeros_like(rgb)], 1),
        "features_t": like.new_zeros(m, 3),
        "rgb": rgb,
        "sh0": rgb_to_sh0(rgb)[:, None, :],
    }
    rows = {}
    for key, value in params.items():
        if key == "shN":
            rows[key] = value.new_zeros((m, *value.shape[1:]))
        elif key in known:
            rows[key] = known[key]
        else:
            raise KeyError(f"STG guided sampling does not know how to initialise per-Gaussian tensor {key!r}")
    return rows
