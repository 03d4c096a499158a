"""Shared reading helpers for the dataset loaders: JSON with named-key errors, images, resizing,
time windows, camera extent, COLMAP models.

Every error names the file it concerns and, where it applies, the expected and the found value.
Video decoding lives in ``moegs.data._video``, initial point clouds in ``moegs.data._init_points``.
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image, UnidentifiedImageError
from torch import Tensor

from moegs.camera import Camera
from moegs.data import decoded
from moegs.data.scene import PointCloud, Scene, View

RESAMPLE = {
    "nearest": Image.Resampling.NEAREST,
    "bilinear": Image.Resampling.BILINEAR,
    "bicubic": Image.Resampling.BICUBIC,  # PIL's default in ``Image.resize`` (3DGS ``PILtoTorch``)
    "lanczos": Image.Resampling.LANCZOS,
    "area": Image.Resampling.BOX,  # box filter == cv2.INTER_AREA for integer factors (NeRF half_res)
}


# -- files and JSON ---------------------------------------------------------------------------------
def require_file(path: Path, what: str) -> Path:
    """``path`` if it is a regular file, else ``FileNotFoundError`` naming it, what it should hold and, when
    something else is there, what (a directory, a FIFO that reading would block on, a socket...)."""
    if path.is_file():
        return path
    if path.exists():
        found = "a directory" if path.is_dir() else "a FIFO" if path.is_fifo() else "no regular file"
        raise FileNotFoundError(f"{what}: expected a file at {path} but found {found}")
    raise FileNotFoundError(f"{what}: expected file {path} but it does not exist")


def load_json(path: Path, what: str) -> Any:
    """Parsed JSON; a missing or malformed file raises an error naming it."""
    require_file(path, what)
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{what}: {path} is not valid JSON ({err})") from err


def key(mapping: Any, name: str | int, path: Path, where: str = "") -> Any:
    """``mapping[name]`` or ``KeyError`` naming the key, the file and the place in it."""
    if not isinstance(mapping, dict) or name not in mapping:
        place = f" in {where}" if where else ""
        found = sorted(map(str, mapping))[:12] if isinstance(mapping, dict) else type(mapping).__name__
        raise KeyError(f"{path}: missing key {name!r}{place} (found {found})")
    return mapping[name]


def _field(name: str | int, where: str) -> str:
    return f"{where}.{name}" if where else repr(name)


def number(mapping: Any, name: str | int, path: Path, where: str = "") -> float:
    """``mapping[name]`` as a finite float; ``TypeError`` naming file and field for anything else."""
    value = key(mapping, name, path, where)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise TypeError(f"{path}: {_field(name, where)} must be a finite number, got {value!r}")
    return float(value)


def text(mapping: Any, name: str | int, path: Path, where: str = "") -> str:
    """``mapping[name]`` as a string; ``TypeError`` naming file and field otherwise."""
    value = key(mapping, name, path, where)
    if not isinstance(value, str):
        raise TypeError(f"{path}: {_field(name, where)} must be a string, got {value!r}")
    return value


def entries(mapping: Any, name: str | int, path: Path, where: str = "") -> list:
    """``mapping[name]`` as a non-empty list; ``TypeError``/``ValueError`` naming file and field."""
    value = key(mapping, name, path, where)
    if not isinstance(value, list):
        raise TypeError(f"{path}: {_field(name, where)} must be a list, got {type(value).__name__}")
    if not value:
        raise ValueError(f"{path}: {_field(name, where)} is empty")
    return value


def matrix(mapping: Any, name: str | int, path: Path, shape: tuple[int, ...], where: str = "") -> Tensor:
    """``mapping[name]``, nested lists of finite numbers of ``shape``, as float64; errors name the field."""
    value = key(mapping, name, path, where)
    expected = "x".join(map(str, shape))
    try:
        tensor = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(f"{path}: {_field(name, where)} must be a {expected} array of numbers") from None
    if tuple(tensor.shape) != shape:
        raise ValueError(f"{path}: {_field(name, where)} must be {expected}, got {list(tensor.shape)}")
    if not torch.isfinite(tensor).all():
        raise ValueError(f"{path}: {_field(name, where)} has NaN or Inf")
    return tensor


def vector(mapping: Any, name: str | int, path: Path, where: str = "") -> list[float]:
    """``mapping[name]``, a list of finite numbers of any length; errors name the file and the field."""
    value = key(mapping, name, path, where)
    if not isinstance(value, list):
        raise TypeError(f"{path}: {_field(name, where)} must be a list of numbers, got {value!r}")
    return matrix(mapping, name, path, (len(value),), where).tolist()


# -- images -----------------------------------------------------------------------------------------
def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` from the file header only (no pixel decoding)."""
    require_file(path, "image")
    try:
        with Image.open(path) as im:
            return im.size
    except (UnidentifiedImageError, OSError) as err:
        raise ValueError(f"cannot read image {path}: {err}") from err


