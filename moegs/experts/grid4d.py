"""Grid4D (Xu et al., NeurIPS 2024): 4D decomposed hash encoding + directional attention MLP.

Facts from ``JiaweiXu8/Grid4D`` (``scene/network.py``, ``scene/deform_model.py``, ``train.py``,
``gaussian_renderer/__init__.py``, ``arguments/``; ``specs/experts_canonical.md`` §3):

* encoding (:class:`~moegs.fields.DecomposedHashGrid4D`): ``h_xyz`` from a hash grid over detached xyz
  (16 levels x 2, 16 -> 2048, 2^19) and ``h_t`` from three space-time grids over (x, y, t), (y, z, t),
  (x, z, t) (32 levels x 2, per-axis 8 -> (32, 32, 16) on D-NeRF); t' = 0.9 (2 t - 1) bound;
* network: attention ``a = 2 sigmoid(Linear(32, 256)(h_xyz)) - 1`` (``directional``);
  ``h = ReLU(Linear(192, 256)(h_t)) * a``; ``depth`` x (Linear(256, 256) + ReLU); single-Linear heads
  warp 7 (+ [1, 0, 0, 0, 0, 0, 0]), rotation 4, scaling 3 (PyTorch default init);
* application: rigid motion about the world origin ``x' = R(q) x + t`` with ``(q, t) = warp`` (R from the
  normalised q), ``s' = exp(s) + ds``, ``q' = normalize(q) + dr`` (not renormalised);
* regularisers: ``lambda_s mean_i ||h_xyz(x_i + d) - h_xyz(x_i)||^2 + lambda_t mean_i ||h_t(xyzt_i + d') -
  h_t(xyzt_i)||^2`` on a random ``*_downsample_ratio`` subset, ``d ~ U(+-perturb)`` (t in bound units);
* 3000 static warm-up iterations, 0.8 L1 + 0.2 D-SSIM, ``spatial_lr_scale`` 5 (also on the scaling lr),
  black background, no pruning before the first opacity-reset interval; ``train.py`` keeps the best
  test-PSNR model at its testing iterations beside the last, and its README renders the last unless asked
  for ``--iteration best``: the paper recipes report both (``test`` and ``best``, ``TEST_ITERATIONS``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene
from moegs.experts.base import QUICK_ITERATIONS, DatasetPreset
from moegs.experts.canonical import QUICK_STATIC_ITERATIONS, DeformingExpert
from moegs.experts.gaussian_params import activate
from moegs.experts.static import QUICK_DENSIFY, QUICK_POINTS, StaticConfig
from moegs.fields import DecomposedHashGrid4D, Heads, mlp
from moegs.gaussians import GaussianFrame
from moegs.render.projection import quat_to_rotmat
from moegs.train.config import TrainConfig
from moegs.train.params import ParamGroup
from moegs.train.strategy import ADCStrategy, Strategy

IDENTITY_WARP = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # (q_w, q_x, q_y, q_z, t_x, t_y, t_z)


class Grid4DNetwork(nn.Module):
    """``(h_xyz [N, Ds], h_t [N, Dt]) -> {"warp" [N, 7], "drot" [N, 4], "dscale" [N, 3]}``.

    ``warp`` already includes the identity offset ``[1, 0, 0, 0, 0, 0, 0]``.
    """

    def __init__(
        self, spatial_dim: int, temporal_dim: int, width: int = 256, depth: int = 0, directional: bool = True
    ) -> None:
        super().__init__()
        self.directional = directional
        self.spatial_mlp = nn.Linear(spatial_dim, width)
        self.temporal_mlp = mlp([temporal_dim, width], relu_last=True)
        self.trunk = mlp([width] * (depth + 1), relu_last=True) if depth > 0 else nn.Identity()
        self.heads = Heads(width, {"warp": 7, "drot": 4, "dscale": 3})
        self.register_buffer("identity_warp", torch.tensor(IDENTITY_WARP), persistent=False)

    def attention(self, h_xyz: Tensor) -> Tensor:
        """``2 sigmoid(.) - 1`` in (-1, 1) (``directional``) or ``sigmoid(.)`` in (0, 1); ``[N, width]``."""
        a = torch.sigmoid(self.spatial_mlp(h_xyz))
        return 2.0 * a - 1.0 if self.directional else a

    def forward(self, h_xyz: Tensor, h_t: Tensor) -> dict[str, Tensor]:
        out = self.heads(self.trunk(self.temporal_mlp(h_t) * self.attention(h_xyz)))
        out["warp"] = out["warp"] + self.identity_warp
        return out


class Grid4DField(nn.Module):
    """Encoder + network. ``forward(xyz [N, 3] world, t [N, 1] in [0, 1])`` -> the network outputs."""

    def __init__(self, encoder: DecomposedHashGrid4D, network: Grid4DNetwork, scale_xyz: float = 1.0) -> None:
        super().__init__()
        self.encoder, self.network, self.scale_xyz = encoder, network, scale_xyz

    def coordinates(self, xyz: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """Grid inputs (bound units): ``xyz * scale_xyz [N, 3]``, ``xyzt [N, 4]``, t' = 0.9 (2t - 1) bound."""
        xyz = xyz * self.scale_xyz
        return xyz, torch.cat([xyz, self.encoder.time_coordinate(t)], dim=-1)

    def forward(self, xyz: Tensor, t: Tensor) -> dict[str, Tensor]:
        if xyz.ndim != 2 or xyz.shape[1] != 3 or t.shape != (xyz.shape[0], 1):
            raise ValueError(
                f"Grid4DField expects xyz [N, 3] and t [N, 1], got {list(xyz.shape)}, {list(t.shape)}"
            )
        xyz, xyzt = self.coordinates(xyz, t)
        return self.network(self.encoder.encode_spatial(xyz), self.encoder.encode_temporal(xyzt))


