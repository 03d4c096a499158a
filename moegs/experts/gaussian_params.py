"""Per-Gaussian 3DGS parameters shared by every expert: initialisation, activation, SH schedule.

Raw (optimised) parameters, all with leading dimension ``N`` (the keys of ``Expert.splats``):

=============  ===========  =====================================================================
key            shape        meaning (activation)
=============  ===========  =====================================================================
``means``      ``[N, 3]``   centres (identity)
``scales``     ``[N, 3]``   log standard deviations (``exp``)
``quats``      ``[N, 4]``   raw quaternions, w first (``normalize``)
``opacities``  ``[N]``      opacity logits (``sigmoid``)
``sh0``        ``[N, 1, 3]`` SH DC coefficient, ``(rgb - 0.5) / C0``
``shN``        ``[N, K, 3]`` higher SH bands, ``K = (degree + 1)² - 1`` (zeros at init)
=============  ===========  =====================================================================

Initialisation follows 3DGS ``create_from_pcd`` (``specs/experts_canonical.md`` section 0):
scale = √(mean squared distance to the 3 nearest neighbours) (``simple_knn.distCUDA2``, floored at
1e-7 before the square root), identity rotation, opacity ``logit(0.1)``, DC from the point colours.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor, nn

from moegs.data.points import initial_scales
from moegs.data.scene import PointCloud
from moegs.gaussians import GaussianFrame
from moegs.render.projection import rgb_to_sh0

SPLAT_KEYS = ("means", "scales", "quats", "opacities", "sh0", "shN")


def num_sh_bases(degree: int) -> int:
    return (degree + 1) ** 2


def init_splats(
    points: PointCloud,
    sh_degree: int = 3,
    init_opacity: float = 0.1,
    init_scale: float = 1.0,
    extra: dict[str, Tensor] | None = None,
) -> nn.ParameterDict:
    """3DGS parameters initialised from a point cloud.

    Args:
        points: ``P`` points with colours.
        sh_degree: maximum SH degree (``shN`` holds ``(sh_degree + 1)² - 1`` bands).
        init_opacity: initial opacity in (0, 1) (3DGS 0.1; 3DGS-MCMC 0.5).
        init_scale: multiplier of the 3-NN scale (3DGS 1.0; 3DGS-MCMC / gsplat ``mcmc`` 0.1).
        extra: further per-Gaussian tensors ``[P, ...]`` (e.g. embeddings), added as parameters.

    Returns:
        ``ParameterDict`` with the keys of ``SPLAT_KEYS`` plus those of ``extra``.
    """
    if not 0.0 < init_opacity < 1.0:
        raise ValueError(f"init_opacity must be in (0, 1), got {init_opacity}")
    if init_scale <= 0:
        raise ValueError(f"init_scale must be positive, got {init_scale}")
    if len(points) < 2:
        raise ValueError(
            f"init_splats needs at least 2 points for the nearest-neighbour scale, got {len(points)}"
        )
    xyz = points.xyz.to(torch.float32)
    n = xyz.shape[0]
    params = {
        "means": xyz.clone(),
        "scales": initial_scales(xyz) + math.log(init_scale),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
        "opacities": torch.logit(torch.full((n,), init_opacity)),
        "sh0": rgb_to_sh0(points.rgb.to(torch.float32))[:, None, :],
        "shN": torch.zeros(n, num_sh_bases(sh_degree) - 1, 3),
    }
    for name, value in (extra or {}).items():
        if name in params:
            raise ValueError(f"extra parameter {name!r} collides with a 3DGS parameter; rename it")
        if value.shape[0] != n:
            raise ValueError(f"extra parameter {name!r} must have leading dim {n}, got {list(value.shape)}")
        params[name] = value
    return nn.ParameterDict({k: nn.Parameter(v) for k, v in params.items()})


def sh_coeffs(splats: Mapping[str, Tensor], active_sh_degree: int) -> Tensor:
    """``[N, (active_sh_degree + 1)², 3]``: DC and the active higher bands."""
    max_degree = int(round((1 + splats["shN"].shape[1]) ** 0.5)) - 1
    if not 0 <= active_sh_degree <= max_degree:
        raise ValueError(f"active_sh_degree must be in 0..{max_degree}, got {active_sh_degree}")
    return torch.cat([splats["sh0"], splats["shN"][:, : num_sh_bases(active_sh_degree) - 1]], dim=1)


def activate(splats: Mapping[str, Tensor], active_sh_degree: int, **overrides: Tensor) -> GaussianFrame:
    """The activated ``GaussianFrame`` of raw 3DGS parameters.

    ``overrides`` replace activated fields (``means``, ``quats``, ``scales``, ``opacities``, ``sh``) with
    values an expert computed itself (e.g. deformed means), skipping their activation.
    """
    unknown = set(overrides) - {"means", "quats", "scales", "opacities", "sh"}
    if unknown:
        raise ValueError(f"activate() got unknown overrides {sorted(unknown)}")

    def field(name, make):
        return overrides[name] if name in overrides else make()

    return GaussianFrame(
        means=field("means", lambda: splats["means"]),
        quats=field("quats", lambda: nn.functional.normalize(splats["quats"], dim=-1)),
        scales=field("scales", lambda: torch.exp(splats["scales"])),
        opacities=field("opacities", lambda: torch.sigmoid(splats["opacities"])),
        sh=field("sh", lambda: sh_coeffs(splats, active_sh_degree)),
    )


def active_sh_degree(step: int, max_degree: int, interval: int) -> int:
    """SH degree used at 1-based iteration ``step``: +1 every ``interval`` iterations (3DGS: 1000,
    ``TrainConfig.sh_degree_interval``), at most ``max_degree``."""
    return min(max_degree, step // interval)
