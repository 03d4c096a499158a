"""What the viewer draws, as plain functions (no browser, no viser): cameras from a viewer's pose, one
image per mode, colour maps, colour bars and legends.

    camera = camera_from_pose(wxyz, position, fov_y, 256, 256, time=0.3)   # viser's pose -> moegs Camera
    image = render_mode(model, camera, "gate grid4d", "blend")              # uint8 [256, 256, 3]

Poses follow viser (and OpenCV): ``wxyz`` rotates camera axes (x right, y down, z forward) into the world,
``position`` is the camera centre, ``fov_y`` the vertical field of view in radians.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import torch

from moegs.camera import Camera, intrinsics

BASE_MODES = ("rgb", "depth", "alpha", "ground truth", "error")
"""Modes of every model; a MoE-GS model adds ``gate <expert>`` for each expert and ``winner``."""

SOURCED_MODES = ("rgb", "depth", "alpha", "error")
"""Modes that show one source: an expert or the blend."""

BLEND = "blend"
"""The source name of a MoE-GS model's routed image."""

DEPTH_COLORMAP, GATE_COLORMAP = "turbo", "viridis"


# ---------------------------------------------------------------------------------------------- cameras
def quat_to_matrix(wxyz) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> rotation ``[3, 3]`` (float64)."""
    w, x, y, z = np.asarray(wxyz, dtype=np.float64) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R) -> np.ndarray:
    """Rotation ``[3, 3]`` -> unit quaternion (w, x, y, z) with ``w >= 0`` (float64)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def camera_from_pose(
    wxyz, position, fov_y: float, width: int, height: int, time: float, near: float = 0.01, far: float = 1e3
) -> Camera:
    """A pinhole ``Camera`` (square pixels, centred principal point) of a viewer's pose."""
    R = quat_to_matrix(wxyz)  # camera -> world
    w2c = np.eye(4)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ np.asarray(position, dtype=np.float64)
    focal = height / 2 / math.tan(fov_y / 2)
    return Camera(
        K=intrinsics(focal, focal, width / 2, height / 2),
        world_to_camera=torch.from_numpy(w2c).float(),
        width=width,
        height=height,
        time=float(time),
        near=near,
        far=far,
    )


def pose_of_camera(camera: Camera) -> tuple[np.ndarray, np.ndarray, float]:
    """``(wxyz [4], position [3], fov_y)`` of ``camera`` (its vertical field of view from ``fy``)."""
    w2c = camera.world_to_camera.detach().cpu().double().numpy()
    R = w2c[:3, :3].T
    return matrix_to_quat(R), -R @ w2c[:3, 3], 2 * math.atan(camera.height / 2 / camera.fy)


def sized(width: int, height: int, long_side: int) -> tuple[int, int]:
    """``(w, h)`` of the aspect ``width / height`` with the longer side ``long_side`` (each at least 1)."""
    scale = long_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


# ---------------------------------------------------------------------------------------------- modes
def modes_of(expert_names: list[str], moe: bool) -> list[str]:
    """The modes of a model of ``expert_names`` (``moe``: with a router)."""
    return [*BASE_MODES, *([f"gate {n}" for n in expert_names] + ["winner"] if moe else [])]


def sources_of(expert_names: list[str], moe: bool) -> list[str]:
    """What ``rgb``, ``depth``, ``alpha`` and ``error`` show: the blend of a MoE-GS model, or an expert."""
    return [BLEND, *expert_names] if moe else list(expert_names)


def check_choice(value: str, choices: list[str], what: str) -> str:
    """``value`` when it is one of ``choices``, else ``ValueError`` naming them."""
    if value not in choices:
        raise ValueError(f"unknown {what} {value!r}; this model's {what}s: {', '.join(choices)}")
    return value


