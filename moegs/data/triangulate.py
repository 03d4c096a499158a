"""Initial points triangulated from one time step of a calibrated multi-view capture.

For multi-view scenes shipped without their point cloud (Panoptic without ``init_pt_cld.npz``): SIFT
features (pycolmap) of every camera's image at one time, matched between each camera and its nearest
cameras (mutual nearest neighbours passing Lowe's ratio test), triangulated with the known projection
matrices (linear DLT), and kept where the point lies in front of both cameras, reprojects within
``max_error`` pixels in both images and is seen under a ray angle of at least ``min_angle`` degrees.
Colours are sampled from the image of the first camera of the pair. Poses are never estimated here:
the capture's calibration is taken as given.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import PointCloud


def sift_extractor() -> Any:
    """pycolmap's CPU SIFT extractor, created without its INFO log line (pycolmap >= 3.12 prefers
    ``FeatureExtractor``; ``Sift`` runs on every version from 3.10)."""
    import pycolmap

    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = int(pycolmap.logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return pycolmap.Sift()
    finally:
        pycolmap.logging.minloglevel = level


def sift_features(image: Tensor, extractor: Any) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints ``[M, 2]`` (pixel x, y) and L2-normalised descriptors ``[M, 128]`` of an
    ``[H, W, 3]`` image in [0, 1] (its luminance), from ``sift_extractor()``."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"sift_features: expected an [H, W, 3] image, got shape {list(image.shape)}")
    gray = (image.double() @ torch.tensor([0.299, 0.587, 0.114], dtype=torch.float64)).float()
    keypoints, descriptors = extractor.extract(np.ascontiguousarray(gray.numpy()))
    desc = descriptors.astype(np.float64)
    desc /= np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    return keypoints[:, :2].astype(np.float64), desc


def mutual_matches(
    desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ia, ib)`` of descriptor pairs that are each other's nearest neighbour and whose
    nearest distance is below ``ratio`` times the second nearest (from ``a``'s side)."""
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    dist = np.sqrt(np.clip(2.0 - 2.0 * desc_a @ desc_b.T, 0.0, None))  # unit vectors
    order = np.argsort(dist, axis=1)[:, :2]
    rows = np.arange(len(desc_a))
    best, second = dist[rows, order[:, 0]], dist[rows, order[:, 1]]
    mutual = np.argmin(dist, axis=0)[order[:, 0]] == rows
    keep = (best < ratio * second) & mutual
    return rows[keep], order[keep, 0]


def projection_matrix(camera: Camera) -> np.ndarray:
    """``K [R | t]``, ``[3, 4]`` float64."""
    return camera.K.double().numpy() @ camera.world_to_camera.double().numpy()[:3]


def triangulate_dlt(P_a: np.ndarray, P_b: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Points ``[M, 3]`` whose projections through ``P_a``, ``P_b [3, 4]`` are ``x_a``, ``x_b [M, 2]``
    (linear triangulation: the null vector of the four DLT equations of each pair)."""
    rows = [
        x_a[:, :1] * P_a[2] - P_a[0],
        x_a[:, 1:] * P_a[2] - P_a[1],
        x_b[:, :1] * P_b[2] - P_b[0],
        x_b[:, 1:] * P_b[2] - P_b[1],
    ]
    _, _, vt = np.linalg.svd(np.stack(rows, axis=1))
    homogeneous = vt[:, -1]
    return homogeneous[:, :3] / homogeneous[:, 3:]


def neighbour_pairs(centres: np.ndarray, neighbours: int) -> list[tuple[int, int]]:
    """Camera pairs ``(a, b)``, ``a < b``, where either is among the other's ``neighbours`` nearest
    (by centre ``[C, 3]``), each once, sorted."""
    pairs = set()
    for a in range(len(centres)):
        for b in np.argsort(np.linalg.norm(centres - centres[a], axis=1))[1 : neighbours + 1]:
            pairs.add((min(a, int(b)), max(a, int(b))))
    return sorted(pairs)


def _project(P: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates ``[M, 2]`` and depths ``[M]`` of ``X [M, 3]`` through ``P [3, 4]``."""
    h = X @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:], h[:, 2]


