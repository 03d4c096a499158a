"""Initial point clouds for the loaders: dataset files (PLY, COLMAP) or random fallbacks.

Random samplers come from ``moegs.data.points`` (``random_in_box``, ``random_in_frusta``); colours
follow the 3DGS random initialisation (grey 0.5 plus a tiny jitter).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import PointCloud

_SH_C0 = 0.28209479177387814


def greyish_colors(n: int, seed: int) -> Tensor:
    """3DGS random-init colours ``SH2RGB(U[0,1) / 255)``: grey 0.5 plus a tiny jitter, ``[n, 3]``."""
    gen = torch.Generator().manual_seed(seed + 1)
    return 0.5 + _SH_C0 * torch.rand(n, 3, generator=gen) / 255.0


def box_points(bbox: Tensor, n: int, seed: int = 0) -> PointCloud:
    """``n`` uniform points in ``bbox [2, 3]`` (``moegs.data.points.random_in_box``), grey-ish colours."""
    from moegs.data.points import random_in_box

    xyz = random_in_box(bbox, n, seed)
    lo, hi = ([round(float(x), 4) for x in b] for b in bbox)
    return PointCloud(xyz=xyz, rgb=greyish_colors(n, seed), source=f"random {n} in box {lo}..{hi}")


def frusta_points(cameras: Sequence[Camera], n: int, near: float, far: float, seed: int = 0) -> PointCloud:
    """``n`` random points inside the cameras' view frusta between ``near`` and ``far``, grey-ish colours."""
    from moegs.data.points import random_in_frusta

    xyz = random_in_frusta(list(cameras), n, near, far, seed)
    return PointCloud(
        xyz=xyz,
        rgb=greyish_colors(n, seed),
        source=f"random {n} in {len(cameras)} camera frusta, depth {near:g}..{far:g}",
    )


def visible_count(xyz: Tensor, cameras: list[Camera]) -> Tensor:
    """How many of ``cameras`` see each point of ``xyz [P, 3]`` (in front and inside the image), ``[P]``."""
    count = torch.zeros(xyz.shape[0], dtype=torch.int32)
    for cam in cameras:
        p = xyz @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        uv = p @ cam.K.T
        z = p[:, 2].clamp_min(1e-9)
        u, v = uv[:, 0] / z, uv[:, 1] / z
        count += ((p[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)).int()
    return count


def shared_volume_points(
    cameras: Sequence[Camera], n: int, near: float, far: float, seed: int, why: str
) -> PointCloud:
    """Frusta points kept only where at least half of ``cameras`` see them (the common capture volume)."""
    cloud = frusta_points(cameras, 4 * n, near, far, seed)
    keep = visible_count(cloud.xyz, list(cameras)) >= (len(cameras) + 1) // 2
    idx = keep.nonzero().squeeze(1)[:n]
    if idx.numel() == 0:
        idx = torch.arange(min(n, len(cloud)))
    return PointCloud(
        xyz=cloud.xyz[idx],
        rgb=cloud.rgb[idx],
        source=f"fallback ({why}): {cloud.source}, kept {idx.numel()} seen by >= half of "
        f"{len(cameras)} cameras",
    )


def ply_points(path: Path) -> PointCloud:
    """xyz and rgb (0..255 -> [0, 1]) of a PLY vertex element (3DGS ``fetchPly`` fields)."""
    from plyfile import PlyData

    try:
        vertex = PlyData.read(str(path))["vertex"]
        xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=-1).astype(np.float32)
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"cannot read points from PLY {path}: {err}") from err
    names = vertex.data.dtype.names
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=-1).astype(np.float32) / 255.0
    else:
        rgb = np.full_like(xyz, 0.5)
    return PointCloud(
        xyz=torch.from_numpy(xyz), rgb=torch.from_numpy(rgb), source=f"{path.name} ({len(xyz)} points)"
    )


def colmap_points(rec: Any, where: Path) -> PointCloud:
    """The 3D points of a ``pycolmap.Reconstruction`` (xyz, rgb in [0, 1])."""
    pts = list(rec.points3D.values())
    if not pts:
        raise ValueError(f"COLMAP model {where} has no 3D points")
    xyz = torch.tensor(np.stack([p.xyz for p in pts]), dtype=torch.float32)
    rgb = torch.tensor(np.stack([p.color for p in pts]), dtype=torch.float32) / 255.0
    return PointCloud(xyz=xyz, rgb=rgb, source=f"COLMAP {where} ({len(pts)} points)")
