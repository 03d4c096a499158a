"""CMU Panoptic sports sequences in the Dynamic3DGaussians (Luiten et al. 2024) layout.

Layout::

    <root>/train_meta.json, test_meta.json   w, h, k[T][C][3][3], w2c[T][C][4][4], fn[T][C], cam_id[T][C]
    <root>/ims/<cam>/<frame:06d>.jpg           RGB, 640x360 (``fn`` is relative to ims/)
    <root>/seg/<cam>/<frame:06d>.png           foreground masks (training cameras only), optional
    <root>/init_pt_cld.npz                     key "data" [N, 7] = xyz, rgb in [0, 1], seg; optional

Conventions chosen:
- Splits: train cameras from ``train_meta.json``, test cameras from ``test_meta.json`` (never hard-coded;
  for basketball these are 27 and 4 cameras: 0, 10, 15, 30).
- ``w2c`` is already OpenCV world-to-camera and ``k`` the pixel intrinsics, read per time step.
- Time: ``t / T`` for meta time step ``t`` of ``T`` (4DGaussians ``readPanopticmeta``; T = 150 gives
  0 .. 149/150). ``time_mode="local"`` renormalises inside a ``frames`` window.
- Background black (Dynamic3DGaussians renders on black; the images keep the real studio background).
- ``extent``: 1.1 x the largest distance of the training camera centres from their mean (their
  ``scene_radius``, identical to 3DGS ``getNerfppNorm``).
- Points: ``init_pt_cld.npz`` when present (``PointCloud.source`` says so). Otherwise (``init``):
  ``"triangulate"`` (default) SIFT matches of the training cameras' native images at the window's first
  time step, triangulated with the given calibration (``moegs.data.triangulate``), at most
  ``num_points`` of them; ``"random"`` ``num_points`` random points in the camera frusta
  (``moegs.data.points.random_in_frusta``), kept only where at least half the training cameras see
  them: the shared capture volume, which has no points on the dome's walls. Triangulation that finds
  nothing (textureless images) falls back to ``"random"`` and the source says why. ``bbox`` comes from
  the points (1%-99% quantiles).
- Masks: ``View.load_mask`` reads ``seg/`` when it exists for that camera (any non-zero = foreground).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data import decoded
from moegs.data import triangulate as triangulate_module
from moegs.data._init_points import shared_volume_points
from moegs.data._io import (
    frame_window,
    key,
    load_json,
    load_rgb,
    loaded_scene,
    normalised_time,
    read_mask,
    require_file,
)
from moegs.data.scene import PointCloud, Scene, View
from moegs.data.triangulate import triangulated_points

_META_KEYS = ("w", "h", "k", "w2c", "fn", "cam_id")


def _read_meta(root: Path, split: str) -> dict:
    path = root / f"{split}_meta.json"
    meta = load_json(path, f"Panoptic {split} split (expected {split}_meta.json in {root})")
    for name in _META_KEYS:
        key(meta, name, path)
    T = len(meta["fn"])
    for name in ("k", "w2c", "cam_id"):
        if len(meta[name]) != T:
            raise ValueError(f"{path}: '{name}' has {len(meta[name])} time steps but 'fn' has {T}")
    meta["_path"] = path
    return meta


def _views(
    root: Path,
    meta: dict,
    window: tuple[int, int],
    T: int,
    time_mode: str,
    scale: float,
    resample: str,
    masks: bool,
) -> list[View]:
    path, native = meta["_path"], (int(meta["w"]), int(meta["h"]))
    bg = torch.zeros(3)
    views = []
    for t in range(*window):
        ks, w2cs, fns, cams = meta["k"][t], meta["w2c"][t], meta["fn"][t], meta["cam_id"][t]
        if not (len(ks) == len(w2cs) == len(fns) == len(cams)):
            raise ValueError(
                f"{path}: time step {t} has {len(ks)} k, {len(w2cs)} w2c, {len(fns)} fn, "
                f"{len(cams)} cam_id entries"
            )
        time = normalised_time(t, window[0], window[1], T, time_mode)
        for k, w2c, fn, cam_id in zip(ks, w2cs, fns, cams, strict=True):
            try:
                cam = Camera(
                    K=torch.tensor(k, dtype=torch.float32),
                    world_to_camera=torch.tensor(w2c, dtype=torch.float32),
                    width=native[0],
                    height=native[1],
                    time=time,
                    camera_id=int(cam_id),
                    frame=t,
                    name=f"cam{int(cam_id):02d}/{t:06d}",
                )
            except (TypeError, ValueError, RuntimeError) as err:  # wrong shapes or values in the json
                raise ValueError(f"{path}: time step {t}, camera {cam_id!r}: {err}") from None
            if scale != 1.0:
                cam = cam.scaled(scale)
            size = (cam.width, cam.height)
            img = root / "ims" / fn
            seg = (root / "seg" / fn).with_suffix(".png")
            load_mask = partial(read_mask, seg, size) if masks and seg.parent.is_dir() else None
            views.append(
                View(
                    camera=cam,
                    key=f"panoptic:{root.name}/{fn}@{size[0]}x{size[1]}",
                    load_image=partial(load_rgb, img, native, size, bg, resample),
                    load_mask=load_mask,
                )
            )
    return views


INITS = ("triangulate", "random")
"""Initialisations when ``init_pt_cld.npz`` is missing (see the module docstring)."""


def _random_points(cameras: list[Camera], n: int, seed: int, why: str) -> PointCloud:
    centers = torch.stack([c.center for c in cameras])
    dist = (centers - centers.mean(0)).norm(dim=-1).median().item()
    return shared_volume_points(cameras, n, 0.2 * dist, 1.6 * dist, seed, why)


def _fallback_points(
    native_first: Callable[[], list[View]],
    sources: list[Path],
    cameras: list[Camera],
    n: int,
    seed: int,
    init: str,
) -> PointCloud:
    """Points without ``init_pt_cld.npz``: triangulated from ``native_first()`` (the window's first time
    step at native resolution, built only for this; the cloud is cached on disk, keyed on the ``sources``
    it is computed from and on the triangulation's code) or random in the shared volume of ``cameras``."""
    if init == "triangulate":

        def triangulate() -> PointCloud:  # only on a cache miss
            views = native_first()
            images = [v.image() for v in views]
            return triangulated_points([v.camera for v in views], images, max_points=n, seed=seed)

        method = hashlib.sha256(Path(triangulate_module.__file__).read_bytes()).hexdigest()
        try:
            return decoded.cached_points(sources, (n, seed, method), triangulate)
        except ValueError as err:
            return _random_points(cameras, n, seed, f"init_pt_cld.npz missing, {err}")
    return _random_points(cameras, n, seed, "init_pt_cld.npz missing")


def _npz_points(path: Path) -> tuple[PointCloud, Tensor]:
    try:
        data = np.load(path)["data"]
    except KeyError as err:
        raise KeyError(f"{path}: missing key 'data' (expected [N, 7] = xyz, rgb, seg)") from err
    if data.ndim != 2 or data.shape[1] < 6:
        raise ValueError(f"{path}: 'data' must be [N, 7] (xyz, rgb, seg), got {list(data.shape)}")
    xyz = torch.from_numpy(np.ascontiguousarray(data[:, :3])).float()
    rgb = torch.from_numpy(np.ascontiguousarray(data[:, 3:6])).float()
    seg = (
        torch.from_numpy(np.ascontiguousarray(data[:, 6])).float()
        if data.shape[1] > 6
        else torch.ones(len(xyz))
    )
    return PointCloud(xyz=xyz, rgb=rgb, source=f"init_pt_cld.npz ({len(xyz)} points)"), seg


def load_panoptic(
    root: str | Path,
    resolution_scale: float = 1.0,
    frames: tuple[int, int] | None = None,
    time_mode: str = "global",
    num_points: int = 100_000,
    seed: int = 0,
    masks: bool = True,
    resample: str = "bicubic",
    name: str | None = None,
    init: str = "triangulate",
) -> Scene:
    """Load a Dynamic3DGaussians-layout Panoptic sequence.

    Args:
        root: folder holding ``train_meta.json``, ``test_meta.json`` and ``ims/``.
        resolution_scale: 1.0 -> 640x360.
        frames: half-open window ``(start, stop)`` of meta time steps (default: all).
        time_mode: ``"global"`` (t / T) or ``"local"`` ((t - start) / (stop - start)).
        num_points: size of the fallback initialisation when ``init_pt_cld.npz`` is missing.
        masks: expose ``seg/`` masks through ``View.load_mask``.
        init: ``"triangulate"`` or ``"random"``: the points when ``init_pt_cld.npz`` is missing.
    """
    if init not in INITS:
        raise ValueError(f"load_panoptic: init must be one of {INITS}, got {init!r}")
    root = Path(root)
    if not (root / "train_meta.json").is_file():
        raise FileNotFoundError(
            f"Panoptic scene: expected {root / 'train_meta.json'} (layout: "
            "train_meta.json, test_meta.json, ims/<cam>/<frame>.jpg, seg/, init_pt_cld.npz)"
        )
    require_file(root / "test_meta.json", "Panoptic test split")
    train_meta, test_meta = _read_meta(root, "train"), _read_meta(root, "test")
    T = len(train_meta["fn"])
    if len(test_meta["fn"]) != T:
        raise ValueError(
            f"{root}: train_meta.json has {T} time steps but test_meta.json {len(test_meta['fn'])}"
        )
    window = frame_window(frames, T, f"Panoptic {root}")
    common = dict(
        window=window, T=T, time_mode=time_mode, scale=resolution_scale, resample=resample, masks=masks
    )
    train = _views(root, train_meta, **common)
    test = _views(root, test_meta, **common)
    first = [v.camera for v in train if v.camera.frame == window[0]]

    npz = root / "init_pt_cld.npz"
    meta = {
        "frames": list(window),
        "total_frames": T,
        "time_mode": time_mode,
        "train_cameras": sorted({v.camera.camera_id for v in train}),
        "test_cameras": sorted({v.camera.camera_id for v in test}),
    }
    if npz.is_file():
        points, seg = _npz_points(npz)
        meta["point_seg_fraction"] = float((seg > 0.5).float().mean())
    else:
        start = {**common, "window": (window[0], window[0] + 1), "scale": 1.0, "masks": False}
        native_first = partial(_views, root, train_meta, **start)
        sources = [train_meta["_path"], *(root / "ims" / fn for fn in train_meta["fn"][window[0]])]
        points = (
            _fallback_points(native_first, sources, first, num_points, seed, init) if num_points > 0 else None
        )
    return loaded_scene(
        "panoptic",
        root.name,
        name,
        train,
        test,
        cameras=first,
        points=points,
        num_frames=window[1] - window[0],
        background=torch.zeros(3),
        multiview=True,
        meta=meta,
    )