def _colours(image: Tensor, xy: np.ndarray) -> np.ndarray:
    """Nearest-pixel colours ``[M, 3]`` of ``image [H, W, 3]`` at ``xy [M, 2]``."""
    h, w = image.shape[:2]
    col = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    return image.numpy()[row, col].astype(np.float64)


def triangulated_points(
    cameras: Sequence[Camera],
    images: Sequence[Tensor],
    neighbours: int = 5,
    max_error: float = 2.0,
    min_angle: float = 2.0,
    max_points: int | None = None,
    seed: int = 0,
) -> PointCloud:
    """Triangulate matches between each camera and its ``neighbours`` nearest cameras (see the module
    docstring). ``images[i]`` is camera ``i``'s ``[H, W, 3]`` image in [0, 1] at its own resolution;
    ``max_points`` keeps a seeded random subset. Raises ``ValueError`` when nothing triangulates."""
    if len(cameras) != len(images) or len(cameras) < 2:
        raise ValueError(
            f"triangulated_points: need >= 2 cameras with one image each, got {len(cameras)} "
            f"cameras and {len(images)} images"
        )
    for cam, img in zip(cameras, images, strict=True):
        if tuple(img.shape) != (cam.height, cam.width, 3):
            raise ValueError(
                f"triangulated_points: camera {cam.name!r} is {cam.width}x{cam.height} but its "
                f"image has shape {list(img.shape)}"
            )
    extractor = sift_extractor()
    features = [sift_features(img, extractor) for img in images]
    P = [projection_matrix(c) for c in cameras]
    centres = np.stack([c.center.double().numpy() for c in cameras])
    cos_min = np.cos(np.deg2rad(min_angle))
    xyz, rgb = [], []
    for a, b in neighbour_pairs(centres, neighbours):
        ia, ib = mutual_matches(features[a][1], features[b][1])
        if len(ia) == 0:
            continue
        x_a, x_b = features[a][0][ia], features[b][0][ib]
        X = triangulate_dlt(P[a], P[b], x_a, x_b)
        keep = np.ones(len(X), dtype=bool)
        for Pm, x in ((P[a], x_a), (P[b], x_b)):
            uv, depth = _project(Pm, X)
            keep &= (depth > 0) & (np.linalg.norm(uv - x, axis=1) < max_error)
        ray_a, ray_b = X - centres[a], X - centres[b]
        cos = (ray_a * ray_b).sum(1) / np.maximum(
            np.linalg.norm(ray_a, axis=1) * np.linalg.norm(ray_b, axis=1), 1e-12
        )
        keep &= cos < cos_min
        xyz.append(X[keep])
        rgb.append(_colours(images[a], x_a[keep]))
    points = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    if len(points) == 0:
        raise ValueError(
            f"triangulated_points: no match between {len(cameras)} cameras triangulated "
            f"(max_error={max_error} px, min_angle={min_angle} deg)"
        )
    colours = np.concatenate(rgb)
    found = len(points)
    if max_points is not None and found > max_points:
        pick = torch.randperm(found, generator=torch.Generator().manual_seed(seed))[:max_points].numpy()
        points, colours = points[np.sort(pick)], colours[np.sort(pick)]
    return PointCloud(
        xyz=torch.from_numpy(points).float(),
        rgb=torch.from_numpy(colours).float().clamp(0, 1),
        source=f"triangulated: SIFT matches of {len(cameras)} calibrated cameras ({neighbours} nearest "
        f"each, reprojection < {max_error:g} px, ray angle >= {min_angle:g} deg), {found} points, "
        f"kept {len(points)}",
    )
