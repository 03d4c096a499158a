"""Shared pieces of the canonical-space deformation experts (DeformableGS, Grid4D, 4DGaussians).

Each keeps 3DGS Gaussians in a canonical space (the ``static`` expert's parameters, learning rates and
densification) and adds a deformation field queried at time ``t``; for a first, static phase the
canonical Gaussians are rendered as they are.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene
from moegs.experts.base import QUICK_ITERATIONS
from moegs.experts.gaussian_params import init_splats
from moegs.experts.static import StaticConfig, StaticExpert, scene_points, thin_points
from moegs.gaussians import GaussianFrame

QUICK_STATIC_ITERATIONS = (
    QUICK_ITERATIONS // 4
)  # quick: the 3000-iteration static phase -> a quarter of the short run


class DeformingExpert(StaticExpert):
    """A static 3DGS expert whose ``frame`` deforms the canonical Gaussians once ``deforming``."""

    def __init__(self, config: StaticConfig, splats: nn.ParameterDict, spatial_lr_scale: float) -> None:
        super().__init__(config, splats, spatial_lr_scale)
        self.step = 0

    @staticmethod
    def canonical(scene: Scene, config: StaticConfig) -> tuple[nn.ParameterDict, float]:
        """Canonical Gaussians from the scene's points and the position lr scale (extent when None)."""
        points = thin_points(scene_points(scene), config.max_init_points, config.train.seed)
        splats = init_splats(points, config.sh_degree, config.init_opacity, config.init_scale)
        scale = config.spatial_lr_scale if config.spatial_lr_scale is not None else scene.extent
        return splats, scale

    @property
    def deforming(self) -> bool:
        """Whether the deformation field acts at the current step."""
        raise NotImplementedError

    def on_step(self, step: int) -> bool:
        self.step = step
        return super().on_step(step)

    def time_column(self, t: float, like: Tensor | None = None) -> Tensor:
        """``[N, 1]`` filled with ``t`` for the ``N`` rows of ``like`` (default: the canonical means)."""
        like = self.splats["means"] if like is None else like
        return torch.full((like.shape[0], 1), float(t), dtype=like.dtype, device=like.device)

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        return self.deform(self.splats, t, camera)

    def deform(
        self, splats: Mapping[str, Tensor], t: float, camera: Camera | None = None, raw_quats: bool = False
    ) -> GaussianFrame:
        """The activated Gaussians at ``t`` of the canonical parameters ``splats`` (this expert's own, or
        those MoDE shares between deformation experts) under this expert's deformation field.
        ``raw_quats``: leave the deformed quaternions as the original computes them before its rasterizer
        normalises them (MoDE mixes those)."""
        raise NotImplementedError
