"""Writers for the native dataset layouts and the ground-truth side files.

N3V: LLFF ``poses_bounds.npy`` + ``camXX.mp4``; D-NeRF: Blender ``transforms_*.json`` + RGBA PNGs;
plus ``gt/`` arrays and masks and a 3DGS-style PLY.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from moegs.camera import Camera

# OpenCV camera axes (right, down, forward) -> LLFF columns (down, right, back) and back.
_OPENCV_TO_LLFF = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# OpenCV (right, down, forward) <-> OpenGL/Blender (right, up, back)
_OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])


def llff_pose(camera: Camera) -> np.ndarray:
    """``[3, 5]`` LLFF pose: camera-to-world rotation columns (down, right, back), centre, ``(H, W, focal)``.

    LLFF stores one focal length; ``camera`` must have ``fx == fy`` and the principal point at the centre.
    """
    if not math.isclose(camera.fx, camera.fy, rel_tol=1e-6):
        raise ValueError(f"LLFF poses need fx == fy, camera {camera.name!r} has {camera.fx} / {camera.fy}")
    if not (
        math.isclose(camera.cx, camera.width / 2, abs_tol=1e-4)
        and math.isclose(camera.cy, camera.height / 2, abs_tol=1e-4)
    ):
        raise ValueError(f"LLFF poses need the principal point at the image centre, camera {camera.name!r}")
    c2w = np.linalg.inv(camera.world_to_camera.to(torch.float64).numpy())
    pose = np.zeros((3, 5))
    pose[:, :3] = c2w[:3, :3] @ _OPENCV_TO_LLFF
    pose[:, 3] = c2w[:3, 3]
    pose[:, 4] = [camera.height, camera.width, camera.fx]
    return pose


def write_poses_bounds(path: Path, cameras: list[Camera], bounds: list[tuple[float, float]]) -> None:
    """``poses_bounds.npy`` ``[N, 17]`` float64: the row-major LLFF 3x5 pose, then near and far."""
    rows = [
        np.concatenate([llff_pose(c).reshape(-1), np.asarray(b, dtype=np.float64)])
        for c, b in zip(cameras, bounds, strict=True)
    ]
    np.save(path, np.stack(rows).astype(np.float64))


def blender_matrix(camera: Camera) -> list[list[float]]:
    """Blender/OpenGL camera-to-world ``[4, 4]`` (nested lists) of an OpenCV camera."""
    c2w = np.linalg.inv(camera.world_to_camera.to(torch.float64).numpy())
    c2w[:3, :3] = c2w[:3, :3] @ _OPENCV_TO_OPENGL
    return c2w.tolist()


def write_transforms(path: Path, split: str, cameras: list[Camera], hfov_rad: float) -> None:
    """``transforms_<split>.json`` (D-NeRF layout: ``file_path`` without extension, ``time`` in [0, 1])."""
    frames = [
        {
            "file_path": f"./{split}/{c.name}",
            "rotation": 0.0,
            "time": float(c.time),
            "transform_matrix": blender_matrix(c),
        }
        for c in cameras
    ]
    path.write_text(json.dumps({"camera_angle_x": float(hfov_rad), "frames": frames}, indent=2))


def to_uint8(x: Tensor) -> np.ndarray:
    """Float in [0, 1] -> uint8 with rounding."""
    return (x.clamp(0.0, 1.0) * 255.0).round().to(torch.uint8).cpu().numpy()


def save_png(path: Path, arr: np.ndarray) -> None:
    Image.fromarray(arr).save(path, compress_level=3)


def save_mask(path: Path, mask: Tensor) -> None:
    """Boolean ``[H, W]`` mask as an 8-bit PNG (0 / 255)."""
    save_png(path, (mask.to(torch.uint8) * 255).cpu().numpy())


def psnr_uint8(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB between two uint8 arrays (``inf`` when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def write_ply(path: Path, xyz: Tensor, rgb: Tensor) -> None:
    """3DGS ``storePly`` layout: x y z nx ny nz (zeros) red green blue (uint8)."""
    from plyfile import PlyData, PlyElement

    n = xyz.shape[0]
    dtype = [
        ("x", "f4"),
        ("y", "f4"),
        ("z", "f4"),
        ("nx", "f4"),
        ("ny", "f4"),
        ("nz", "f4"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
    ]
    data = np.zeros(n, dtype=dtype)
    p = xyz.detach().cpu().numpy().astype(np.float32)
    c = to_uint8(rgb.detach().cpu())
    data["x"], data["y"], data["z"] = p[:, 0], p[:, 1], p[:, 2]
    data["red"], data["green"], data["blue"] = c[:, 0], c[:, 1], c[:, 2]
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
