"""Deformable 3D Gaussians (Yang et al., CVPR 2024): an MLP on PE(x), PE(t) deforms canonical 3DGS.

Facts from ``ingra14m/Deformable-3D-Gaussians`` (``utils/time_utils.py``, ``scene/deform_model.py``,
``gaussian_renderer/__init__.py``, ``train.py``, ``arguments/__init__.py``;
``specs/experts_canonical.md`` §4):

* input: canonical xyz, **detached**, NeRF PE with 10 frequencies (63 dims); t with 6 frequencies on
  Blender/D-NeRF (13 dims, then ``timenet`` Linear(13, 256)-ReLU-Linear(256, 30)) or 10 elsewhere (21 dims);
* 8 x 256 ReLU MLP, the input concatenated again after layer 4; linear heads dx 3, drot 4, dscale 3
  (PyTorch default init, so the deltas are small but not zero at the start);
* deltas in **activated** space: ``x' = x + dx``, ``s' = exp(s) + ds``, ``q' = normalize(q) + dr`` (not
  renormalised; the rasterizer uses the quaternion as given, like the 3DGS CUDA kernel);
* static warm-up: no deformation for iterations ``< warm_up`` (3000);
* annealed smooth training (AST, real data only): ``t += N(0, 1) / n * 0.1 (1 - step / 20000)``, one draw per
  iteration shared by all Gaussians;
* loss 0.8 L1 + 0.2 D-SSIM, 40k iterations, ``spatial_lr_scale`` hard-coded to 5 (it also multiplies the
  scaling lr: 5e-3), deformation Adam lr ``8e-4 -> 1.6e-6`` over 40k, black background on every dataset
  (no ``-w`` in the README commands), 100k random initial points on D-NeRF.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene
from moegs.experts.base import QUICK_ITERATIONS, DatasetPreset
from moegs.experts.canonical import QUICK_STATIC_ITERATIONS, DeformingExpert
from moegs.experts.gaussian_params import activate
from moegs.experts.static import QUICK_DENSIFY, QUICK_POINTS, StaticConfig
from moegs.fields import Heads, PositionalEncoding, SkipMLP, mlp
from moegs.gaussians import GaussianFrame
from moegs.train.config import TrainConfig
from moegs.train.params import ParamGroup
from moegs.train.strategy import ADCStrategy, Strategy


class DeformableField(nn.Module):
    """``(xyz [N, 3], t [N, 1]) -> {"dx" [N, 3], "drot" [N, 4], "dscale" [N, 3]}``.

    Args:
        xyz_freqs, time_freqs: PE frequencies of xyz and t.
        timenet_out: width of the Blender ``timenet`` output (None: PE(t) goes to the MLP directly).
        timenet_width: hidden width of ``timenet``.
        depth, width, skips: the trunk (:class:`~moegs.fields.SkipMLP`).
    """

    def __init__(
        self,
        xyz_freqs: int = 10,
        time_freqs: int = 6,
        timenet_out: int | None = 30,
        timenet_width: int = 256,
        depth: int = 8,
        width: int = 256,
        skips: tuple[int, ...] = (4,),
    ) -> None:
        super().__init__()
        self.pe_xyz = PositionalEncoding(3, xyz_freqs)
        self.pe_time = PositionalEncoding(1, time_freqs)
        self.timenet = mlp([self.pe_time.out_dim, timenet_width, timenet_out]) if timenet_out else None
        time_dim = timenet_out or self.pe_time.out_dim
        self.trunk = SkipMLP(self.pe_xyz.out_dim + time_dim, width, depth, skips)
        self.heads = Heads(width, {"dx": 3, "drot": 4, "dscale": 3})

    def forward(self, xyz: Tensor, t: Tensor) -> dict[str, Tensor]:
        if xyz.ndim != 2 or xyz.shape[1] != 3 or t.shape != (xyz.shape[0], 1):
            raise ValueError(
                f"DeformableField expects xyz [N, 3] and t [N, 1], got {list(xyz.shape)}, {list(t.shape)}"
            )
        t_emb = self.pe_time(t)
        if self.timenet is not None:
            t_emb = self.timenet(t_emb)
        return self.heads(self.trunk(torch.cat([self.pe_xyz(xyz), t_emb], dim=-1)))


def ast_scale(step: int, initial: float = 0.1, steps: int = 20_000) -> float:
    """AST noise multiplier: linear from ``initial`` to 0 over ``steps`` (original: to 1e-15), then 0."""
    return initial * max(0.0, 1.0 - step / steps)


@dataclass
class DeformableConfig(StaticConfig):
    """DeformableGS hyperparameters; defaults are the D-NeRF (``--is_blender``) protocol.

    Inherited 3DGS fields keep the original values except where set below.
    """

    xyz_freqs: int = 10
    """PE frequencies of xyz (``multires``)."""
    time_freqs: int = 6
    """PE frequencies of t: 6 with ``--is_blender`` (D-NeRF), 10 otherwise."""
    timenet_out: int | None = 30
    """Blender ``timenet`` output width (Linear(13, 256)-ReLU-Linear(256, 30)); None on real data."""
    timenet_width: int = 256
    """Hidden width of ``timenet``."""
    depth: int = 8
    """Trunk layers (``D``)."""
    width: int = 256
    """Trunk width (``W``)."""
    skips: tuple[int, ...] = (4,)
    """The input is concatenated again after these layers (``D // 2``)."""
    warm_up: int = 3000
    """Iterations ``< warm_up`` render the canonical Gaussians without deformation."""
    time_noise: bool = False
    """Annealed smooth training (AST): only on real data (not ``--is_blender``)."""
    time_noise_scale: float = 0.1
    """AST multiplier at step 0 (``get_linear_noise_func(lr_init=0.1)``)."""
    time_noise_steps: int = 20_000
    """AST multiplier reaches 0 here (``max_steps=20000``)."""
    time_noise_over_left: bool = True
    """AST's time step is 1 / the views left in the epoch's camera stack, as ``train.py:79-85`` computes
    ``total_frame = len(viewpoint_stack)`` before each pop (from 1/n up to 1/1 through an epoch); False:
    1 / all training views."""
    deform_lr: float = 1.6e-4
    """Deformation MLP initial lr, times ``spatial_lr_scale`` (``position_lr_init * 5`` = 8e-4)."""
    deform_lr_final: float = 1.6e-6
    """Deformation MLP final lr, **not** scaled (``position_lr_final``)."""
    deform_lr_max_steps: int = 40_000
    """Decay length of the deformation lr (``deform_lr_max_steps``)."""
    lr_delay_mult: float = 0.01
    """``position_lr_delay_mult``; inactive because the original never sets delay steps."""
    spatial_lr_scale: float | None = 5.0
    """Hard-coded 5 in ``GaussianModel`` and ``DeformModel`` (the scene extent is ignored)."""
    scales_lr: float = 5e-3
    """``scaling_lr`` 0.001 (``arguments/__init__.py:90``) times ``spatial_lr_scale`` 5
    (set at ``scene/gaussian_model.py:117``, applied at ``:124``)."""
    strategy: Strategy = field(default_factory=ADCStrategy)
    """Densification of the ``paper`` branch (vanilla ‖∂L/∂μ2D‖, τ 2e-4, 500-15k every 100, reset 3000);
    the ``main`` branch's AbsGS gradient (τ 7e-4) is not reproduced."""
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=40_000, lambda_dssim=0.2))

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "dnerf": DatasetPreset("paper-dnerf", "arguments/__init__.py; README.md:83 (--is_blender)"),
        "hypernerf": DatasetPreset(
            "paper-hypernerf", "arguments/__init__.py; README.md:89 (--iterations 20000)"
        ),
        "n3v": DatasetPreset(
            "paper-n3v",
            "adaptation: the original reads 24 frames per N3V camera (scene/__init__.py:58) "
            "and has no N3V command; real-data path on the full sequence",
            adapted=True,
        ),
    }
    DEFAULT_PRESET: ClassVar[str] = "paper-n3v"
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "black"}
    """``_white_background = False`` (``arguments/__init__.py:57``) and no ``-w`` in the README."""

    DEFAULT_DATASET: ClassVar[str | None] = "dnerf"

    @classmethod
    def paper_hypernerf(cls) -> DeformableConfig:
        """HyperNeRF / NeRF-DS: real data (PE(t) 10, no timenet, AST), 20k iterations (README)."""
        return cls(
            time_freqs=10,
            timenet_out=None,
            time_noise=True,
            train=TrainConfig(iterations=20_000, lambda_dssim=0.2),
        )

    @classmethod
    def paper_n3v(cls) -> DeformableConfig:
        """N3V as real data with the 40k default; the original reads only 24 frames per camera, MoE-GS's
        N3V DeformableGS is an adaptation on the full sequence (``specs/experts_canonical.md`` §4.3)."""
        return cls(time_freqs=10, timenet_out=None, time_noise=True)

    @classmethod
    def quick_fields(cls, paper: DeformableConfig) -> dict[str, Any]:
        """CPU minutes on 100x100 D-NeRF: the static baseline's budget (600 iterations, 5k points)."""
        return {
            "max_init_points": QUICK_POINTS,
            "width": 64,  # trunk width 256 -> 64 (CPU cost; depth, skip and heads unchanged)
            "warm_up": QUICK_STATIC_ITERATIONS,  # 3000 of 40k -> 150 of 600
            "time_noise_steps": QUICK_ITERATIONS // 2,  # AST anneals over half the run (20k of 40k)
            "means_lr_max_steps": QUICK_ITERATIONS,  # the canonical xyz decay spans the short run
            # deform_lr_max_steps stays 40k: a 600-step decay starves the MLP (measured 22.3 vs 26.7 dB)
            **QUICK_DENSIFY,
        }


