"""4DGaussians HexPlane field (K-Planes with six planes over (x, y, z, t)).

Facts from ``hustvl/4DGaussians`` ``scene/hexplane.py`` (see ``specs/experts_canonical.md`` §1.1):

* Six planes in ``itertools.combinations`` order over the axes (x, y, z, t) = (0, 1, 2, 3):
  ``xy, xz, xt, yz, yt, zt``. Plane ``(a, b)`` has shape ``[1, C, res_b, res_a]`` and is sampled with
  ``grid_sample`` at ``(coord_a, coord_b)`` (bilinear, ``align_corners=True``, ``padding_mode='border'``).
* Spatial planes start ``U(0.1, 0.5)``; planes containing t start at 1.
* The six plane features are **multiplied**; the scales (``multires``) are **concatenated**:
  ``out_dim = C * len(multires)``. Scale ``m`` multiplies the spatial resolution only.
* xyz is mapped to [-1, 1] by the AABB of the initial point cloud, computed as the original
  ``normalize_aabb(x, [max, min])`` = ``(x - max) * 2 / (min - max) - 1``: ``max -> -1``, ``min -> +1``
  (a mirror image of the usual map; kept so plane contents match the original layout).
* t in [0, 1] is used raw, so only the upper half of each temporal axis is sampled (4DGaussians #251).

Regularisers (4DGaussians ``compute_regulation``, ``scene/gaussian_model.py``, summed over scales
and planes):

* plane smoothness ``Ls`` on xy, xz, yz; time smoothness ``Lt`` on xt, yt, zt: the mean squared
  **second** difference along the plane's height axis (dim -2: y / z for spatial planes, t for time planes);
* ``L1t`` on xt, yt, zt: ``mean |1 - plane|``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

AXES = "xyzt"
COMBINATIONS: tuple[tuple[int, int], ...] = tuple(itertools.combinations(range(4), 2))
"""``((0,1), (0,2), (0,3), (1,2), (1,3), (2,3))`` = xy, xz, xt, yz, yt, zt."""
SPATIAL_PLANES = tuple(k for k, c in enumerate(COMBINATIONS) if 3 not in c)  # xy, xz, yz -> (0, 1, 3)
TIME_PLANES = tuple(k for k, c in enumerate(COMBINATIONS) if 3 in c)  # xt, yt, zt -> (2, 4, 5)


def normalize_aabb(xyz: Tensor, aabb: Tensor) -> Tensor:
    """The original ``normalize_aabb``: ``(xyz - aabb[0]) * 2 / (aabb[1] - aabb[0]) - 1``.

    4DGaussians stores ``aabb = [max, min]`` ``[2, 3]``, so ``max -> -1`` and ``min -> +1``.
    """
    return (xyz - aabb[0]) * (2.0 / (aabb[1] - aabb[0])) - 1.0


def sample_plane(plane: Tensor, coords: Tensor) -> Tensor:
    """Bilinear lookup of ``plane [1, C, H, W]`` at ``coords [N, 2]`` in [-1, 1] (x -> W, y -> H).

    ``align_corners=True`` (-1 and +1 are the centres of the first and last texels), border padding.
    Returns ``[N, C]``.
    """
    if plane.ndim != 4 or plane.shape[0] != 1:
        raise ValueError(f"plane must have shape [1, C, H, W], got {list(plane.shape)}")
    if coords.ndim != 2 or coords.shape[-1] != 2:
        raise ValueError(f"coords must have shape [N, 2], got {list(coords.shape)}")
    out = F.grid_sample(
        plane, coords.view(1, 1, -1, 2), mode="bilinear", padding_mode="border", align_corners=True
    )  # [1, C, 1, N]
    return out[0, :, 0].transpose(0, 1)


def plane_smoothness(plane: Tensor) -> Tensor:
    """Mean squared second difference along the height axis (dim -2) of ``plane [..., H, W]`` (H >= 3)."""
    if plane.shape[-2] < 3:
        raise ValueError(f"plane_smoothness needs height >= 3, got shape {list(plane.shape)}")
    first = plane[..., 1:, :] - plane[..., :-1, :]
    second = first[..., 1:, :] - first[..., :-1, :]
    return second.square().mean()


class HexPlane(nn.Module):
    """Multiresolution HexPlane: ``(xyz [N, 3], t [N, 1]) -> features [N, C * len(multires)]``.

    Args:
        resolution: base resolution ``(rx, ry, rz, rt)``; scale ``m`` uses ``(m rx, m ry, m rz, rt)``.
        feature_dim: ``C`` channels per plane.
        multires: spatial resolution multipliers (4DGaussians ``[1, 2]`` / HyperNeRF ``[1, 2, 4]``).
        aabb_min, aabb_max: ``[3]`` box mapped onto [-1, 1] (set from the initial points with
            :meth:`set_aabb`; defaults to the original's unused ``bounds=1.6`` cube).
        spatial_init: ``(a, b)`` of the uniform init of spatial planes.
    """

    def __init__(
        self,
        resolution: Sequence[int] = (64, 64, 64, 25),
        feature_dim: int = 32,
        multires: Sequence[int] = (1, 2),
        aabb_min: Sequence[float] = (-1.6,) * 3,
        aabb_max: Sequence[float] = (1.6,) * 3,
        spatial_init: tuple[float, float] = (0.1, 0.5),
    ) -> None:
        super().__init__()
        if len(resolution) != 4 or min(resolution) < 2:
            raise ValueError(f"resolution must be 4 ints >= 2 (x, y, z, t), got {list(resolution)}")
        if not multires:
            raise ValueError("multires must name at least one scale")
        self.resolution, self.feature_dim, self.multires = tuple(resolution), feature_dim, tuple(multires)
        self.register_buffer("aabb", torch.zeros(2, 3))
        self.set_aabb(torch.as_tensor(aabb_min), torch.as_tensor(aabb_max))
        self.scales = nn.ModuleList()
        for m in self.multires:
            res = [r * m for r in self.resolution[:3]] + [self.resolution[3]]
            planes = nn.ParameterList()
            for a, b in COMBINATIONS:
                plane = torch.empty(1, feature_dim, res[b], res[a])
                if b == 3:
                    nn.init.ones_(plane)
                else:
                    nn.init.uniform_(plane, *spatial_init)
                planes.append(nn.Parameter(plane))
            self.scales.append(planes)

    @property
    def out_dim(self) -> int:
        return self.feature_dim * len(self.multires)

    def set_aabb(self, xyz_min: Tensor, xyz_max: Tensor) -> None:
        """Store the box as the original ``[max, min]`` (see :func:`normalize_aabb`)."""
        xyz_min, xyz_max = torch.as_tensor(xyz_min).float(), torch.as_tensor(xyz_max).float()
        if xyz_min.shape != (3,) or xyz_max.shape != (3,) or not bool((xyz_max > xyz_min).all()):
            raise ValueError(f"set_aabb needs min < max, each [3]; got {xyz_min.tolist()} {xyz_max.tolist()}")
        self.aabb.copy_(torch.stack([xyz_max, xyz_min]).to(self.aabb.device))

    def planes(self, kind: str = "all") -> list[Tensor]:
        """All planes of every scale, or only ``"space"`` (xy, xz, yz) / ``"time"`` (xt, yt, zt) ones."""
        index = {"all": range(6), "space": SPATIAL_PLANES, "time": TIME_PLANES}[kind]
        return [planes[k] for planes in self.scales for k in index]

    def forward(self, xyz: Tensor, t: Tensor) -> Tensor:
        """``xyz [N, 3]`` world, ``t [N, 1]`` in [0, 1] (used raw) -> ``[N, C * len(multires)]``."""
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"HexPlane xyz must have shape [N, 3], got {list(xyz.shape)}")
        if t.shape != (xyz.shape[0], 1):
            raise ValueError(f"HexPlane t must have shape [{xyz.shape[0]}, 1], got {list(t.shape)}")
        pts = torch.cat([normalize_aabb(xyz, self.aabb), t.to(xyz.dtype)], dim=-1)  # [N, 4]
        features = []
        for planes in self.scales:
            product = None
            for plane, (a, b) in zip(planes, COMBINATIONS, strict=True):
                f = sample_plane(plane, pts[:, [a, b]])
                product = f if product is None else product * f
            features.append(product)
        return torch.cat(features, dim=-1)

    def space_smoothness(self) -> Tensor:
        """``Ls``: sum of :func:`plane_smoothness` over the spatial planes of every scale."""
        return torch.stack([plane_smoothness(p) for p in self.planes("space")]).sum()

    def time_smoothness(self) -> Tensor:
        """``Lt``: sum of :func:`plane_smoothness` (along t) over the time planes of every scale."""
        return torch.stack([plane_smoothness(p) for p in self.planes("time")]).sum()

    def time_l1(self) -> Tensor:
        """``L1t``: sum over the time planes of ``mean |1 - plane|``."""
        return torch.stack([(1.0 - p).abs().mean() for p in self.planes("time")]).sum()

    def extra_repr(self) -> str:
        return f"resolution={self.resolution}, feature_dim={self.feature_dim}, multires={self.multires}"