def perturbation_loss(
    encode: Callable[[Tensor], Tensor], points: Tensor, perturb: Tensor, ratio: float
) -> Tensor:
    """``mean_i ||encode(p_i + d_i) - encode(p_i)||^2`` with ``d_i ~ U(-perturb, perturb)`` over a random
    subset of ``max(1, int(ratio N))`` rows of ``points [N, D]`` (all rows when ``ratio >= 1``)."""
    if ratio < 1.0:
        keep = max(1, int(points.shape[0] * ratio))
        points = points[torch.randperm(points.shape[0], device=points.device)[:keep]]
    moved = points + (torch.rand_like(points) * 2.0 - 1.0) * perturb
    return (encode(moved) - encode(points)).square().sum(-1).mean()


def rigid_warp(means: Tensor, warp: Tensor) -> Tensor:
    """``R(normalize(warp[:, :4])) @ means + warp[:, 4:]`` for ``means [N, 3]``, ``warp [N, 7]``."""
    rot = quat_to_rotmat(nn.functional.normalize(warp[:, :4], dim=-1))
    return (rot @ means[..., None])[..., 0] + warp[:, 4:]


TEST_ITERATIONS = (5000, 6000, 7000, *range(10_000, 50_001, 1000))
"""Where ``train.py`` scores the test views and keeps the best model (``testing_iterations``, :266-267)."""


