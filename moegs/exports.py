"""``moegs export``: a trained run's Gaussians at one or many times, as files other viewers open.

Formats:

- ``ply``: the standard 3DGS PLY (``moegs.io.export_ply``; SuperSplat, gsplat, graphdeco's viewers).
- ``splat``: the layout of antimatter15/splat and the web viewers that read it. 32 bytes per Gaussian,
  little endian, no header::

      position  3 x float32   world x, y, z
      scale     3 x float32   standard deviations (linear, not log)
      colour    4 x uint8     R, G, B from the SH DC term (0.5 + C0 * dc), A = opacity, times 255
      rotation  4 x uint8     unit quaternion (w, x, y, z), each q * 128 + 128 clipped to [0, 255]

  sorted by ``scale_x * scale_y * scale_z * opacity``, largest first (antimatter15's ``convert.py``).

``export_times`` writes one file per time into a folder with ``index.json``::

    {"format": "ply", "expert": "grid4d", "scene": "dnerf:mutant",
     "frames": [{"time": 0.0, "file": "frame_0000_t0.000.ply", "num_gaussians": 12345}, ...]}
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from moegs.gaussians import GaussianFrame

FORMATS = ("ply", "splat")
"""File formats ``moegs export --format`` writes."""

SPLAT_DTYPE = np.dtype(
    [("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)]
)
"""One Gaussian of a ``.splat`` file (32 bytes)."""

INDEX = "index.json"
"""The file of an export folder that lists its times and files."""


def _rgb(frame: GaussianFrame) -> torch.Tensor:
    """``[N, 3]`` base colour: RGB ``colors`` as they are, else the SH DC term as 3DGS converts it."""
    from moegs.render.projection import sh0_to_rgb

    if frame.sh is not None and frame.sh.shape[2] == 3:
        return sh0_to_rgb(frame.sh[:, 0, :])
    if frame.colors is not None and frame.colors.shape[1] == 3:
        return frame.colors
    raise ValueError(f"a .splat file holds RGB; the frame has {frame.num_channels} colour channels")


def splat_bytes(frame: GaussianFrame) -> bytes:
    """``frame`` (activated values) in the ``.splat`` layout of the module (``32 * N`` bytes)."""
    frame = frame.detach().to("cpu")
    scales = frame.scales.abs().double()  # as positive_scales
    rgba = torch.cat([_rgb(frame).double(), frame.opacities.double()[:, None]], dim=1)
    quats = torch.nn.functional.normalize(frame.quats.double(), dim=-1)
    order = torch.argsort(-(scales.prod(dim=1) * frame.opacities.double()), stable=True)
    data = np.empty(len(frame), dtype=SPLAT_DTYPE)
    data["position"] = frame.means[order].numpy()
    data["scale"] = scales[order].numpy()
    data["rgba"] = (rgba[order] * 255).round().clamp(0, 255).numpy()
    data["rotation"] = (quats[order] * 128 + 128).round().clamp(0, 255).numpy()
    return data.tobytes()


def write_splat(frame: GaussianFrame, path: str | Path) -> Path:
    """Write ``frame`` as a ``.splat`` file; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(splat_bytes(frame))
    return path


def read_splat(path: str | Path) -> dict[str, np.ndarray]:
    """A ``.splat`` file decoded: ``position [N, 3]``, ``scale [N, 3]``, ``rgba [N, 4]`` in [0, 1],
    ``rotation [N, 4]`` (w, x, y, z) in [-1, 1] (quantised; not renormalised)."""
    raw = Path(path).read_bytes()
    if len(raw) % SPLAT_DTYPE.itemsize:
        raise ValueError(f"{path}: {len(raw)} bytes is no multiple of {SPLAT_DTYPE.itemsize}; not a .splat")
    data = np.frombuffer(raw, dtype=SPLAT_DTYPE)
    return {
        "position": data["position"].astype(np.float32),
        "scale": data["scale"].astype(np.float32),
        "rgba": data["rgba"].astype(np.float32) / 255,
        "rotation": (data["rotation"].astype(np.float32) - 128) / 128,
    }


def positive_scales(frame: GaussianFrame) -> GaussianFrame:
    """``frame`` with ``|scales|``: only their squares enter the covariance (``GaussianFrame``; Deformable
    3DGS adds its offsets after the activation), and a PLY stores their logarithms."""
    return replace(frame, scales=frame.scales.abs()) if bool((frame.scales < 0).any()) else frame


def write_frame(frame: GaussianFrame, path: str | Path, fmt: str) -> Path:
    """Write ``frame`` to ``path`` in ``fmt`` (one of ``FORMATS``)."""
    from moegs.io import export_ply

    if fmt == "ply":
        return export_ply(positive_scales(frame), path)
    if fmt == "splat":
        return write_splat(frame, path)
    raise ValueError(f"unknown export format {fmt!r}; one of {', '.join(FORMATS)}")


def parse_times(text: str, scene_times: list[float]) -> list[float]:
    """``--times``: ``all`` (the scene's distinct frame times, sorted) or comma-separated times in [0, 1]."""
    if text.strip() == "all":
        return sorted({round(float(t), 6) for t in scene_times})
    times = []
    for item in text.split(","):
        try:
            t = float(item)
        except ValueError:
            t = float("nan")
        if not 0.0 <= t <= 1.0:
            raise ValueError(
                f"--times expects 'all' or comma-separated times in [0, 1], got {item.strip()!r}"
            )
        times.append(t)
    return times


def export_times(expert, times: list[float], folder: str | Path, fmt: str, about: dict) -> Path:
    """One ``fmt`` file of ``expert.frame(t)`` per time in ``folder`` and ``folder/index.json`` (``about``:
    fields added to the index, e.g. expert and scene). Returns the index's path."""
    from moegs.io import write_json

    folder = Path(folder)
    frames = []
    with torch.no_grad():
        for i, t in enumerate(times):
            frame = expert.frame(t)
            name = f"frame_{i:04d}_t{t:.3f}.{fmt}"
            write_frame(frame, folder / name, fmt)
            frames.append({"time": t, "file": name, "num_gaussians": len(frame)})
    return write_json(folder / INDEX, {"format": fmt, **about, "frames": frames})
