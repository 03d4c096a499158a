"""Analytic ground truth of the synthetic scenes: depth, object ids and dynamic masks per view.

Two sources that agree: the side files written by ``generate`` (``gt/``) for the dataset's own views,
and ``render_ground_truth`` which ray-casts the scene description for ANY camera and time (for
analyses such as region-wise best-expert maps at novel views).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import Scene, View
from moegs.data.synthetic.generate import read_meta
from moegs.data.synthetic.raycast import Render, render
from moegs.data.synthetic.scenes import CATEGORIES, build_scene

_N3V_NAME = re.compile(r"^(cam\d+)/(\d+)$")
_DNERF_NAME = re.compile(r"^(train|val|test)/(r_\d+)$")


@dataclass
class GroundTruth:
    """Per-pixel ground truth of one view.

    Attributes:
        depth: ``[H, W]`` float32 z-depth (0 where no surface).
        ids: ``[H, W]`` int64 object id (0 where no surface; see ``objects``).
        dynamic: ``[H, W]`` bool, the first hit is a non-static object.
        objects: the scene's object table (``id``, ``name``, ``category``, ``dynamic``, ``description``).
    """

    depth: Tensor
    ids: Tensor
    dynamic: Tensor
    objects: list[dict]

    def mask(self, *, categories: tuple[str, ...] = (), names: tuple[str, ...] = ()) -> Tensor:
        """``[H, W]`` bool: pixels whose object has one of ``categories`` or ``names``."""
        bad = sorted(set(categories) - set(CATEGORIES))
        if bad:
            raise ValueError(f"unknown categories {bad}; valid: {list(CATEGORIES)}")
        known = {o["name"] for o in self.objects}
        if set(names) - known:
            raise ValueError(f"unknown object names {sorted(set(names) - known)}; valid: {sorted(known)}")
        ids = [o["id"] for o in self.objects if o["category"] in categories or o["name"] in names]
        return torch.isin(self.ids, torch.tensor(ids, dtype=self.ids.dtype))


def _resize_nearest(arr: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if (arr.shape[1], arr.shape[0]) == size:
        return arr
    return np.asarray(Image.fromarray(arr).resize(size, Image.Resampling.NEAREST))


def _view_name(view: View | Camera | str) -> tuple[str, tuple[int, int] | None]:
    if isinstance(view, View):
        return view.camera.name, (view.camera.width, view.camera.height)
    if isinstance(view, Camera):
        return view.name, (view.width, view.height)
    return str(view), None


def gt_files(scene_dir: Path, name: str) -> tuple[Path, Path, Path, int | None]:
    """Paths of (depth, ids, mask) for a view named ``camXX/NNNN`` (n3v) or ``<split>/r_XXX`` (dnerf), and the
    frame index into the n3v stacks (None for dnerf)."""
    m = _N3V_NAME.match(name)
    if m:
        folder = scene_dir / "gt" / m.group(1)
        frame = int(m.group(2))
        return folder / "depth.npy", folder / "ids.npy", folder / "mask" / f"{frame:04d}.png", frame
    m = _DNERF_NAME.match(name)
    if m:
        folder = scene_dir / "gt" / m.group(1)
        stem = m.group(2)
        return (folder / f"{stem}_depth.npy", folder / f"{stem}_ids.png", folder / f"{stem}_mask.png", None)
    raise ValueError(
        f"ground truth: cannot map view name {name!r} to a synthetic view "
        "(expected 'camXX/NNNN' for n3v or 'train|val|test/r_XXX' for dnerf)"
    )


def load_ground_truth(scene_dir: str | Path, view: View | Camera | str) -> GroundTruth:
    """Ground truth written by ``generate`` for one of the scene's views.

    ``view`` is a loaded ``View``/``Camera`` (its ``name``) or the name itself. When the view's size
    differs from the generated size (a loader ``resolution_scale``), maps are resized (nearest).
    """
    scene_dir = Path(scene_dir)
    meta = read_meta(scene_dir)
    if meta is None:
        raise FileNotFoundError(
            f"ground truth: {scene_dir}/scene_meta.json not found (not a generated scene)"
        )
    name, size = _view_name(view)
    depth_p, ids_p, _, frame = gt_files(scene_dir, name)
    for p in (depth_p, ids_p):
        if not p.is_file():
            raise FileNotFoundError(f"ground truth of view {name!r}: expected {p}")
    if frame is None:
        depth = np.load(depth_p)
        ids = np.asarray(Image.open(ids_p))
    else:
        d, i = np.load(depth_p, mmap_mode="r"), np.load(ids_p, mmap_mode="r")
        if frame >= d.shape[0]:
            raise IndexError(f"ground truth: frame {frame} outside 0..{d.shape[0] - 1} in {depth_p}")
        depth, ids = np.array(d[frame]), np.array(i[frame])
    if size is not None:
        depth = _resize_nearest(depth, size)
        ids = _resize_nearest(ids, size)
    ids_t = torch.from_numpy(ids.astype(np.int64))
    lut = torch.zeros(256, dtype=torch.bool)
    lut[meta["dynamic_ids"]] = True
    return GroundTruth(
        depth=torch.from_numpy(depth.astype(np.float32)),
        ids=ids_t,
        dynamic=lut[ids_t],
        objects=meta["objects"],
    )


def ground_truth(scene: Scene, view: View | Camera | str) -> GroundTruth:
    """``load_ground_truth`` for a view of a scene returned by ``load_synthetic``."""
    meta = getattr(scene, "meta", None)
    info = meta.get("synthetic") if isinstance(meta, dict) else None
    if not info:
        raise ValueError(f"scene {scene.name!r} was not loaded by load_synthetic (no meta['synthetic'])")
    return load_ground_truth(info["dir"], view)


def load_regimes(scene_dir: str | Path, name: str, size: tuple[int, int]) -> dict[str, Tensor]:
    """``{category: [H, W] float32 mask}`` of view ``name`` at ``size = (width, height)``: the pixels whose
    first hit is an object of each motion regime of the scene (every dynamic category the scene has, also
    where this view does not show it)."""
    gt = load_ground_truth(scene_dir, name)
    ids = torch.from_numpy(_resize_nearest(gt.ids.numpy().astype(np.uint8), size).copy())  # writable
    out: dict[str, Tensor] = {}
    for o in gt.objects:
        if o["dynamic"]:
            mask = (ids == o["id"]).to(torch.float32)
            out[o["category"]] = out[o["category"]] + mask if o["category"] in out else mask
    return out


def load_mask(path: Path, size: tuple[int, int]) -> Tensor:
    """Mask PNG -> ``[H, W]`` float32 in {0, 1} at ``size = (width, height)`` (nearest resize)."""
    if not path.is_file():
        raise FileNotFoundError(f"ground-truth mask: expected {path}")
    arr = _resize_nearest(np.asarray(Image.open(path).convert("L")), size)
    return torch.from_numpy((arr > 0).astype(np.float32))


def render_ground_truth(
    scene: str, camera: Camera, time: float | None = None, seed: int = 0, supersample: int = 1
) -> Render:
    """Ray-cast the named scene description (``n3v_like`` | ``dnerf_like``) from any camera.

    ``time`` defaults to ``camera.time`` (the synthetic loaders keep the scene's own time convention, so a
    loaded camera renders its own frame). Returns ``Render`` (rgb, alpha, depth, ids, normal).
    """
    desc = build_scene(scene, seed)
    t = camera.time if time is None else float(time)
    return render(desc.primitives(t), camera, t, supersample)