def read_image(path: Path) -> np.ndarray:
    """Decoded image ``[H, W, C]`` uint8 with C = 3 (RGB) or 4 (RGBA); grey and palette become RGB(A)."""
    require_file(path, "image")
    try:
        with Image.open(path) as im:
            if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                im = im.convert("RGBA")
            elif im.mode != "RGB":
                im = im.convert("RGB")
            return np.asarray(im).copy()
    except (UnidentifiedImageError, OSError) as err:
        raise ValueError(f"cannot decode image {path}: {err}") from err


def read_mask(path: Path, size: tuple[int, int]) -> Tensor:
    """Mask ``[H, W]`` float32 in [0, 1] at ``size = (width, height)`` (any non-zero pixel counts as 1)."""
    require_file(path, "mask")
    try:
        with Image.open(path) as im:
            arr = np.asarray(im.convert("L"), dtype=np.float32) / 255.0
    except (UnidentifiedImageError, OSError) as err:
        raise ValueError(f"cannot decode mask {path}: {err}") from err
    mask = torch.from_numpy((arr > 0).astype(np.float32))
    if (mask.shape[1], mask.shape[0]) != size:
        mask = resize(mask[..., None], size, "nearest")[..., 0]
    return mask


def check_size(arr: np.ndarray | Tensor, expected: tuple[int, int], path: Path | str) -> None:
    """Raise if an ``[H, W, ...]`` array is not ``expected = (width, height)``."""
    got = (int(arr.shape[1]), int(arr.shape[0]))
    if got != tuple(expected):
        raise ValueError(
            f"{path}: image is {got[0]}x{got[1]} but {expected[0]}x{expected[1]} was expected "
            "(from the calibration / the first image of the scene)"
        )


BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


def background_color(background: str | Tensor) -> Tensor:
    """``"white"``, ``"black"`` or an RGB tensor -> float32 ``[3]``; ``ValueError`` otherwise."""
    if isinstance(background, Tensor):
        if background.numel() != 3:
            raise ValueError(f"background must have 3 values (RGB), got shape {list(background.shape)}")
        return background.to(torch.float32).reshape(3)
    if background not in BACKGROUNDS:
        raise ValueError(f"background must be 'white', 'black' or an RGB tensor, got {background!r}")
    return torch.tensor(BACKGROUNDS[background])


def to_rgb8(arr: np.ndarray, background: Tensor) -> np.ndarray:
    """uint8 ``[H, W, 3|4]`` -> uint8 ``[H, W, 3]``: RGB as it is; RGBA composited on ``background [3]``.

    The composite is quantised to 8 bits by truncation, in float64, as the dynamic-GS loaders of D-NeRF
    do (``np.array(arr * 255.0, dtype=np.byte)`` after ``rgb * a + bg * (1 - a)``: 4DGaussians
    ``scene/dataset_readers.py:285-287``, DeformableGS ``scene/dataset_readers.py:249-255``, Grid4D
    ``scene/dataset_readers.py:250-256``), so the ground truth is the 8-bit image they train on.
    """
    if arr.shape[-1] != 4:
        return np.ascontiguousarray(arr[..., :3])
    norm = arr.astype(np.float64) / 255.0
    alpha = norm[..., 3:4]
    bg = background.to(torch.float64).numpy()
    composite = norm[..., :3] * alpha + bg * (1.0 - alpha)
    return (composite * 255.0).astype(np.int64).clip(0, 255).astype(np.uint8)


