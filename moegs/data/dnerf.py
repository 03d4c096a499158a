"""D-NeRF synthetic scenes (Pumarola et al. 2021) in their native Blender layout.

Layout::

    <root>/transforms_{train,val,test}.json   camera_angle_x, frames[{file_path, time, transform_matrix}]
    <root>/{train,val,test}/r_XXX.png          RGBA, 800x800

Conventions chosen (see ``specs/peers_and_style.md`` C.2):
- Resolution: native 800x800 (the dynamic-GS protocol of 4DGaussians, DeformableGS, Grid4D).
  ``resolution_scale=0.5`` gives the NeRF-era 400x400 protocol (box filter = ``cv2.INTER_AREA``).
- Background: white by default (4DGaussians, nerfstudio, the original D-NeRF); ``"black"`` for the
  DeformableGS/Grid4D setting. RGBA is composited on it at native resolution and quantised to 8 bits by
  truncation before resizing, as 4DGaussians, DeformableGS and Grid4D do (``_io.to_rgb8``).
- Poses: ``transform_matrix`` is a Blender/OpenGL camera-to-world (x right, y up, z back); its y and z
  axes are flipped to OpenCV and inverted to world-to-camera. ``fx = fy = 0.5 W / tan(camera_angle_x / 2)``,
  principal point at the image centre.
- Time: the json ``time`` (already in [0, 1]); ``num_frames`` counts distinct training times.
- Points: D-NeRF has none; 100k random points in [-1.3, 1.3]^3 (DeformableGS / Grid4D; 4DGaussians
  uses 2000, pass ``num_points=2000``). ``bbox`` is that box; ``extent`` is 3DGS ``getNerfppNorm``.
- Test split: ``test`` (MoE-GS; lego's test split is misaligned, ``test_split="val"`` evaluates on val).
- Masks: ``View.load_mask`` is the object (alpha > 0.5 after resizing): D-NeRF's moving content, the
  "dynamic" region of the region metrics; the empty background is the "static" one.
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path

import torch
from torch import Tensor

from moegs.camera import Camera, intrinsics, rotation_problem
from moegs.data._init_points import box_points
from moegs.data._io import (
    background_color,
    entries,
    image_size,
    load_alpha_mask,
    load_json,
    load_rgb,
    loaded_scene,
    matrix,
    number,
    text,
)
from moegs.data.scene import Scene, View

BOX = 1.3  # half-size of the random-init box (DeformableGS / Grid4D / 4DGaussians)
_OPENGL_TO_OPENCV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


def blender_to_w2c(c2w_gl: Tensor) -> Tensor:
    """Blender/OpenGL camera-to-world ``[4, 4]`` -> OpenCV world-to-camera ``[4, 4]`` (float32)."""
    c2w = c2w_gl.to(torch.float64) @ _OPENGL_TO_OPENCV
    return torch.linalg.inv(c2w).to(torch.float32)


def w2c_to_blender(w2c: Tensor) -> Tensor:
    """Inverse of :func:`blender_to_w2c` (used to write fixtures)."""
    return (torch.linalg.inv(w2c.to(torch.float64)) @ _OPENGL_TO_OPENCV).to(torch.float32)


def _read_split(
    root: Path,
    split: str,
    scale: float,
    bg: Tensor,
    resample: str,
    native: tuple[int, int] | None,
    used: dict[Path, str],
) -> tuple[list[View], tuple[int, int]]:
    """The views of one split; ``used`` (image file -> the split and frame that read it) is filled, and an
    image read twice, within a split or by both (a test view that is trained on), is refused."""
    path = root / f"transforms_{split}.json"
    meta = load_json(path, f"D-NeRF {split} split (expected transforms_{split}.json in {root})")
    angle = number(meta, "camera_angle_x", path)
    if not 0.0 < angle < math.pi:
        raise ValueError(f"{path}: 'camera_angle_x' must be a field of view in (0, pi) radians, got {angle}")
    frames = entries(meta, "frames", path)
    views = []
    for i, fr in enumerate(frames):
        where = f"frames[{i}]"
        rel = text(fr, "file_path", path, where)
        img_path = (root / rel).with_suffix(".png") if not rel.endswith(".png") else root / rel
        first = used.setdefault(img_path.resolve(), f"transforms_{split}.json {where}")
        if first != f"transforms_{split}.json {where}":
            raise ValueError(
                f"{path}: {where} reads {img_path}, which {first} reads too; each view needs its own image"
            )
        if native is None:
            native = image_size(img_path)
        c2w = matrix(fr, "transform_matrix", path, (4, 4), where)
        problem = rotation_problem(c2w[:3, :3])
        if problem:
            raise ValueError(f"{path}: {where}.transform_matrix: its rotation {problem}")
        t = number(fr, "time", path, where)
        if not 0.0 <= t <= 1.0:
            raise ValueError(f"{path}: {where}.time = {t} is outside [0, 1]")
        focal = 0.5 * native[0] / math.tan(0.5 * angle)
        cam = Camera(
            K=intrinsics(focal, focal, native[0] / 2, native[1] / 2),
            world_to_camera=blender_to_w2c(c2w),
            width=native[0],
            height=native[1],
            time=t,
            camera_id=0,
            frame=i,
            name=f"{split}/{Path(rel).stem}",
        )
        if scale != 1.0:
            cam = cam.scaled(scale)
        size = (cam.width, cam.height)
        views.append(
            View(
                camera=cam,
                key=f"dnerf:{root.name}/{split}/{i}@{size[0]}x{size[1]}",
                load_image=partial(load_rgb, img_path, native, size, bg, resample),
                load_mask=partial(load_alpha_mask, img_path, native, size, resample),
            )
        )
    return views, native


def load_dnerf(
    root: str | Path,
    resolution_scale: float = 1.0,
    background: str | Tensor = "white",
    test_split: str = "test",
    num_points: int = 100_000,
    seed: int = 0,
    resample: str = "area",
    name: str | None = None,
) -> Scene:
    """Load a D-NeRF scene folder.

    Args:
        root: folder holding ``transforms_train.json``.
        resolution_scale: 1.0 -> 800x800 (dynamic-GS protocol), 0.5 -> 400x400 (NeRF protocol).
        background: ``"white"`` (default), ``"black"`` or an RGB tensor ``[3]``.
        test_split: ``"test"`` or ``"val"``.
        num_points: random initial points in [-1.3, 1.3]^3 (0 for none).
        resample: PIL filter for ``resolution_scale != 1`` (``"area"`` = ``cv2.INTER_AREA``).
    """
    root = Path(root)
    if not (root / "transforms_train.json").is_file():
        raise FileNotFoundError(
            f"D-NeRF scene: expected {root / 'transforms_train.json'} "
            "(layout: transforms_{train,val,test}.json + train/ val/ test/ PNGs)"
        )
    if test_split not in ("test", "val"):
        raise ValueError(f"D-NeRF test_split must be 'test' or 'val', got {test_split!r}")
    bg = background_color(background)
    used: dict[Path, str] = {}
    train, native = _read_split(root, "train", resolution_scale, bg, resample, None, used)
    test, _ = _read_split(root, test_split, resolution_scale, bg, resample, native, used)
    bbox = torch.tensor([[-BOX] * 3, [BOX] * 3])
    points = box_points(bbox, num_points, seed) if num_points > 0 else None
    return loaded_scene(
        "dnerf",
        root.name,
        name,
        train,
        test,
        cameras=[v.camera for v in train],
        points=points,
        bbox=bbox,
        num_frames=len({v.camera.time for v in train}),
        background=bg,
        meta={
            "test_split": test_split,
            "native_size": list(native),
            "resolution_scale": resolution_scale,
            "time": "json 'time'",
            "bbox": "random-init box [-1.3, 1.3]^3",
        },
    )
