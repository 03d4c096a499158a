"""Camera paths for ``moegs render``: the test views in time order, an orbit, or an LLFF-style spiral.

Every path is a list of :class:`~moegs.camera.Camera` with the intrinsics, image size and clipping planes
of a reference camera (the scene's first test view, else its first training view) and a time that
advances uniformly over the path's frames. ``orbit`` and ``spiral`` are built from the scene's cameras
only (no geometry):

- the **look-at centre** is the point nearest to every camera's optical axis (least squares);
- **up** is the mean of the cameras' up vectors (OpenCV: minus the camera's y axis);
- ``orbit`` circles the up axis through the centre at the cameras' mean height and horizontal radius,
  starting above the first camera and closing on itself (frame ``n`` would be frame 0 again), looking at
  the centre: the path for cameras that surround the scene (D-NeRF, Panoptic);
- ``spiral`` is NeRF's ``render_path_spiral`` for forward-facing rigs (N3V, Technicolor, LLFF): two turns
  around the mean camera, within the 90th percentile of the cameras' offsets from it in the mean camera's
  frame, looking at the look-at centre, also closed;
- ``auto`` picks ``orbit`` when the cameras look in many directions (their mean unit viewing direction is
  shorter than ``FORWARD_FACING``), ``spiral`` otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from moegs.camera import Camera, look_at

PATHS = ("auto", "test", "orbit", "spiral")
"""Path names ``moegs render --path`` accepts."""

FORWARD_FACING = 0.9
"""Length of the cameras' mean unit viewing direction from which a rig counts as forward-facing."""


def camera_axes(cameras: Sequence[Camera]) -> tuple[Tensor, Tensor, Tensor]:
    """``(centres [N, 3], forward [N, 3], up [N, 3])`` of ``cameras`` in world coordinates (float64, CPU)."""
    w2c = torch.stack([c.world_to_camera.detach().cpu().double() for c in cameras])  # [N, 4, 4]
    R, t = w2c[:, :3, :3], w2c[:, :3, 3]
    centres = -(R.transpose(1, 2) @ t[..., None])[..., 0]
    return centres, R[:, 2], -R[:, 1]


def look_at_centre(cameras: Sequence[Camera]) -> Tensor:
    """``[3]`` point nearest to every camera's optical axis in the least-squares sense (float64).

    Axes that are (nearly) parallel do not fix the point along their direction: a small ridge term then
    pulls it towards the cameras' mean centre pushed along their mean viewing direction by one mean
    camera distance."""
    centres, forward, _ = camera_axes(cameras)
    project = torch.eye(3, dtype=torch.float64) - forward[:, :, None] * forward[:, None, :]  # [N, 3, 3]
    A, b = project.sum(0), (project @ centres[..., None]).sum(0)[:, 0]
    spread = (centres - centres.mean(0)).norm(dim=-1).mean().clamp_min(1e-6)
    prior = centres.mean(0) + torch.nn.functional.normalize(forward.mean(0), dim=0) * spread
    ridge = 1e-4 * float(A.trace()) / 3
    return torch.linalg.solve(A + ridge * torch.eye(3, dtype=torch.float64), b + ridge * prior)


def world_up(cameras: Sequence[Camera]) -> Tensor:
    """``[3]`` unit world up vector: the mean of the cameras' up vectors (float64)."""
    up = camera_axes(cameras)[2].mean(0)
    if float(up.norm()) < 1e-6:
        raise ValueError("the cameras' up vectors cancel out; cannot choose an up direction for the path")
    return up / up.norm()


def is_forward_facing(cameras: Sequence[Camera]) -> bool:
    """True when the cameras look roughly one way (mean unit viewing direction >= ``FORWARD_FACING``)."""
    return float(camera_axes(cameras)[1].mean(0).norm()) >= FORWARD_FACING


def path_times(frames: int, start: float = 0.0, stop: float = 1.0) -> list[float]:
    """``frames`` times evenly spaced from ``start`` to ``stop`` (both included; ``[start]`` for one)."""
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    if frames == 1:
        return [float(start)]
    return [start + (stop - start) * k / (frames - 1) for k in range(frames)]


def _posed(reference: Camera, eye: Tensor, target: Tensor, up: Tensor, time: float, name: str) -> Camera:
    """``reference``'s intrinsics, size and planes at ``eye`` looking at ``target`` (float32, CPU)."""
    w2c = look_at(eye.float(), target.float(), up.float())
    return Camera(
        K=reference.K.detach().cpu().float(),
        world_to_camera=w2c,
        width=reference.width,
        height=reference.height,
        time=float(time),
        near=reference.near,
        far=reference.far,
        camera_id=reference.camera_id,
        name=name,
    )