def resize(img: Tensor, size: tuple[int, int], method: str = "bicubic") -> Tensor:
    """Resize float ``[H, W, C]`` to ``size = (width, height)`` channel by channel with a PIL filter.

    Runs on float32 ("F" mode) so no 8-bit rounding is added; values are clamped back to the input range.
    """
    if method not in RESAMPLE:
        raise ValueError(f"unknown resample method {method!r}; valid: {sorted(RESAMPLE)}")
    if (img.shape[1], img.shape[0]) == tuple(size):
        return img
    arr = img.detach().cpu().numpy().astype(np.float32)
    out = np.stack(
        [
            np.asarray(Image.fromarray(arr[..., c], mode="F").resize(size, RESAMPLE[method]))
            for c in range(arr.shape[-1])
        ],
        axis=-1,
    )
    return torch.from_numpy(out).clamp_(float(img.min()), float(img.max()))


def resize_uint8(arr: np.ndarray, size: tuple[int, int], method: str = "bicubic") -> np.ndarray:
    """Resize uint8 ``[H, W, C]`` to ``size = (width, height)`` with a PIL filter (as the GS loaders do)."""
    if method not in RESAMPLE:
        raise ValueError(f"unknown resample method {method!r}; valid: {sorted(RESAMPLE)}")
    if (arr.shape[1], arr.shape[0]) == tuple(size):
        return arr
    return np.array(Image.fromarray(arr).resize(size, RESAMPLE[method]))


def load_rgb(
    path: Path, native: tuple[int, int], size: tuple[int, int], background: Tensor, method: str
) -> Tensor:
    """Read ``path``, check its native size, composite on ``background``, resize to ``size``.

    Returns ``[H, W, 3]`` uint8 (``View.image`` gives it as float32 in [0, 1]). RGBA is composited and
    quantised at native resolution (``to_rgb8``) and the 8-bit composite is resized with PIL, as the GS
    loaders do (3DGS ``PILtoTorch``). Results are kept on disk between processes (``moegs.data.decoded``).
    """

    def load() -> Tensor:
        arr = read_image(path)
        check_size(arr, native, path)
        return torch.from_numpy(resize_uint8(to_rgb8(arr, background), size, method))

    args = (tuple(native), tuple(size), tuple(background.tolist()), method)
    return decoded.cached("rgb8", path, args, (size[1], size[0], 3), load, torch.uint8)


def load_alpha_mask(path: Path, native: tuple[int, int], size: tuple[int, int], method: str) -> Tensor:
    """Object mask ``[H, W]`` float32 of an RGBA image: its alpha resized to ``size``, above 0.5 (an
    RGB image has no alpha: ``ValueError`` naming the file). Kept on disk like ``load_rgb``."""

    def load() -> Tensor:
        arr = read_image(path)
        check_size(arr, native, path)
        if arr.shape[-1] != 4:
            raise ValueError(f"{path}: no alpha channel, so no object mask (expected an RGBA PNG)")
        alpha = resize(torch.from_numpy(arr[..., 3:].astype(np.float32) / 255.0), size, method)[..., 0]
        return (alpha > 0.5).float()

    return decoded.cached("alpha-mask", path, (tuple(native), tuple(size), method), (size[1], size[0]), load)


# -- scene-level quantities -------------------------------------------------------------------------
def camera_extent(cameras: Sequence[Camera]) -> float:
    """3DGS ``getNerfppNorm`` radius: 1.1 x the largest distance of a camera centre from their mean."""
    centers = torch.stack([c.center for c in cameras]).to(torch.float64)
    radius = (centers - centers.mean(0)).norm(dim=-1).max().item()
    return 1.1 * radius if radius > 0 else 1.0


