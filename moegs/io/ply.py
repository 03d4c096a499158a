"""3DGS-compatible PLY files (the layout of graphdeco 3DGS ``GaussianModel.save_ply``).

One ``vertex`` element of float32 properties, in this order::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3K-1)  opacity  scale_0..2  rot_0..3

with raw values: opacity as a logit, scales as logs, ``rot`` the quaternion (w, x, y, z), ``f_dc`` the
SH DC coefficient per channel and ``f_rest`` the ``K = (degree + 1)² - 1`` higher bands stored
channel-major (all bands of R, then G, then B), as 3DGS flattens ``features_rest.transpose(1, 2)``.
Normals are zeros.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from moegs.gaussians import GaussianFrame
from moegs.render.projection import rgb_to_sh0

_OPACITY_EPS = 1e-7  # keeps logit finite for opacities saturated at 0 or 1


def _sh(frame: GaussianFrame) -> torch.Tensor:
    """``[N, B, 3]`` SH of ``frame`` (RGB colours become a DC-only SH)."""
    if frame.sh is not None:
        if frame.sh.shape[2] != 3:
            raise ValueError(f"export_ply writes RGB SH; the frame has {frame.sh.shape[2]} channels")
        return frame.sh
    if frame.colors.shape[1] != 3:
        raise ValueError(f"export_ply writes RGB; the frame has {frame.colors.shape[1]} colour channels")
    return rgb_to_sh0(frame.colors)[:, None, :]


def export_ply(frame: GaussianFrame, path: str | Path) -> Path:
    """Write ``frame`` (activated values) as a 3DGS PLY; returns the path."""
    frame = frame.detach().to("cpu")
    sh = _sh(frame).to(torch.float32)
    n, bases = sh.shape[0], sh.shape[1]
    dc = sh[:, 0, :]  # [N, 3]
    rest = sh[:, 1:, :].transpose(1, 2).reshape(n, -1)  # [N, 3 * (B - 1)], channel-major
    opacity = torch.logit(frame.opacities.clamp(_OPACITY_EPS, 1 - _OPACITY_EPS))[:, None]
    columns = {
        **{c: frame.means[:, i] for i, c in enumerate("xyz")},
        **{c: torch.zeros(n) for c in ("nx", "ny", "nz")},
        **{f"f_dc_{i}": dc[:, i] for i in range(3)},
        **{f"f_rest_{i}": rest[:, i] for i in range(3 * (bases - 1))},
        "opacity": opacity[:, 0],
        **{f"scale_{i}": torch.log(frame.scales[:, i]) for i in range(3)},
        **{f"rot_{i}": frame.quats[:, i] for i in range(4)},
    }
    data = np.empty(n, dtype=[(name, "f4") for name in columns])
    for name, values in columns.items():
        data[name] = values.to(torch.float32).numpy()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    return path


def read_ply(path: str | Path) -> GaussianFrame:
    """Read a 3DGS PLY into an activated ``GaussianFrame`` (quaternions normalised)."""
    vertex = PlyData.read(str(path))["vertex"]
    names = {p.name for p in vertex.properties}

    def column(name: str) -> torch.Tensor:
        if name not in names:
            raise ValueError(f"{path}: not a 3DGS PLY, missing property {name!r}")
        return torch.from_numpy(np.asarray(vertex[name], np.float32))

    def cols(prefix: str, count: int) -> torch.Tensor:
        return (
            torch.stack([column(f"{prefix}{i}") for i in range(count)], dim=1) if count else torch.zeros(n, 0)
        )

    n = len(vertex.data)
    rest_count = len([p for p in names if p.startswith("f_rest_")])
    if rest_count % 3 or int(round((rest_count // 3 + 1) ** 0.5)) ** 2 != rest_count // 3 + 1:
        raise ValueError(f"{path}: {rest_count} f_rest properties do not form SH bands of 3 channels")
    dc = cols("f_dc_", 3)[:, None, :]
    rest = cols("f_rest_", rest_count).reshape(n, 3, rest_count // 3).transpose(1, 2)
    return GaussianFrame(
        means=torch.stack([column(c) for c in "xyz"], dim=1),
        quats=torch.nn.functional.normalize(cols("rot_", 4), dim=-1),
        scales=torch.exp(cols("scale_", 3)),
        opacities=torch.sigmoid(column("opacity")),
        sh=torch.cat([dc, rest], dim=1),
    )