def orbit_path(
    cameras: Sequence[Camera], reference: Camera, frames: int, times: tuple[float, float] = (0.0, 1.0)
) -> list[Camera]:
    """``frames`` cameras on a closed circle around ``look_at_centre(cameras)``, looking at it.

    The circle lies at the cameras' mean height along ``world_up`` and at their mean horizontal distance
    from the up axis through the centre; it starts at the first camera's bearing. Time runs from
    ``times[0]`` to ``times[1]``.
    """
    centres, _, _ = camera_axes(cameras)
    centre, up = look_at_centre(cameras), world_up(cameras)
    offsets = centres - centre  # [N, 3]
    heights = offsets @ up  # [N]
    flat = offsets - heights[:, None] * up  # [N, 3] horizontal offsets
    radius = float(flat.norm(dim=-1).mean())
    if radius < 1e-6 * max(1.0, float(offsets.norm(dim=-1).mean())):
        raise ValueError("the cameras sit on the up axis of their look-at centre; use --path spiral or test")
    e1 = flat[0] / flat[0].norm() if float(flat[0].norm()) > 1e-9 else flat.mean(0) / flat.mean(0).norm()
    e2 = torch.linalg.cross(up, e1)
    lift = centre + heights.mean() * up
    path = []
    for k, time in enumerate(path_times(frames, *times)):
        angle = 2 * math.pi * k / frames
        eye = lift + radius * (math.cos(angle) * e1 + math.sin(angle) * e2)
        path.append(_posed(reference, eye, centre, up, time, f"orbit/{k:04d}"))
    return path


def spiral_path(
    cameras: Sequence[Camera],
    reference: Camera,
    frames: int,
    times: tuple[float, float] = (0.0, 1.0),
    turns: float = 2.0,
) -> list[Camera]:
    """``frames`` cameras on NeRF's closed spiral around the mean camera, looking at
    ``look_at_centre(cameras)``.

    The mean camera sits at the cameras' mean centre with their mean axes; the spiral's radii along its
    x, y and z axes are the 90th percentiles of the cameras' absolute offsets from it (LLFF); ``turns``
    turns in x/y and one in depth. Time runs from ``times[0]`` to ``times[1]``.
    """
    centres, forward, _ = camera_axes(cameras)
    up, target = world_up(cameras), look_at_centre(cameras)
    z = torch.nn.functional.normalize(forward.mean(0), dim=0)
    x = torch.nn.functional.normalize(torch.linalg.cross(z, up), dim=0)
    y = torch.linalg.cross(z, x)
    axes = torch.stack([x, y, z])  # [3, 3] rows: the mean camera's axes
    mean = centres.mean(0)
    radii = torch.quantile((centres - mean).abs() @ axes.T, 0.9, dim=0)  # [3]
    path = []
    for k, time in enumerate(path_times(frames, *times)):
        angle = 2 * math.pi * turns * k / frames
        local = torch.tensor(
            [math.cos(angle), -math.sin(angle), -math.sin(angle / turns)], dtype=torch.float64
        )
        eye = mean + (radii * local) @ axes
        path.append(_posed(reference, eye, target, up, time, f"spiral/{k:04d}"))
    return path


def camera_path(
    kind: str,
    cameras: Sequence[Camera],
    reference: Camera,
    frames: int,
    times: tuple[float, float] = (0.0, 1.0),
) -> tuple[str, list[Camera]]:
    """``(the path's name, its cameras)`` for ``kind`` in ``orbit | spiral | auto`` (``auto``: orbit for
    cameras around the scene, spiral for a forward-facing rig; see ``is_forward_facing``)."""
    if kind == "auto":
        kind = "spiral" if is_forward_facing(cameras) else "orbit"
    if kind == "orbit":
        return kind, orbit_path(cameras, reference, frames, times)
    if kind == "spiral":
        return kind, spiral_path(cameras, reference, frames, times)
    raise ValueError(f"--path: expected one of {', '.join(p for p in PATHS if p != 'test')}, got {kind!r}")


__all__ = [
    "FORWARD_FACING",
    "PATHS",
    "camera_axes",
    "camera_path",
    "is_forward_facing",
    "look_at_centre",
    "orbit_path",
    "path_times",
    "spiral_path",
    "world_up",
]
