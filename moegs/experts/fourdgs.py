"""4D Gaussian Splatting (Wu et al., CVPR 2024): HexPlane features + a small MLP with deformation heads.

Facts from ``hustvl/4DGaussians`` (``scene/deformation.py``, ``scene/hexplane.py``, ``train.py``,
``arguments/``; ``specs/experts_canonical.md`` §1):

* field: :class:`~moegs.fields.HexPlane` over (canonical xyz, **not** detached; raw t), then
  ``feature_out`` = Linear(C |multires|, W) (+ (ReLU, Linear(W, W)) per extra depth), then heads
  ``ReLU-Linear(W, W)-ReLU-Linear(W, out)``: dx 3, ds 3, dr 4 (+ do 1, dSH 48 on N3V); Xavier weights;
* deltas in **raw** space: ``x' = x + dx``, ``s' = exp(s + ds)``, ``q' = normalize(q + dr)``,
  ``o' = sigmoid(o + do)``, ``SH' = SH + dSH``;
* two stages: ``coarse_iterations`` (3000) of static 3DGS, then the fine stage with fresh optimisers, a
  restarted counter (every schedule, densification statistic and opacity reset restarts) and the grid
  regularisers ``plane_tv Ls + time_smoothness Lt + l1_time L1t``;
* L1 loss only, white background, ``spatial_lr_scale`` = scene extent on xyz, MLP and grid rates;
* densification only while N < 360k; low-opacity pruning a separate step every ``pruning_interval``,
  only while N > 200k (small scenes never prune); D-NeRF init = 2000 random points.

Left out (dead code in the original): ``timenet``, the PE buffers, ``static_mlp``, ``empty_voxel``; the
heads of switched-off outputs (``no_do`` / ``no_dshs``) are not built, so they hold no parameters.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene
from moegs.experts.base import QUICK_ITERATIONS, DatasetPreset
from moegs.experts.canonical import QUICK_STATIC_ITERATIONS, DeformingExpert
from moegs.experts.gaussian_params import activate, num_sh_bases, sh_coeffs
from moegs.experts.static import QUICK_POINTS, StaticConfig
from moegs.fields import Heads, HexPlane, mlp, xavier_weights_
from moegs.gaussians import GaussianFrame
from moegs.train.config import TrainConfig
from moegs.train.params import ParamGroup
from moegs.train.strategy import NEVER, ADCStrategy, ops

SH_COEFFS = num_sh_bases(3)  # the dSH head always predicts all 16 bands x RGB


class FourDGSField(nn.Module):
    """``(xyz [N, 3], t [N, 1]) -> {"dx" [N, 3], "ds" [N, 3], "dr" [N, 4], ("do" [N, 1], "dsh" [N, 48])}``."""

    def __init__(
        self,
        hexplane: HexPlane,
        width: int = 64,
        depth: int = 0,
        deform_opacity: bool = False,
        deform_sh: bool = False,
    ) -> None:
        super().__init__()
        self.grid = hexplane
        self.feature_out = mlp([hexplane.out_dim] + [width] * max(1, depth))
        outputs = {"dx": 3, "ds": 3, "dr": 4}
        if deform_opacity:
            outputs["do"] = 1
        if deform_sh:
            outputs["dsh"] = SH_COEFFS * 3
        self.heads = Heads(width, outputs, hidden=(width,), relu_first=True)
        xavier_weights_(self.feature_out)
        xavier_weights_(self.heads)

    def mlp_parameters(self) -> list[nn.Parameter]:
        return [*self.feature_out.parameters(), *self.heads.parameters()]

    def forward(self, xyz: Tensor, t: Tensor) -> dict[str, Tensor]:
        return self.heads(self.feature_out(self.grid(xyz, t)))


@dataclass
class FourDGSStrategy(ADCStrategy):
    """4DGaussians' densification: 3DGS clone/split and a separate prune step, gated by N, on a counter
    that restarts with the fine stage. Per-view screen gradients of a batch are summed before the norm
    (``train.py:195-196, 223-225, 262``)."""

    batch_stats: str = "summed"

    coarse_iterations: int = 3000
    """Length of the coarse stage; the fine stage restarts every counter below at 1."""
    prune_from: int = 500
    """Prune only when the stage step ``> prune_from`` (``pruning_from_iter``)."""
    prune_every: int = 100
    """... and ``% prune_every == 0`` (``pruning_interval``: D-NeRF 8000)."""
    densify_below: int = 360_000
    """Densify only while N < this."""
    prune_above: int = 200_000
    """Prune only while N > this."""
    prune_screen_size: float | None = 20.0
    """After the first reset interval prune max screen radius > 20 px (fires here: ``prune`` is separate)."""
    reset_at_densify_from_if_white: bool = False
    """4DGaussians has no extra reset at ``densify_from`` with a white background."""

    @staticmethod
    def _count(params) -> int:
        return params["means"].shape[0]

    def stage_step(self, step: int) -> int:
        """The iteration counter of the current stage (1-based; restarts after ``coarse_iterations``)."""
        return step - self.coarse_iterations if step > self.coarse_iterations else step

    @torch.no_grad()
    def _densify(self, params, optimizers, state: dict) -> None:
        extent = state["scene_scale"]
        grads = state["grad2d"] / state["count"].clamp(min=1)
        small = torch.exp(params["scales"]).max(dim=1).values <= self.percent_dense * extent
        candidates = grads >= self.grad_threshold
        clone, to_split = candidates & small, candidates & ~small
        ops.duplicate(params, optimizers, clone)
        cloned = int(clone.sum())
        to_split = torch.cat([to_split, to_split.new_zeros(cloned)])
        ops.split(params, optimizers, to_split, self.split_samples, self.split_scale_divisor)
        self._reset_stats(state, params["means"].shape[0], params["means"].detach())
        state["last_refine"] = {"clone": cloned, "split": int(to_split.sum()), "prune": 0}

    @torch.no_grad()
    def _prune(self, params, optimizers, state: dict, stage_step: int) -> None:
        prune = torch.sigmoid(params["opacities"]) < self.prune_opacity
        if stage_step > self.reset_every:
            if self.prune_world_scale is not None:
                world = torch.exp(params["scales"]).max(dim=1).values
                prune |= world > self.prune_world_scale * state["scene_scale"]
            if self.prune_screen_size is not None:
                prune |= state["max_radii"] > self.prune_screen_size
        self._remove_keeping_stats(params, optimizers, state, prune)
        state["last_refine"] = {"clone": 0, "split": 0, "prune": int(prune.sum())}

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        local = self.stage_step(step)
        if step == self.coarse_iterations + 1:
            state["grad2d"] = None  # fresh statistics for the fine stage
        if local >= self.densify_until:
            return
        self._update_stats(params, state, info)
        densify = self.densifies(local)
        if densify and self._count(params) < self.densify_below:
            self._densify(params, optimizers, state)
        prune = local > self.prune_from and local % self.prune_every == 0
        if prune and self._count(params) > self.prune_above:
            self._prune(params, optimizers, state, local)
        if local % self.reset_every == 0:
            ops.reset_opacity(params, optimizers, self.reset_value)


@dataclass
class FourDGSConfig(StaticConfig):
    """4DGaussians hyperparameters; defaults are the D-NeRF configs (``arguments/dnerf/dnerf_default.py``)."""

    max_init_points: int | None = 2000
    """D-NeRF: 2000 random points in [-1.3, 1.3]^3 (a random subset of the loader's uniform points)."""
    spatial_lr_scale: float | None = None
    """None: the scene extent (``cameras_extent``) scales the xyz, MLP and grid rates."""
    means_lr_max_steps: int = 20_000
    """``position_lr_max_steps``; also the decay length of the MLP and grid rates."""
    feature_dim: int = 32
    """HexPlane channels per plane (``output_coordinate_dim``)."""
    resolution: int = 64
    """Base spatial plane resolution (``kplanes_config.resolution[:3]``)."""
    time_resolution: int = 25
    """Temporal plane resolution (``kplanes_config.resolution[3]``): 25 by default, N3V / HyperNeRF 150,
    per-scene values in ``SCENE_OVERRIDES``."""
    multires: tuple[int, ...] = (1, 2)
    """Spatial resolution multipliers; features are concatenated over them."""
    width: int = 64
    """MLP width (``net_width``)."""
    depth: int = 0
    """``defor_depth``: 0 and 1 build the same net (one Linear before the heads)."""
    deform_opacity: bool = False
    """Deform opacity (``no_do=False``; N3V)."""
    deform_sh: bool = False
    """Deform the SH coefficients (``no_dshs=False``; N3V)."""
    coarse_iterations: int = 3000
    """Static 3DGS iterations before the deformation starts (included in ``train.iterations``)."""
    deformation_lr: float = 1.6e-4
    """MLP lr (``deformation_lr_init``), times ``spatial_lr_scale``."""
    deformation_lr_final: float = 1.6e-6
    """MLP final lr (D-NeRF 1.6e-6; default 1.6e-5), times ``spatial_lr_scale``."""
    grid_lr: float = 1.6e-3
    """HexPlane lr (``grid_lr_init``), times ``spatial_lr_scale``."""
    grid_lr_final: float = 1.6e-5
    """HexPlane final lr (D-NeRF 1.6e-5; default 1.6e-4), times ``spatial_lr_scale``."""
    lr_delay_mult: float = 0.01
    """``*_lr_delay_mult``; inactive because the original never sets delay steps."""
    plane_tv_weight: float = 1e-4
    """Weight of ``Ls`` (spatial-plane smoothness)."""
    time_smoothness_weight: float = 1e-2
    """Weight of ``Lt`` (temporal smoothness); 0 switches all three regularisers off, as the original."""
    l1_time_planes: float = 1e-4
    """Weight of ``L1t`` (time planes stay near 1)."""
    strategy: FourDGSStrategy = field(default_factory=lambda: FourDGSStrategy(prune_every=8000))
    """Densification: 500-15k every 100, τ 2e-4, reset every 3000, prune every 8000 (D-NeRF)."""
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=23_000, lambda_dssim=0.0))
    """Coarse + fine iterations, L1 only (``lambda_dssim = 0`` in every 4DGaussians config)."""

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "dnerf": DatasetPreset("paper-dnerf", "arguments/dnerf/dnerf_default.py over arguments/__init__.py"),
        "n3v": DatasetPreset("paper-n3v", "arguments/dynerf/default.py"),
        "hypernerf": DatasetPreset("paper-hypernerf", "arguments/hypernerf/default.py"),
    }
    DEFAULT_PRESET: ClassVar[str] = "paper-n3v"
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "white"}
    """``_white_background = True`` as a ``store_true`` flag: it cannot be switched off
    (``arguments/__init__.py``; ``train.py`` background)."""
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {
        "n3v": {
            "resample": "lanczos",  # scene/neural_3D_dataset_NDC.py:371 img.resize(..., Image.LANCZOS)
            "points": "mvs40k",  # scene/dataset_readers.py:444 points3D_downsample2.ply (README.md:151-153)
        },
    }
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {
        # kplanes temporal resolution (arguments/dnerf/<scene>.py:8, arguments/hypernerf/<scene>.py:7)
        "dnerf:lego": {"time_resolution": 25},
        "dnerf:hellwarrior": {"time_resolution": 50},
        "dnerf:hook": {"time_resolution": 50},
        "dnerf:bouncingballs": {"time_resolution": 75},
        "dnerf:mutant": {"time_resolution": 75},
        "dnerf:standup": {"time_resolution": 75},
        "dnerf:jumpingjacks": {"time_resolution": 100},
        "dnerf:trex": {"time_resolution": 100},
        "hypernerf:3dprinter": {"time_resolution": 100},
        "hypernerf:broom": {"time_resolution": 100},  # arguments/hypernerf/broom2.py:7
        "hypernerf:chicken": {"time_resolution": 80},
        "hypernerf:peel-banana": {"time_resolution": 250},  # arguments/hypernerf/banana.py:7
        # batch 4: the default of arguments/dynerf/default.py:25; the other scenes' files set 2
        "n3v:coffee_martini": {"train.batch_size": 4},
        "n3v:flame_salmon": {"train.batch_size": 4},
    }

    DEFAULT_DATASET: ClassVar[str | None] = "dnerf"

    @classmethod
    def paper_n3v(cls) -> FourDGSConfig:
        """``arguments/dynerf/default.py`` (batch 2; coffee_martini and flame_salmon_1 use 4)."""
        return cls(
            max_init_points=None,
            feature_dim=16,
            time_resolution=150,
            width=128,
            deform_opacity=True,
            deform_sh=True,
            deformation_lr_final=1.6e-5,
            grid_lr_final=1.6e-4,
            plane_tv_weight=2e-4,
            time_smoothness_weight=1e-3,
            strategy=FourDGSStrategy(densify_until=10_000, reset_every=60_000, prune_every=100),
            train=TrainConfig(iterations=3000 + 14_000, batch_size=2, lambda_dssim=0.0),
        )

    @classmethod
    def paper_hypernerf(cls) -> FourDGSConfig:
        """``arguments/hypernerf/default.py`` (per-scene T in ``TIME_RESOLUTION``, else 150)."""
        return cls(
            max_init_points=None,
            feature_dim=16,
            time_resolution=150,
            multires=(1, 2, 4),
            width=128,
            depth=1,
            deformation_lr_final=1.6e-5,
            grid_lr_final=1.6e-4,
            plane_tv_weight=2e-4,
            time_smoothness_weight=1e-3,
            strategy=FourDGSStrategy(densify_until=10_000, reset_every=300_000, prune_every=100),
            train=TrainConfig(iterations=3000 + 14_000, batch_size=2, lambda_dssim=0.0),
        )

    @classmethod
    def quick_fields(cls, paper: FourDGSConfig) -> dict[str, Any]:
        """CPU minutes on 100x100 D-NeRF: the static baseline's budget (coarse 150 + fine 450)."""
        coarse = QUICK_STATIC_ITERATIONS  # 3000 + 20000 -> 150 + 450
        return {
            "resolution": 32,  # planes 64 (x1, x2) -> 32 (x1, x2) for 100 px images
            "max_init_points": min(paper.max_init_points or QUICK_POINTS, QUICK_POINTS),  # MVS <= 40k -> 5k
            "coarse_iterations": coarse,
            "means_lr_max_steps": QUICK_ITERATIONS,  # the decays span a stage of the short run
            "strategy.coarse_iterations": coarse,
            "strategy.densify_from": 100,
            "strategy.densify_until": 450,
            # every 50, not the original 100: the short window then densifies 8 times, not 4; measured on
            # dnerf:mutant (quick, 600 it): 26.25 dB with 4220 Gaussians vs 24.30 dB with 2342 at every 100
            "strategy.densify_every": 50,
            # resets every 300 where the original resets at all (D-NeRF 3000; N3V/HyperNeRF: never)
            "strategy.reset_every": 300 if paper.strategy.reset_every < paper.train.iterations else NEVER,
            "strategy.prune_from": 100,
            "strategy.prune_every": 400,
            "train.batch_size": 1,  # N3V / HyperNeRF batch 2 (4) -> 1 (CPU cost; one view per step)
        }

    def __post_init__(self) -> None:
        if self.strategy.coarse_iterations != self.coarse_iterations:
            raise ValueError(
                f"FourDGSConfig: strategy.coarse_iterations ({self.strategy.coarse_iterations}) "
                f"must equal coarse_iterations ({self.coarse_iterations})"
            )