@dataclass
class Grid4DConfig(StaticConfig):
    """Grid4D hyperparameters; defaults are the D-NeRF configs (``arguments/dnerf/*.py``)."""

    bound: float | None = 1.6
    """Half-size of the encoded cube (``bound``); points outside get zero features. None: derived from
    the scene (``scene_bound``), for scenes Grid4D has no configuration of (``own_frame_fields``)."""
    scale_xyz: float = 1.0
    """xyz multiplier before encoding (``scale_xyz``)."""
    spatial_levels: int = 16
    """Levels of the xyz grid (``canonical_num_levels``)."""
    spatial_level_dim: int = 2
    """Features per level of the xyz grid."""
    spatial_base: int = 16
    """Coarsest resolution of the xyz grid."""
    spatial_desired: int = 2048
    """Finest resolution of the xyz grid."""
    spatial_log2_size: int = 19
    """log2 table size of the xyz grid."""
    temporal_levels: int = 32
    """Levels of each space-time grid (``deform_num_levels``)."""
    temporal_level_dim: int = 2
    """Features per level of each space-time grid."""
    temporal_base: tuple[int, int, int] = (8, 8, 8)
    """Coarsest (space, space, time) resolution of each space-time grid."""
    temporal_desired: tuple[int, int, int] = (32, 32, 16)
    """Finest (space, space, time) resolution of each space-time grid."""
    temporal_log2_size: int = 19
    """log2 table size of each space-time grid."""
    width: int = 256
    """Network width."""
    depth: int = 0
    """Hidden Linear+ReLU layers after the attention product (D-NeRF 0; ``ModelParams`` / MoDE default 1)."""
    directional: bool = True
    """Attention in (-1, 1) (``2 sigmoid - 1``) rather than (0, 1)."""
    warm_up: int = 3000
    """Iterations ``< warm_up`` render the canonical Gaussians without deformation."""
    network_lr_scale: float = 5.0
    """Network lr = ``means_lr * network_lr_scale`` decaying to ``means_lr_final`` (unscaled)."""
    grid_lr_scale: float = 50.0
    """Grid lr = ``means_lr * grid_lr_scale`` decaying to ``means_lr_final * grid_lr_scale``."""
    deform_lr_max_steps: int = 45_000
    """Decay length of the network and grid rates (``deform_lr_max_steps``)."""
    lr_delay_mult: float = 0.01
    """``position_lr_delay_mult``; inactive because the original never sets delay steps."""
    lambda_spatial: float = 0.5
    """Weight of the spatial perturbation loss (``lambda_spatial_tv``)."""
    lambda_temporal: float = 0.5
    """Weight of the temporal perturbation loss (``lambda_temporal_tv``)."""
    spatial_downsample_ratio: float = 0.1
    """Fraction of Gaussians in the spatial loss."""
    temporal_downsample_ratio: float = 0.1
    """Fraction of Gaussians in the temporal loss."""
    spatial_perturb: tuple[float, float, float] = (1e-2, 1e-2, 1e-2)
    """Half-range of the xyz perturbation (bound units)."""
    temporal_perturb: tuple[float, float, float, float] = (1e-2, 1e-2, 1e-2, 1e-3)
    """Half-range of the (x, y, z, t') perturbation (bound units; lego uses t 0)."""
    reg_after_densify: bool = False
    """Apply the perturbation losses only after ``strategy.densify_until`` (N3V)."""
    spatial_lr_scale: float | None = 5.0
    """Hard-coded 5 in ``GaussianModel`` (the scene extent is ignored)."""
    means_lr_max_steps: int = 35_000
    """``position_lr_max_steps``."""
    scales_lr: float = 5e-3
    """``scaling_lr`` 0.001 (``arguments/__init__.py:120``) times ``spatial_lr_scale`` 5
    (set at ``scene/gaussian_model.py:117``, applied at ``:124``)."""
    strategy: Strategy = field(default_factory=lambda: ADCStrategy(prune_after_reset_only=True))
    """3DGS densify-and-prune: 500-15k every 100, τ 2e-4, opacity reset every 3000, no pruning before the
    first reset interval (``train.py:154`` passes no size threshold until then, and
    ``scene/gaussian_model.py:374-380`` prunes only with one)."""
    train: TrainConfig = field(
        default_factory=lambda: TrainConfig(
            iterations=50_000, lambda_dssim=0.2, select_best_at=TEST_ITERATIONS
        )
    )

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "dnerf": DatasetPreset("paper-dnerf", "arguments/dnerf/*.py over arguments/__init__.py"),
        "n3v": DatasetPreset("paper-n3v", "arguments/neu3d/*.py (cook_spinach and the three like it)"),
        "hypernerf": DatasetPreset("paper-hypernerf", "arguments/hypernerf/vrig_3dprinter.py"),
    }
    DEFAULT_PRESET: ClassVar[str] = "paper-n3v"
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "black"}
    """``_white_background = False`` (``arguments/__init__.py:56``); no config or README command sets it."""
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {
        "n3v": {
            "resample": "lanczos",  # scene/neu3d.py:367 img.resize(self.img_wh, Image.LANCZOS)
            "points": "mvs40k",  # scene/dataset_readers.py:587 4DGaussians' points3D_downsample2.ply
        },
    }
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {
        "dnerf:lego": {
            "grid_lr_scale": 250.0,  # arguments/dnerf/lego.py:23
            "lambda_spatial": 1.0,  # lego.py:26
            "lambda_temporal": 1.0,  # lego.py:30
            "temporal_perturb": (1e-2, 1e-2, 1e-2, 0.0),  # lego.py:32
        },
        "n3v:coffee_martini": {
            "temporal_desired": (64, 64, 128),  # arguments/neu3d/coffee_martini.py:11
            "lambda_spatial": 0.0,  # coffee_martini.py:28
            "lambda_temporal": 0.0,  # coffee_martini.py:32
            "train.lambda_dssim": 0.0,  # coffee_martini.py:36
            "train.iterations": 50_000,  # coffee_martini.py sets none: arguments/__init__.py:101
        },
        "n3v:flame_salmon": {
            "temporal_desired": (64, 64, 128),  # arguments/neu3d/flame_salmon_1.py:11
            "lambda_spatial": 0.0,  # flame_salmon_1.py:28
            "lambda_temporal": 0.0,  # flame_salmon_1.py:32
            "train.lambda_dssim": 0.0,  # flame_salmon_1.py:36
            "train.iterations": 50_000,  # flame_salmon_1.py:39 commented: arguments/__init__.py:101
        },
        "hypernerf:broom": {
            "spatial_desired": 2048,  # arguments/hypernerf/vrig_broom.py:5
            "temporal_base": (16, 16, 16),  # vrig_broom.py:10
            "temporal_desired": (256, 256, 64),  # vrig_broom.py:11
            "bound": 0.8,  # vrig_broom.py:14
            "spatial_downsample_ratio": 0.1,  # vrig_broom.py:27
            "spatial_perturb": (1e-3, 1e-3, 1e-3),  # vrig_broom.py:28
            "warm_up": 0,  # vrig_broom.py:34
            "strategy.densify_until": 12_000,  # vrig_broom.py:36
            "train.iterations": 30_000,  # vrig_broom.py:37
            "deform_lr_max_steps": 30_000,  # vrig_broom.py:38
            "means_lr_max_steps": 30_000,  # vrig_broom.py:39
        },
        "hypernerf:chicken": {
            "spatial_desired": 2048,  # arguments/hypernerf/vrig_chicken.py:5
            "bound": 1.6,  # vrig_chicken.py:14
            "spatial_perturb": (1e-3, 1e-3, 1e-3),  # vrig_chicken.py:28
            "strategy.reset_every": 1000,  # vrig_chicken.py:35
            "strategy.densify_until": 10_000,  # vrig_chicken.py:36
            "deform_lr_max_steps": 25_000,  # vrig_chicken.py:38
            "means_lr_max_steps": 25_000,  # vrig_chicken.py:39
        },
        "hypernerf:peel-banana": {
            "spatial_desired": 2048,  # arguments/hypernerf/vrig_peel-banana.py:5
            "temporal_base": (16, 16, 16),  # vrig_peel-banana.py:10
            "temporal_desired": (256, 256, 256),  # vrig_peel-banana.py:11
            "grid_lr_scale": 10.0,  # vrig_peel-banana.py:23
            "warm_up": 0,  # vrig_peel-banana.py:35
            "strategy.reset_every": 1000,  # vrig_peel-banana.py:36
            "strategy.densify_until": 7000,  # vrig_peel-banana.py:37
            "train.iterations": 30_000,  # vrig_peel-banana.py:38
            "deform_lr_max_steps": 30_000,  # vrig_peel-banana.py:39
            "means_lr_max_steps": 25_000,  # vrig_peel-banana.py:40
        },
    }

    DEFAULT_DATASET: ClassVar[str | None] = "dnerf"

    @classmethod
    def paper_n3v(cls) -> Grid4DConfig:
        """``arguments/neu3d/*.py`` (most scenes; coffee/salmon use [64, 64, 128], no reg, no D-SSIM)."""
        return cls(
            bound=30.0,
            temporal_base=(16, 16, 16),
            temporal_desired=(512, 512, 128),
            network_lr_scale=1.0,
            spatial_perturb=(5e-3,) * 3,
            temporal_perturb=(5e-3, 5e-3, 5e-3, 0.0),
            spatial_downsample_ratio=1.0,
            temporal_downsample_ratio=1.0,
            reg_after_densify=True,
            strategy=ADCStrategy(
                densify_every=400, reset_every=6000, prune_world_scale=None, prune_after_reset_only=True
            ),
            train=TrainConfig(iterations=20_000, lambda_dssim=0.2, select_best_at=TEST_ITERATIONS),
        )

    @classmethod
    def paper_hypernerf(cls) -> Grid4DConfig:
        """``arguments/hypernerf/vrig_3dprinter.py`` (HyperNeRF configs differ per scene; see spec §3.4)."""
        return cls(
            bound=1.0,
            spatial_desired=256,
            temporal_base=(16, 16, 8),
            temporal_desired=(512, 512, 32),
            depth=1,
            network_lr_scale=1.0,
            lambda_spatial=1.0,
            lambda_temporal=1.0,
            spatial_downsample_ratio=1.0,
            temporal_downsample_ratio=1.0,
            temporal_perturb=(1e-2, 1e-2, 1e-2, 0.0),
            warm_up=1000,
            deform_lr_max_steps=40_000,
            strategy=ADCStrategy(prune_after_reset_only=True),
            train=TrainConfig(iterations=40_000, lambda_dssim=0.2, select_best_at=TEST_ITERATIONS),
        )

    @classmethod
    def own_frame_fields(cls, config: Grid4DConfig, dataset: str, real: bool) -> dict[str, Any]:
        """Grid4D's bounds are those of the datasets it has configurations for (D-NeRF 1.6, N3V 30,
        HyperNeRF 0.8-2.0; ``arguments/{dnerf,neu3d,hypernerf}``); elsewhere (Panoptic, Technicolor, the
        stand-ins) the N3V bound of 30 would leave most of each grid axis empty (basketball's content lies
        within about 2.8 units), so the bound comes from the scene (``scene_bound``)."""
        own = real and dataset in cls.DATASET_PRESETS
        return {} if own or config.bound is None else {"bound": None}

    @classmethod
    def quick_fields(cls, paper: Grid4DConfig) -> dict[str, Any]:
        """CPU minutes on 100x100 D-NeRF: the static baseline's budget (600 iterations, 5k points)."""
        return {
            "max_init_points": QUICK_POINTS,
            "spatial_levels": 8,
            "spatial_desired": 512,  # 16 levels to 2048 -> 8 to 512 (100 px images)
            "spatial_log2_size": 14,  # tables 2^19 -> 2^14 (CPU memory and Adam cost)
            "temporal_levels": 8,
            "temporal_log2_size": 14,  # 32 -> 8 levels over the same range
            "warm_up": QUICK_STATIC_ITERATIONS,  # 3000 of 50k -> 150 of 600
            "means_lr_max_steps": QUICK_ITERATIONS,  # the canonical xyz decay spans the short run
            "train.select_best_at": (),  # the last model only (no test-set selection at CPU scale)
            # deform_lr_max_steps stays: a 600-step decay starves grid and MLP (measured 22.7 vs 28.2 dB)
            **QUICK_DENSIFY,
        }


