"""Multi-view depth consistency (MoE-GS appendix, eq. MDC).

    MDC = 1/|P| sum_{(i, j) in P} || Pi_j(D_i) - D_j ||_1

over all ordered view pairs ``P`` at one time: every pixel of depth map ``D_i`` with a depth is lifted to
3D with camera ``i``, projected into camera ``j``, and its camera-``j`` depth is compared with ``D_j``
sampled (bilinearly) at the projected position. Depths are camera z (as ``rasterize`` returns them); a
pixel counts where ``D_i > 0``, the point lands inside image ``j`` in front of it, and the four ``D_j``
samples around it are all > 0. Each pair's error is the mean over its counted pixels; pairs with no
counted pixel are skipped (and reported by ``mdc_pairs``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from moegs.camera import Camera


def _check(depths: Sequence[Tensor], cameras: Sequence[Camera]) -> None:
    if len(depths) != len(cameras):
        raise ValueError(f"mdc: {len(depths)} depth maps but {len(cameras)} cameras")
    if len(depths) < 2:
        raise ValueError(f"mdc needs at least two views, got {len(depths)}")
    for i, (d, cam) in enumerate(zip(depths, cameras, strict=True)):
        if not isinstance(d, Tensor) or tuple(d.shape) != (cam.height, cam.width):
            shape = list(d.shape) if isinstance(d, Tensor) else type(d).__name__
            raise ValueError(f"mdc: depths[{i}] must have shape [{cam.height}, {cam.width}], got {shape}")
        if not torch.isfinite(d).all():
            raise FloatingPointError(f"mdc: depths[{i}] contains NaN or Inf")


def _lift(depth: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """World points ``[M, 3]`` of the pixels with depth > 0, and their mask ``[H, W]``."""
    valid = depth > 0
    ys, xs = torch.nonzero(valid, as_tuple=True)
    z = depth[valid]
    pix = torch.stack([xs + 0.5, ys + 0.5, torch.ones_like(z)], dim=-1).to(depth.dtype)
    cam_points = (pix @ torch.linalg.inv(camera.K.to(depth.dtype)).T) * z[:, None]
    c2w = camera.camera_to_world.to(depth.dtype)
    return cam_points @ c2w[:3, :3].T + c2w[:3, 3], valid


def _pair_error(depth_i: Tensor, cam_i: Camera, depth_j: Tensor, cam_j: Camera) -> Tensor | None:
    """Mean |z_j(lifted D_i) - D_j(projection)| over the counted pixels, or None when there are none."""
    points, _ = _lift(depth_i, cam_i)
    w2c = cam_j.world_to_camera.to(points.dtype)
    local = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = local[:, 2]
    front = z > 1e-6
    uv = (local[:, :2] / z.clamp_min(1e-6)[:, None]) @ cam_j.K[:2, :2].to(points.dtype).T + cam_j.K[:2, 2].to(
        points.dtype
    )
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5  # pixel-centre coordinates
    h, w = depth_j.shape
    inside = front & (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    if not inside.any():
        return None
    x, y, z = x[inside], y[inside], z[inside]
    x0, y0 = (
        x.floor().long().clamp(max=w - 2 if w > 1 else 0),
        y.floor().long().clamp(max=h - 2 if h > 1 else 0),
    )
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    fx, fy = x - x0, y - y0
    corners = torch.stack([depth_j[y0, x0], depth_j[y0, x1], depth_j[y1, x0], depth_j[y1, x1]])
    sampled = (
        corners[0] * (1 - fx) * (1 - fy)
        + corners[1] * fx * (1 - fy)
        + corners[2] * (1 - fx) * fy
        + corners[3] * fx * fy
    )
    ok = (corners > 0).all(0)
    if not ok.any():
        return None
    return (z[ok] - sampled[ok]).abs().mean()


@torch.no_grad()
def mdc_pairs(depths: Sequence[Tensor], cameras: Sequence[Camera]) -> dict[tuple[int, int], float | None]:
    """The error of every ordered pair ``(i, j)``, None where no pixel could be compared."""
    _check(depths, cameras)
    out: dict[tuple[int, int], float | None] = {}
    for i in range(len(depths)):
        for j in range(len(depths)):
            if i != j:
                err = _pair_error(depths[i], cameras[i], depths[j], cameras[j])
                out[(i, j)] = None if err is None else float(err)
    return out


def mdc(depths: Sequence[Tensor], cameras: Sequence[Camera]) -> float:
    """Mean reprojection L1 depth error over ordered view pairs (scene units); NaN when no pair overlaps.

    Args:
        depths: ``V >= 2`` depth maps ``[H_v, W_v]`` (camera z, 0 = empty) at one time.
        cameras: the ``V`` cameras that rendered them.
    """
    errors = [e for e in mdc_pairs(depths, cameras).values() if e is not None]
    return sum(errors) / len(errors) if errors else float("nan")