class FourDGSExpert(DeformingExpert):
    """Canonical 3DGS + :class:`FourDGSField`, coarse (static) then fine (deforming) stage."""

    name = "fourdgs"
    config_class = FourDGSConfig

    def __init__(
        self, config: FourDGSConfig, splats: nn.ParameterDict, spatial_lr_scale: float, time_resolution: int
    ) -> None:
        super().__init__(config, splats, spatial_lr_scale)
        c = config
        means = splats["means"].detach()
        hexplane = HexPlane(
            (c.resolution,) * 3 + (time_resolution,),
            c.feature_dim,
            c.multires,
            aabb_min=means.min(0).values,
            aabb_max=means.max(0).values,
        )
        self.fields = FourDGSField(hexplane, c.width, c.depth, c.deform_opacity, c.deform_sh)

    @classmethod
    def from_scene(cls, scene: Scene, config: FourDGSConfig) -> FourDGSExpert:
        splats, scale = cls.canonical(scene, config)
        return cls(config, splats, scale, config.time_resolution)

    @property
    def deforming(self) -> bool:
        """The fine stage: steps after ``coarse_iterations``."""
        return self.step > self.config.coarse_iterations

    def on_step(self, step: int) -> bool:
        super().on_step(step)
        return step == self.config.coarse_iterations + 1  # fine stage: fresh optimisers

    def deform(
        self, splats: Mapping[str, Tensor], t: float, camera: Camera | None = None, raw_quats: bool = False
    ) -> GaussianFrame:
        s = splats
        if not self.deforming:
            return activate(s, self.active_sh_degree)
        d = self.fields(s["means"], self.time_column(t, s["means"]))
        quats = s["quats"] + d["dr"]
        overrides = {
            "means": s["means"] + d["dx"],
            "scales": torch.exp(s["scales"] + d["ds"]),
            "quats": quats if raw_quats else nn.functional.normalize(quats, dim=-1),
        }
        if "do" in d:
            overrides["opacities"] = torch.sigmoid(s["opacities"] + d["do"][:, 0])
        if "dsh" in d:
            sh = sh_coeffs(s, self.active_sh_degree)
            overrides["sh"] = sh + d["dsh"].view(-1, SH_COEFFS, 3)[:, : sh.shape[1]]
        return activate(s, self.active_sh_degree, **overrides)

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        c, grid = self.config, self.fields.grid
        if not self.deforming or c.time_smoothness_weight == 0:
            return torch.zeros((), device=self.splats["means"].device)
        return (
            c.plane_tv_weight * grid.space_smoothness()
            + c.time_smoothness_weight * grid.time_smoothness()
            + c.l1_time_planes * grid.time_l1()
        )

    def param_groups(self) -> list[ParamGroup]:
        c, s = self.config, self.spatial_lr_scale
        if not self.deforming:
            return super().param_groups()
        schedule = dict(lr_delay_mult=c.lr_delay_mult, max_steps=c.means_lr_max_steps)
        groups = [
            *super().param_groups(),
            ParamGroup(
                "deformation",
                self.fields.mlp_parameters(),
                c.deformation_lr * s,
                lr_final=c.deformation_lr_final * s,
                **schedule,
            ),
            ParamGroup(
                "grid",
                list(self.fields.grid.parameters()),
                c.grid_lr * s,
                lr_final=c.grid_lr_final * s,
                **schedule,
            ),
        ]
        return [replace(g, start_step=c.coarse_iterations) for g in groups]  # schedules restart when fine


__all__ = ["FourDGSConfig", "FourDGSExpert", "FourDGSField", "FourDGSStrategy"]