def points_bbox(xyz: Tensor, quantile: float = 0.0) -> Tensor:
    """``[2, 3]`` axis-aligned bounds of ``xyz [P, 3]``; ``quantile`` > 0 trims outliers on both sides."""
    if quantile > 0 and xyz.shape[0] > 10:
        q = torch.tensor([quantile, 1.0 - quantile], dtype=xyz.dtype)
        return torch.quantile(xyz, q, dim=0).to(torch.float32)
    return torch.stack([xyz.min(0).values, xyz.max(0).values]).to(torch.float32)


def camera_bbox(cameras: Sequence[Camera]) -> Tensor:
    """``[2, 3]`` bounds of the camera centres (a scene's content bounds when it has no points)."""
    return points_bbox(torch.stack([c.center for c in cameras]))


def loaded_scene(
    dataset: str,
    folder: str,
    name: str | None,
    train: list[View],
    test: list[View],
    *,
    cameras: Sequence[Camera],
    points: PointCloud | None,
    bbox: Tensor | None = None,
    **fields: Any,
) -> Scene:
    """The ``Scene`` a dataset loader returns: named ``dataset:folder`` unless ``name`` is given, with the
    3DGS ``extent`` of the training ``cameras`` and, unless ``bbox`` is given, the initial points'
    1%-trimmed bounds (the cameras' centres without points). ``fields``: the rest of ``Scene``."""
    if bbox is None:
        bbox = points_bbox(points.xyz, 0.01) if points is not None else camera_bbox(cameras)
    return Scene(
        name=name or f"{dataset}:{folder}",
        dataset=dataset,
        train=train,
        test=test,
        extent=camera_extent(cameras),
        points=points,
        bbox=bbox,
        **fields,
    )


def frame_window(frames: tuple[int, int] | None, available: int, what: str) -> tuple[int, int]:
    """Validated half-open window ``(start, stop)`` of frame indices; ``None`` means all."""
    if frames is None:
        return 0, available
    start, stop = int(frames[0]), int(frames[1])
    if not (0 <= start < stop <= available):
        raise ValueError(f"{what}: frame window {frames} is outside 0..{available} (half-open start, stop)")
    return start, stop


def normalised_time(frame: int, start: int, stop: int, total: int, mode: str) -> float:
    """Time of ``frame`` in [0, 1).

    ``global``: ``frame / total`` (4DGaussians and the MoE-GS router on N3V: frame/300).
    ``local``: ``(frame - start) / (stop - start)`` (STG segments, MoE-GS on Technicolor).
    """
    if mode == "global":
        return frame / total
    if mode == "local":
        return (frame - start) / (stop - start)
    raise ValueError(f"time mode must be 'global' or 'local', got {mode!r}")


# -- COLMAP models --------------------------------------------------------------------------------
def read_colmap(path: Path) -> Any:
    """``pycolmap.Reconstruction`` of a COLMAP model folder (text or binary), with a clear error."""
    import pycolmap

    if not path.is_dir() or not any((path / f"images.{ext}").is_file() for ext in ("bin", "txt")):
        raise FileNotFoundError(
            f"COLMAP model: expected {path}/images.bin or images.txt (with cameras.* and points3D.*)"
        )
    try:
        return pycolmap.Reconstruction(str(path))
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on bad files
        raise ValueError(f"cannot read COLMAP model {path}: {err}") from err


def colmap_w2c(image: Any) -> Tensor:
    """OpenCV world-to-camera ``[4, 4]`` of a ``pycolmap.Image`` (a method in pycolmap >= 3.12)."""
    pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3] = torch.from_numpy(np.asarray(pose.matrix(), dtype=np.float64))
    return w2c.to(torch.float32)


def with_background(loader: Any, source: Any, background: str | Tensor | None, **kwargs: Any) -> Any:
    """``loader(source, **kwargs)`` on ``background``: passed to loaders that composite RGBA images
    (``background`` argument), set as the scene's colour for the others."""
    if background is None:
        return loader(source, **kwargs)
    if "background" in inspect.signature(loader).parameters:
        return loader(source, background=background, **kwargs)
    scene = loader(source, **kwargs)
    scene.background = background_color(background)
    return scene