class DeformableExpert(DeformingExpert):
    """Canonical 3DGS + :class:`DeformableField`; ``fields`` is the deformation network."""

    name = "deformable"
    config_class = DeformableConfig

    def __init__(
        self,
        config: DeformableConfig,
        splats: nn.ParameterDict,
        spatial_lr_scale: float,
        time_interval: float,
    ) -> None:
        super().__init__(config, splats, spatial_lr_scale)
        self.fields = DeformableField(
            config.xyz_freqs,
            config.time_freqs,
            config.timenet_out,
            config.timenet_width,
            config.depth,
            config.width,
            config.skips,
        )
        self.time_interval = time_interval

    @classmethod
    def from_scene(cls, scene: Scene, config: DeformableConfig) -> DeformableExpert:
        splats, scale = cls.canonical(scene, config)
        return cls(config, splats, scale, time_interval=1.0 / len(scene.train))

    def on_views(self, left: int) -> None:
        """AST over the shrinking camera stack (``time_noise_over_left``)."""
        if self.config.time_noise_over_left and left > 0:
            self.time_interval = 1.0 / left

    @property
    def deforming(self) -> bool:
        return self.step >= self.config.warm_up

    def deltas(self, t: float) -> dict[str, Tensor]:
        """Network outputs for every Gaussian at time ``t`` (with AST noise while training)."""
        xyz, time, c = self.splats["means"].detach(), self.time_column(t), self.config
        if c.time_noise and self.training and torch.is_grad_enabled():
            noise = torch.randn((), device=xyz.device) * self.time_interval
            time = time + noise * ast_scale(self.step, c.time_noise_scale, c.time_noise_steps)
        return self.fields(xyz, time)

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        if not self.deforming:
            return activate(self.splats, self.active_sh_degree)
        d = self.deltas(t)
        return activate(
            self.splats,
            self.active_sh_degree,
            means=self.splats["means"] + d["dx"],
            scales=torch.exp(self.splats["scales"]) + d["dscale"],
            quats=nn.functional.normalize(self.splats["quats"], dim=-1) + d["drot"],
        )

    def param_groups(self) -> list[ParamGroup]:
        c = self.config
        return [
            *super().param_groups(),
            ParamGroup(
                "deform",
                list(self.fields.parameters()),
                c.deform_lr * self.spatial_lr_scale,
                lr_final=c.deform_lr_final,
                lr_delay_mult=c.lr_delay_mult,
                max_steps=c.deform_lr_max_steps,
            ),
        ]


__all__ = ["DeformableConfig", "DeformableExpert", "DeformableField", "ast_scale"]