BOUND_MARGIN = 1.25
"""``scene_bound`` over the scene's largest coordinate: D-NeRF's bound 1.6 is 1.23x its 1.3 box."""


def scene_bound(scene: Scene) -> float:
    """A bound for a scene without a Grid4D configuration: ``BOUND_MARGIN`` x the largest absolute
    coordinate of its content bounds (``Scene.bbox``; Panoptic's: the 1%-99% quantiles of its points)."""
    return round(BOUND_MARGIN * float(scene.bbox.abs().max()), 3)


class Grid4DExpert(DeformingExpert):
    """Canonical 3DGS + :class:`Grid4DField`."""

    name = "grid4d"
    config_class = Grid4DConfig

    def __init__(self, config: Grid4DConfig, splats: nn.ParameterDict, spatial_lr_scale: float) -> None:
        super().__init__(config, splats, spatial_lr_scale)
        c = config
        encoder = DecomposedHashGrid4D(
            c.bound,
            c.spatial_levels,
            c.spatial_level_dim,
            c.spatial_base,
            c.spatial_desired,
            c.spatial_log2_size,
            c.temporal_levels,
            c.temporal_level_dim,
            c.temporal_base,
            c.temporal_desired,
            c.temporal_log2_size,
        )
        network = Grid4DNetwork(encoder.spatial_dim, encoder.temporal_dim, c.width, c.depth, c.directional)
        self.fields = Grid4DField(encoder, network, c.scale_xyz)
        self._last_time: float | None = None  # time of the last training frame(), for regularization()

    @classmethod
    def from_scene(cls, scene: Scene, config: Grid4DConfig) -> Grid4DExpert:
        if config.bound is None:
            config = replace(config, bound=scene_bound(scene))
        return cls(config, *cls.canonical(scene, config))

    @property
    def deforming(self) -> bool:
        return self.step >= self.config.warm_up

    def deform(
        self, splats: Mapping[str, Tensor], t: float, camera: Camera | None = None, raw_quats: bool = False
    ) -> GaussianFrame:
        """Grid4D adds ``dr`` to the unit canonical quaternion and never renormalises; ``raw_quats`` adds
        it to the raw canonical one, as MoDE's Grid4D member does (``r_can + d_rotation``,
        ``specs/official_moegs.md`` section 6)."""
        if not self.deforming:
            return activate(splats, self.active_sh_degree)
        if self.training and torch.is_grad_enabled():
            self._last_time = float(t)
        d = self.fields(splats["means"].detach(), self.time_column(t, splats["means"]))
        return activate(
            splats,
            self.active_sh_degree,
            means=rigid_warp(splats["means"], d["warp"]),
            scales=torch.exp(splats["scales"]) + d["dscale"],
            quats=(splats["quats"] if raw_quats else nn.functional.normalize(splats["quats"], dim=-1))
            + d["drot"],
        )

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        """Perturbation losses at the Gaussians and time of the last training ``frame()``."""
        c = self.config
        zero = torch.zeros((), device=self.splats["means"].device)
        densify_until = getattr(c.strategy, "densify_until", 0)
        if not self.deforming or self._last_time is None or (c.reg_after_densify and step <= densify_until):
            return zero
        xyz, xyzt = self.fields.coordinates(self.splats["means"].detach(), self.time_column(self._last_time))
        enc, loss = self.fields.encoder, zero
        if c.lambda_spatial > 0:
            loss = loss + c.lambda_spatial * perturbation_loss(
                enc.encode_spatial, xyz, xyz.new_tensor(c.spatial_perturb), c.spatial_downsample_ratio
            )
        if c.lambda_temporal > 0:
            loss = loss + c.lambda_temporal * perturbation_loss(
                enc.encode_temporal, xyzt, xyzt.new_tensor(c.temporal_perturb), c.temporal_downsample_ratio
            )
        return loss

    def param_groups(self) -> list[ParamGroup]:
        c, base = self.config, self.config.means_lr
        return [
            *super().param_groups(),
            ParamGroup(
                "deform",
                list(self.fields.network.parameters()),
                base * c.network_lr_scale,
                lr_final=c.means_lr_final,
                lr_delay_mult=c.lr_delay_mult,
                max_steps=c.deform_lr_max_steps,
            ),
            ParamGroup(
                "grid",
                list(self.fields.encoder.parameters()),
                base * c.grid_lr_scale,
                lr_final=c.means_lr_final * c.grid_lr_scale,
                lr_delay_mult=c.lr_delay_mult,
                max_steps=c.deform_lr_max_steps,
            ),
        ]


__all__ = ["Grid4DConfig", "Grid4DExpert", "Grid4DField", "Grid4DNetwork", "perturbation_loss", "rigid_warp"]
