"""HyperNeRF / Nerfies captures (Park et al. 2021) in their released layout.

Layout::

    <root>/dataset.json      ids, train_ids, val_ids
    <root>/metadata.json     {id: {warp_id, appearance_id, camera_id}} (time_id in some releases)
    <root>/scene.json        scale, center, near, far
    <root>/camera/<id>.json  orientation [3][3], position [3], focal_length, principal_point [2],
                             pixel_aspect_ratio, skew, radial_distortion [3], tangential_distortion [2],
                             image_size [W, H] (full resolution)
    <root>/rgb/<k>x/<id>.png images downscaled k times (1x, 2x, 4x, ...)
    <root>/points.npy        optional static points (world units); points3d.ply / points3D_downsample2.ply
                             (COLMAP clouds of 4DGaussians / DeformableGS, already normalised) preferred

Conventions chosen (``specs/peers_and_style.md`` C.2):
- Split ``vrig``: train = ``train_ids``, test = ``val_ids`` (the second rig camera). ``interp`` (or
  ``auto`` when ``val_ids`` is empty): train every 4th id, test the ids offset by 2 (DeformableGS
  ``scene/dataset_readers.py:421-423``, Grid4D :417-418; 4DGaussians ``scene/hyper_loader.py:63-66``
  and E-D3DGS :79-82 also drop the last test id).
- Resolution: ``resolution_scale=0.5`` -> ``rgb/2x`` = 960x536 on disk (the paper's "960x540"; the full
  images are 1920x1072). Intrinsics are the camera json's scaled by 1/k; the image size is the PNG's
  (checked to be within k pixels of the scaled json size; the difference goes to ``scene.meta``).
- Poses: Nerfies ``orientation`` is the world-to-camera rotation with OpenCV axes, so
  ``w2c = [R | -R (position - center) * scale]`` after the ``scene.json`` normalisation that
  4DGaussians and DeformableGS apply (points get the same ``(x - center) * scale``).
- ``fx = focal_length``, ``fy = focal_length * pixel_aspect_ratio``. Principal point ``"centered"``
  by default, as the GS methods (FoV-only projection) use; ``principal_point="calibrated"`` keeps the
  json value. Skew and lens distortion are ignored as in every GS method; their size is recorded in
  ``scene.meta["ignored_distortion_max"]``.
- Time: ``warp_id / max(warp_id)`` over all ids (4DGaussians); ``time_key="time_id"`` for DeformableGS.
- Background black (real captures; no alpha).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera, intrinsics
from moegs.data._init_points import greyish_colors, ply_points, shared_volume_points
from moegs.data._io import (
    image_size,
    key,
    load_json,
    load_rgb,
    loaded_scene,
    matrix,
    number,
    vector,
)
from moegs.data.scene import PointCloud, Scene, View


def nerfies_to_w2c(orientation: Tensor, position: Tensor, center: Tensor, scale: float) -> Tensor:
    """Nerfies camera (rotation ``[3, 3]``, position ``[3]``) -> OpenCV world-to-camera ``[4, 4]`` after
    the ``(x - center) * scale`` scene normalisation."""
    R = orientation.to(torch.float64)
    pos = (position.to(torch.float64) - center.to(torch.float64)) * scale
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ pos
    return w2c.to(torch.float32)


def _split(dataset: dict, path: Path, split: str) -> tuple[list[str], list[str], str]:
    ids = [str(i) for i in key(dataset, "ids", path)]
    val = [str(i) for i in dataset.get("val_ids", [])]
    if split == "auto":
        split = "vrig" if val else "interp"
    if split == "vrig":
        if not val:
            raise ValueError(f"{path}: split 'vrig' needs a non-empty 'val_ids'")
        return [str(i) for i in key(dataset, "train_ids", path)], val, split
    if split == "interp":
        return ids[::4], ids[2::4], split
    raise ValueError(f"HyperNeRF split must be 'auto', 'vrig' or 'interp', got {split!r}")


def _camera(
    root: Path,
    item: str,
    center: Tensor,
    scale: float,
    factor: int,
    size: tuple[int, int],
    principal_point: str,
) -> tuple[Camera, float]:
    path = root / "camera" / f"{item}.json"
    cj = load_json(path, f"HyperNeRF camera {item} (expected camera/<id>.json)")
    R = matrix(cj, "orientation", path, (3, 3))
    pos = matrix(cj, "position", path, (3,))
    f = number(cj, "focal_length", path)
    fy = f * (number(cj, "pixel_aspect_ratio", path) if "pixel_aspect_ratio" in cj else 1.0)
    full = matrix(cj, "image_size", path, (2,)).tolist()
    if principal_point == "centered":
        cx, cy = size[0] * factor / 2, size[1] * factor / 2
    elif principal_point == "calibrated":
        cx, cy = matrix(cj, "principal_point", path, (2,)).tolist()
    else:
        raise ValueError(f"principal_point must be 'centered' or 'calibrated', got {principal_point!r}")
    expected = (round(full[0] / factor), round(full[1] / factor))
    if abs(expected[0] - size[0]) > factor or abs(expected[1] - size[1]) > factor:
        raise ValueError(
            f"HyperNeRF: rgb/{factor}x images are {size[0]}x{size[1]} but {path} says "
            f"{full[0]:g}x{full[1]:g} / {factor} = {expected[0]}x{expected[1]}"
        )
    K = intrinsics(f / factor, fy / factor, cx / factor, cy / factor)
    try:
        w2c = nerfies_to_w2c(R, pos, center, scale)
        cam = Camera(K=K, world_to_camera=w2c, width=size[0], height=size[1], name=item)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    radial = vector(cj, "radial_distortion", path) if "radial_distortion" in cj else []
    tangential = vector(cj, "tangential_distortion", path) if "tangential_distortion" in cj else []
    skew = number(cj, "skew", path) if "skew" in cj else 0.0
    distortion = max(abs(v) for v in [*radial, *tangential, skew])
    return cam, distortion


def _points(root: Path, center: Tensor, scale: float, seed: int) -> PointCloud | None:
    for ply in (root / "points3d.ply", root / "points3D_downsample2.ply"):
        if ply.is_file():
            return ply_points(ply)
    npy = root / "points.npy"
    if not npy.is_file():
        return None
    xyz = np.load(npy)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"{npy}: expected [P, 3] points, got {list(xyz.shape)}")
    pts = (torch.from_numpy(xyz).to(torch.float64) - center) * scale
    return PointCloud(
        xyz=pts.float(),
        rgb=greyish_colors(len(pts), seed),
        source=f"points.npy ({len(pts)} points, normalised; static parts only)",
    )


def load_hypernerf(
    root: str | Path,
    resolution_scale: float = 0.5,
    split: str = "auto",
    time_key: str = "warp_id",
    principal_point: str = "centered",
    num_points: int = 100_000,
    seed: int = 0,
    name: str | None = None,
) -> Scene:
    """Load a HyperNeRF scene.

    Args:
        resolution_scale: 1/k for the ``rgb/<k>x`` folder (0.5 -> ``rgb/2x``, the 4DGaussians protocol).
        split: ``"auto"``, ``"vrig"`` or ``"interp"``.
        time_key: metadata field normalised to time (``warp_id`` or ``time_id``).
        principal_point: ``"centered"`` (GS methods) or ``"calibrated"``.
        num_points: fallback random points when the scene has no cloud (0: none).
    """
    root = Path(root)
    ds_path = root / "dataset.json"
    if not ds_path.is_file():
        raise FileNotFoundError(
            f"HyperNeRF scene: expected {ds_path} (layout: dataset.json, metadata.json, "
            "scene.json, camera/<id>.json, rgb/<k>x/<id>.png)"
        )
    factor = round(1.0 / resolution_scale)
    if factor < 1 or abs(factor * resolution_scale - 1.0) > 1e-6:
        raise ValueError(
            f"HyperNeRF resolution_scale must be 1/k for an rgb/<k>x folder, got {resolution_scale}"
        )
    rgb_dir = root / "rgb" / f"{factor}x"
    if not rgb_dir.is_dir():
        have = sorted(p.name for p in (root / "rgb").glob("*x")) if (root / "rgb").is_dir() else []
        raise FileNotFoundError(
            f"HyperNeRF: expected {rgb_dir} for resolution_scale={resolution_scale} (found {have})"
        )
    dataset = load_json(ds_path, "HyperNeRF split")
    md_path = root / "metadata.json"
    metadata = load_json(md_path, "HyperNeRF metadata (expected metadata.json)")
    sc_path = root / "scene.json"
    scene_json = load_json(sc_path, "HyperNeRF scene normalisation (expected scene.json)")
    center = matrix(scene_json, "center", sc_path, (3,))
    scale = number(scene_json, "scale", sc_path)
    train_ids, test_ids, split = _split(dataset, ds_path, split)
    all_ids = [str(i) for i in key(dataset, "ids", ds_path)]
    stamps = {
        i: int(number(key(metadata, i, md_path), time_key, md_path, f"metadata[{i!r}]")) for i in all_ids
    }
    t_max = max(stamps.values()) or 1

    size = image_size(rgb_dir / f"{train_ids[0]}.png")
    bg = torch.zeros(3)
    worst = 0.0

    def views(ids: list[str]) -> list[View]:
        nonlocal worst
        out = []
        for item in ids:
            if item not in stamps:
                raise KeyError(f"{md_path}: missing key {item!r} (listed in {ds_path})")
            cam, dist = _camera(root, item, center, scale, factor, size, principal_point)
            worst = max(worst, dist)
            cid = int(metadata[item].get("camera_id", 0))
            cam = Camera(
                K=cam.K,
                world_to_camera=cam.world_to_camera,
                width=cam.width,
                height=cam.height,
                time=stamps[item] / t_max,
                camera_id=cid,
                frame=stamps[item],
                name=item,
            )
            out.append(
                View(
                    camera=cam,
                    key=f"hypernerf:{root.name}/{item}@{size[0]}x{size[1]}",
                    load_image=partial(load_rgb, rgb_dir / f"{item}.png", size, size, bg, "bicubic"),
                )
            )
        return out

    train, test = views(train_ids), views(test_ids)
    train_cams = [v.camera for v in train]
    points = _points(root, center, scale, seed)
    if points is None and num_points > 0:
        near = float(scene_json.get("near", 0.1))
        far = float(scene_json.get("far", 2.0))
        points = shared_volume_points(
            train_cams[:: max(1, len(train_cams) // 50)],
            num_points,
            near,
            far,
            seed,
            "no points.npy / points3d.ply",
        )
    meta = {
        "split": split,
        "rgb_folder": f"{factor}x",
        "time_key": time_key,
        "max_time_id": t_max,
        "principal_point": principal_point,
        "ignored_distortion_max": worst,
        "scale": scale,
        "center": center.tolist(),
        "near": scene_json.get("near"),
        "far": scene_json.get("far"),
    }
    return loaded_scene(
        "hypernerf",
        root.name,
        name,
        train,
        test,
        cameras=train_cams,
        points=points,
        num_frames=len({v.camera.frame for v in train}),
        background=bg,
        meta=meta,
    )