# ---------------------------------------------------------------------------------------------- images
def to_u8(image: torch.Tensor | np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` (or ``[H, W]``, drawn grey) float in [0, 1] -> uint8 ``[H, W, 3]``."""
    image = torch.as_tensor(image).detach().cpu().float()
    if image.ndim == 2:
        image = image[..., None].expand(*image.shape, 3)
    return (image.clamp(0, 1) * 255).round().to(torch.uint8).numpy()


def colormap(values: np.ndarray, name: str) -> np.ndarray:
    """``[...]`` values in [0, 1] -> uint8 ``[..., 3]`` through a matplotlib colour map."""
    from matplotlib import colormaps

    return (colormaps[name](np.clip(values, 0, 1))[..., :3] * 255).round().astype(np.uint8)


def depth_image(depth: torch.Tensor, alpha: torch.Tensor) -> tuple[np.ndarray, float, float]:
    """``(image uint8 [H, W, 3], near, far)``: depth ``[H, W]`` between its 2nd and 98th percentile where
    ``alpha [H, W] > 0.5`` through ``DEPTH_COLORMAP`` (near warm, far cold), faded to black with alpha."""
    depth, alpha = depth.detach().cpu().float().numpy(), alpha.detach().cpu().float().numpy()
    covered = depth[alpha > 0.5]
    near, far = (np.percentile(covered, [2, 98]) if covered.size else (0.0, 1.0)).tolist()
    far = max(far, near + 1e-6)
    image = colormap(1 - (depth - near) / (far - near), DEPTH_COLORMAP).astype(np.float32)
    return (image * np.clip(alpha, 0, 1)[..., None]).round().astype(np.uint8), near, far


def _font(height: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=max(9, height // 28))


def colour_bar_box(height: int, width: int) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` (exclusive ends) of the colour bar ``with_colour_bar`` draws on an image: the
    middle half of the width, near the bottom."""
    y1 = height - max(3, height // 16)
    return width // 4, y1 - max(4, height // 24), width - width // 4, y1


def with_colour_bar(image: np.ndarray, cmap: str, low: str, high: str, reverse: bool = False) -> np.ndarray:
    """``image`` uint8 ``[H, W, 3]`` with a horizontal bar of ``cmap`` at the bottom (``colour_bar_box``; low
    values at the left, ``reverse``: at the right), framed in white, labelled ``low`` and ``high``."""
    from PIL import Image, ImageDraw

    h, w = image.shape[:2]
    x0, y0, x1, y1 = colour_bar_box(h, w)
    ramp = np.linspace(0, 1, x1 - x0)
    out = image.copy()
    out[y0:y1, x0:x1] = colormap(1 - ramp if reverse else ramp, cmap)[None, :, :]
    picture = Image.fromarray(out)
    draw = ImageDraw.Draw(picture)
    draw.rectangle((x0 - 1, y0 - 1, x1, y1), outline=(255, 255, 255))
    font, middle = _font(h), (y0 + y1) / 2
    style = {"fill": (255, 255, 255), "font": font, "stroke_width": 1, "stroke_fill": (0, 0, 0)}
    draw.text((x0 - 4, middle), low, anchor="rm", **style)
    draw.text((x1 + 4, middle), high, anchor="lm", **style)
    return np.asarray(picture)


def with_legend(image: np.ndarray, names: list[str]) -> np.ndarray:
    """``image`` with a legend at the top left: one square per expert in its winner-map colour
    (``moegs.moe.visualize.PALETTE``) and its name."""
    from PIL import Image, ImageDraw

    from moegs.moe.visualize import PALETTE

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = _font(image.shape[0])
    size = max(6, image.shape[0] // 28)
    for k, name in enumerate(names):
        y = 4 + k * (size + 4)
        colour = tuple(int(c) for c in PALETTE[k % len(PALETTE)])
        draw.rectangle((4, y, 4 + size, y + size), fill=colour, outline=(255, 255, 255))
        draw.text((8 + size, y), name, fill=(255, 255, 255), font=font, stroke_width=1, stroke_fill=(0, 0, 0))
    return np.asarray(picture)


def message_image(text: str, width: int, height: int) -> np.ndarray:
    """A dark grey uint8 ``[H, W, 3]`` image with ``text`` in the middle (a mode that cannot draw here)."""
    from PIL import Image, ImageDraw

    picture = Image.new("RGB", (width, height), (40, 40, 40))
    draw = ImageDraw.Draw(picture)
    draw.multiline_text(
        (width / 2, height / 2), text, fill=(230, 230, 230), font=_font(height), anchor="mm", align="center"
    )
    return np.asarray(picture)


def letterbox(image: np.ndarray, aspect: float) -> np.ndarray:
    """``image`` padded with black to the aspect ``width / height`` (centred)."""
    h, w = image.shape[:2]
    if w / h < aspect:
        pad = round(h * aspect) - w
        return np.pad(image, ((0, 0), (pad // 2, pad - pad // 2), (0, 0)))
    pad = round(w / aspect) - h
    return np.pad(image, ((pad // 2, pad - pad // 2), (0, 0), (0, 0)))


@cache
def _resize(width: int, height: int):
    from PIL import Image

    return lambda image: np.asarray(Image.fromarray(image).resize((width, height), Image.BILINEAR))


def resized(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 ``[H, W, 3]`` resized to ``[height, width, 3]`` (bilinear; as it is when the size matches)."""
    return image if image.shape[:2] == (height, width) else _resize(width, height)(image)


# ---------------------------------------------------------------------------------------------- rendering
@torch.no_grad()
def render_mode(model, camera: Camera, mode: str, source: str, truth: np.ndarray | None = None) -> np.ndarray:
    """uint8 ``[H, W, 3]`` of ``model`` (a ``moegs.viewer.model.ViewModel``) through ``camera`` in ``mode``.

    ``source`` (``model.sources``) picks what ``rgb``, ``depth``, ``alpha`` and ``error`` show: the blend
    of a MoE-GS model or one expert. ``truth``: the dataset image (uint8, any size) the camera shows, for
    ``ground truth`` and ``error``; without it those modes draw a message. Depth, error and gates get a
    colour bar, the winner map a legend.
    """
    check_choice(mode, model.modes, "mode")
    check_choice(source, model.sources, "source")
    h, w = camera.height, camera.width
    if mode in ("ground truth", "error") and truth is None:
        return message_image(f"{mode}:\npick a dataset camera", w, h)
    if mode == "ground truth":
        return resized(truth, w, h)
    names = model.names
    if mode == "winner" or mode.startswith("gate "):
        gates = model.render_moe(camera).gates
        if mode == "winner":
            from moegs.moe.visualize import winner_map

            return with_legend(winner_map(gates), names)
        gate = gates[names.index(mode.removeprefix("gate "))].cpu().numpy()
        return with_colour_bar(colormap(gate, GATE_COLORMAP), GATE_COLORMAP, "0", "1")
    rgb, alpha, depth = model.render_layers(camera, source, need_depth=mode in ("depth", "alpha"))
    if mode == "rgb":
        return to_u8(rgb)
    if mode == "alpha":
        return to_u8(alpha)
    if mode == "depth":
        image, near, far = depth_image(depth, alpha)
        return with_colour_bar(image, DEPTH_COLORMAP, f"{near:.2f}", f"{far:.2f}", reverse=True)
    from moegs.outputs import ERROR_COLORMAP, ERROR_GAIN, error_image

    error = error_image(to_u8(rgb), resized(truth, w, h))
    return with_colour_bar(error, ERROR_COLORMAP, "0", f"{1 / ERROR_GAIN:g}")
