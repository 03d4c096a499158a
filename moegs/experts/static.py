"""Static 3DGS (Kerbl et al. 2023) trained on every frame: the no-deformation baseline.

One set of Gaussians answers every time ``t``; it is what a deformable expert must beat. Learning
rates, initialisation and densification are those of graphdeco 3DGS as the dynamic methods vendor it
(``arguments/__init__.py``, ``scene/gaussian_model.py``; ``specs/experts_canonical.md`` section 0):
``opacity_lr`` 0.05 as in DeformableGS :89, 4DGaussians :127, Grid4D :119 and 3dgs-mcmc :81;
graphdeco's 2024 releases halve it to 0.025.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch

from moegs.camera import Camera
from moegs.data.scene import PointCloud, Scene
from moegs.experts.base import QUICK_ITERATIONS, DatasetPreset, Expert, ExpertConfig, splat_param_groups
from moegs.experts.gaussian_params import activate, active_sh_degree, init_splats
from moegs.gaussians import GaussianFrame
from moegs.train.config import TrainConfig
from moegs.train.params import ParamGroup
from moegs.train.strategy import ADCStrategy, Strategy

QUICK_POINTS = (
    5000  # quick presets: at most 5k initial points (D-NeRF's 100k random points; CPU rasterizer cost)
)


QUICK_DENSIFY = {  # quick: 3DGS ADC 500-15k every 100, reset every 3000 -> 100-450 every 100, reset at 300
    "strategy.densify_from": 100,
    "strategy.densify_until": 450,
    # the original interval: every 50 grew 15-35k Gaussians on a 128x96 stand-in (2 per pixel, the originals
    # ~0.1) for the same dynamic-region PSNR (static 15.8 vs 15.9 dB, Grid4D 18.8 vs 18.7) at twice the cost
    "strategy.densify_every": 100,
    "strategy.reset_every": 300,
}


@dataclass
class StaticConfig(ExpertConfig):
    """3DGS hyperparameters (defaults: graphdeco 3DGS ``OptimizationParams``)."""

    sh_degree: int = 3
    """Maximum SH degree; the active degree grows by one every 1000 iterations."""
    init_opacity: float = 0.1
    """Initial opacity (3DGS ``inverse_sigmoid(0.1)``)."""
    init_scale: float = 1.0
    """Multiplier of the 3-NN initial scale (3DGS 1.0)."""
    max_init_points: int | None = None
    """Keep at most this many of the scene's initial points (random subset, ``train.seed``); None: all."""
    spatial_lr_scale: float | None = None
    """Multiplier of the position learning rates; None = the scene extent (3DGS ``cameras_extent``)."""
    means_lr: float = 1.6e-4
    """Initial position learning rate (``position_lr_init``), times ``spatial_lr_scale``."""
    means_lr_final: float = 1.6e-6
    """Final position learning rate (``position_lr_final``), times ``spatial_lr_scale``."""
    means_lr_max_steps: int = 30_000
    """Iterations of the exponential decay (``position_lr_max_steps``)."""
    sh0_lr: float = 2.5e-3
    """SH DC learning rate (``feature_lr``)."""
    shN_lr: float = 2.5e-3 / 20
    """Higher SH bands (``feature_lr / 20``)."""
    opacities_lr: float = 0.05
    """Opacity logit learning rate (``opacity_lr``)."""
    scales_lr: float = 5e-3
    """Log-scale learning rate (``scaling_lr``)."""
    quats_lr: float = 1e-3
    """Quaternion learning rate (``rotation_lr``)."""
    strategy: Strategy = field(default_factory=ADCStrategy)
    """Densification (3DGS adaptive density control)."""
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=30_000, lambda_dssim=0.2))

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "*": DatasetPreset("paper", "graphdeco 3DGS arguments/__init__.py: one recipe for every dataset")
    }
    BACKGROUNDS: ClassVar[dict[str, str]] = {"dnerf": "white", "*": "black"}
    """3DGS trains Blender-synthetic scenes with ``-w`` (README), real captures on black."""

    @classmethod
    def quick_fields(cls, paper: StaticConfig) -> dict[str, Any]:
        """CPU minutes: 600 iterations, 5k initial points, 1/8 resolution, ADC compressed to the short run."""
        return {
            "max_init_points": QUICK_POINTS,
            "means_lr_max_steps": QUICK_ITERATIONS,  # decay over the whole short run, as 3DGS over 30k
            **QUICK_DENSIFY,
        }


def scene_points(scene: Scene) -> PointCloud:
    """The scene's initial points, or ``ValueError`` saying how to get some."""
    if scene.points is None:
        raise ValueError(
            f"scene {scene.name!r} has no initial points; load it with points "
            "(e.g. D-NeRF num_points > 0) or build them with moegs.data.points"
        )
    return scene.points


def thin_points(points: PointCloud, max_points: int | None, seed: int) -> PointCloud:
    """A random subset of at most ``max_points`` points (all when None), in the original order."""
    if max_points is None or len(points) <= max_points:
        return points
    g = torch.Generator().manual_seed(seed)
    keep = torch.randperm(len(points), generator=g)[:max_points].sort().values
    times = points.times[keep] if points.times is not None else None
    return PointCloud(points.xyz[keep], points.rgb[keep], f"{points.source}, {max_points} kept", times)


class StaticExpert(Expert):
    """One static 3DGS model for all times."""

    name = "static"
    config_class = StaticConfig

    def __init__(self, config: StaticConfig, splats, spatial_lr_scale: float) -> None:
        super().__init__(config, splats)
        self.spatial_lr_scale = spatial_lr_scale
        self.active_sh_degree = 0

    @classmethod
    def from_scene(cls, scene: Scene, config: StaticConfig) -> StaticExpert:
        points = thin_points(scene_points(scene), config.max_init_points, config.train.seed)
        splats = init_splats(points, config.sh_degree, config.init_opacity, config.init_scale)
        scale = config.spatial_lr_scale if config.spatial_lr_scale is not None else scene.extent
        return cls(config, splats, scale)

    def on_step(self, step: int) -> bool:
        self.active_sh_degree = active_sh_degree(
            step, self.config.sh_degree, self.config.train.sh_degree_interval
        )
        return False

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        return activate(self.splats, self.active_sh_degree)

    def splat_inputs_key(self, camera: Camera) -> float:
        """3DGS and the canonical-space deformation experts (SH colours, fields of ``t`` only): the
        inputs depend on the camera only through its time."""
        return camera.time

    def param_groups(self) -> list[ParamGroup]:
        c, s = self.config, self.spatial_lr_scale
        constant = [
            ("sh0", c.sh0_lr),
            ("shN", c.shN_lr),
            ("opacities", c.opacities_lr),
            ("scales", c.scales_lr),
            ("quats", c.quats_lr),
        ]
        return splat_param_groups(self.splats, c, s, constant)

    def strategy(self) -> Strategy:
        return self.config.strategy
