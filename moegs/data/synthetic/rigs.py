"""Camera rigs: an N3V-like forward-facing multi-view rig and a D-NeRF-like monocular orbit."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from moegs.camera import Camera, intrinsics, look_at


def pinhole(width: int, height: int, hfov_deg: float) -> Tensor:
    """``[3, 3]`` intrinsics with square pixels and the principal point at the image centre
    (the only intrinsics both the LLFF ``hwf`` and the D-NeRF ``camera_angle_x`` can express)."""
    f = 0.5 * width / math.tan(0.5 * math.radians(hfov_deg))
    return intrinsics(f, f, width / 2.0, height / 2.0)


def forward_facing_rig(
    n: int,
    target: Tensor,
    width: int,
    height: int,
    hfov_deg: float,
    *,
    center: tuple[float, float, float] = (0.0, -1.0, 1.35),
    span: float = 2.0,
    rows_dz: float = 0.25,
    seed: int = 0,
) -> list[Camera]:
    """``n`` cameras on a shallow arc facing ``target`` (N3V-like). Camera 0 sits in the middle of the rig
    (the held-out test camera, as ``cam00`` in N3V); cameras 1..n-1 alternate between two rows spread
    over ``span`` metres along x, with a small seeded jitter.

    Returns:
        cameras with ``camera_id`` 0..n-1 and names ``cam00`` ... (``time``/``frame`` set later).
    """
    if n < 3:
        raise ValueError(f"forward_facing_rig needs at least 3 cameras (1 test + 2 train), got {n}")
    g = torch.Generator().manual_seed(10_007 + seed)
    cx, cy, cz = center
    K = pinhole(width, height, hfov_deg)
    eyes = [torch.tensor([cx, cy, cz])]
    m = n - 1
    for i in range(m):
        u = -1.0 + 2.0 * i / max(m - 1, 1)
        dz = rows_dz if i % 2 else -rows_dz
        jitter = (torch.rand(3, generator=g) - 0.5) * torch.tensor([0.08, 0.08, 0.06])
        eyes.append(torch.tensor([cx + 0.5 * span * u, cy + 0.25 * u * u, cz + dz]) + jitter)
    cams = []
    for k, eye in enumerate(eyes):
        w2c = look_at(eye, target)
        cams.append(
            Camera(
                K=K.clone(), world_to_camera=w2c, width=width, height=height, camera_id=k, name=f"cam{k:02d}"
            )
        )
    return cams


def orbit_cameras(
    times: list[float],
    target: Tensor,
    radius: float,
    width: int,
    height: int,
    hfov_deg: float,
    *,
    elev_deg: tuple[float, float] = (15.0, 55.0),
    seed: int = 0,
    prefix: str = "r",
) -> list[Camera]:
    """One camera per time on the upper hemisphere around ``target`` (D-NeRF-like: random azimuth and
    elevation per frame, seeded). Returns cameras with ``time`` set, ``frame`` = index, names ``r_000``..."""
    g = torch.Generator().manual_seed(20_011 + seed)
    K = pinhole(width, height, hfov_deg)
    cams = []
    for i, t in enumerate(times):
        az = float(torch.rand((), generator=g)) * 2.0 * math.pi
        el = math.radians(elev_deg[0] + float(torch.rand((), generator=g)) * (elev_deg[1] - elev_deg[0]))
        eye = target + radius * torch.tensor(
            [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
        )
        cams.append(
            Camera(
                K=K.clone(),
                world_to_camera=look_at(eye, target),
                width=width,
                height=height,
                time=float(t),
                camera_id=0,
                frame=i,
                name=f"{prefix}_{i:03d}",
            )
        )
    return cams
