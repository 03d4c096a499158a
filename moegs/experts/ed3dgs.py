"""E-D3DGS (Bae et al., ECCV 2024): per-Gaussian and temporal embeddings decoded by two MLP branches.

Every Gaussian ``i`` carries a learned embedding ``z_i`` (32-D, zero at init); time ``t`` is encoded by
a table of temporal embeddings ``e(t)`` (256-D) read with linear interpolation over ``M`` knots. Two
identical branches (coarse, fine) map ``[e(t), z_i]`` to offsets of the canonical attributes; they act
one after the other and their offsets add up::

    h = Linear([e(t), z_i])           (+ (ReLU, Linear) x (depth - 1))
    x += dx(h) a,  q += dq(h) a,  log s += ds(h) a a_s,  logit o += do(h) a a_o,  SH += dSH(h) a_c

with the ramp ``a = clip(step / 1000, 0, 1)`` and the delayed ramp ``a_{s,o,c} = clip((step -
deform_from) / 1000, 0, 1)`` (N3V ``use_anneal``). The coarse branch reads a table resized to
``min_embeddings`` knots; the fine branch's knot count grows linearly from min to max over
``coarse_to_fine_until`` iterations (max at test). On multi-view data each camera has a learned time
offset (its mean over trained cameras at test).

Training extras: L1 + ``1e-4 sigmoid(mean opacity logit)`` (instead of opacity resets) + a local
smoothness of the embeddings over k = 20 canonical neighbours; on multi-view data a camera sampler
that keeps consecutive cameras far apart, error-guided frames after ``random_until`` and D-SSIM only on
the iterations that reuse one frame across cameras.

Sources: ``JeongminB/E-D3DGS`` @ a68543e (``scene/deformation.py``, ``scene/gaussian_model.py``,
``train.py``, ``utils/extra_utils.py``, ``arguments/``); ``specs/experts_canonical.md`` section 2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.points import knn_torch
from moegs.data.scene import Scene, View
from moegs.experts.base import (
    QUICK_ITERATIONS,
    DatasetPreset,
    Expert,
    ExpertConfig,
    quick_step,
    splat_param_groups,
)
from moegs.experts.gaussian_params import activate, active_sh_degree, init_splats, num_sh_bases
from moegs.experts.static import QUICK_POINTS, scene_points, thin_points
from moegs.fields.mlp import Heads, mlp
from moegs.gaussians import GaussianFrame
from moegs.render import RenderOutput
from moegs.train.config import TrainConfig
from moegs.train.losses import dssim, l1
from moegs.train.params import ParamGroup
from moegs.train.strategy import NEVER, ADCStrategy, Strategy

DEFORMABLE = ("means", "scales", "quats", "opacities", "sh")
_HEAD_DIMS = {"means": 3, "scales": 3, "quats": 4, "opacities": 1}


# -- formulas ----------------------------------------------------------------------------------------
def consecutive_pairs(count: int, frames: int, batch_size: int, generator: torch.Generator) -> list[int]:
    """E-D3DGS's monocular batch (``train.py:110-113``): ``max(B // 2, 1)`` draws ``f`` from
    ``0..⌈count / 2⌉ - 1`` with repetition (``count`` training images), then images ``2f`` of every
    draw and ``2f + 1`` of every draw, modulo ``frames`` (``scene.maxtime``, the scene's frame count,
    e.g. 207 in ``arguments/hypernerf/vrig-3dprinter.py:10``): ``2 max(B // 2, 1)`` indices. With one
    training image per frame (HyperNeRF vrig) the two counts agree."""
    draws = torch.randint(
        math.ceil(count / 2), (max(batch_size // 2, 1),), generator=generator, device="cpu"
    ).tolist()
    return [2 * f % frames for f in draws] + [(2 * f + 1) % frames for f in draws]


def sample_rows(table: Tensor, u: Tensor) -> Tensor:
    """Linear interpolation between the rows of ``table [K, C]`` at normalised positions ``u [...]``.

    ``u = 0`` is row 0 and ``u = 1`` row ``K - 1`` (``grid_sample(align_corners=True)``); positions
    outside [0, 1] are reflected at the ends (``padding_mode="reflection"``). Returns ``[..., C]``.
    """
    if table.ndim != 2:
        raise ValueError(f"sample_rows: table must be [K, C], got {list(table.shape)}")
    k = table.shape[0]
    if k == 1:
        return table[0].expand(*u.shape, table.shape[1])
    u = torch.remainder(u.abs(), 2.0)
    u = torch.where(u > 1.0, 2.0 - u, u)
    pos = u * (k - 1)
    lo = pos.floor().long().clamp(max=k - 2)
    w = (pos - lo.to(pos.dtype))[..., None]
    return table[lo] * (1.0 - w) + table[lo + 1] * w


def temporal_embedding(table: Tensor, t: float | Tensor, knots: int) -> Tensor:
    """E-D3DGS ``get_temporal_embed``: ``table [K, C]`` resized to ``knots`` rows (linear, aligned
    corners), then read at time ``t`` (linear between knots, reflected outside [0, 1]). Returns ``[C]``.

    ``t`` may be a 0-dim tensor (a time shifted by a learned camera offset keeps its gradient)."""
    if knots < 1:
        raise ValueError(f"temporal_embedding needs knots >= 1, got {knots}")
    grid = torch.linspace(0.0, 1.0, knots, dtype=table.dtype, device=table.device)
    resized = sample_rows(table, grid)  # [knots, C]
    return sample_rows(resized, torch.as_tensor(t, dtype=table.dtype, device=table.device))


def knots_at(step: int, min_knots: int, max_knots: int, until: int | None) -> int:
    """Fine-branch knot count at ``step``: ``int(min + (max - min) clip(step, 0, until) / until)``
    (E-D3DGS ``int_lininterp``); ``until=None`` (no coarse-to-fine) gives ``max_knots``."""
    if until is None:
        return max_knots
    return int(min_knots + (max_knots - min_knots) * min(max(step, 0), until) / until)


def ramp(step: int, start: int, length: int) -> float:
    """``clip((step - start) / length, 0, 1)``: the E-D3DGS anneal coefficient."""
    return min(max((step - start) / length, 0.0), 1.0)


def knn(points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """The ``k`` nearest other points of each point (as open3d ``KDTreeFlann`` in E-D3DGS).

    On the CPU a KD-tree in float64 (scipy); elsewhere exact sums of squared differences on the points'
    device (``moegs.data.points.knn_torch``), which round differently and may order ties otherwise, so the
    CPU keeps the KD-tree and its results.

    Args:
        points: ``[N, 3]``.

    Returns:
        squared distances ``[N, k']`` and indices ``[N, k']`` (int64), ``k' = min(k, N - 1)``.
    """
    n = points.shape[0]
    k = min(k, n - 1)
    if k < 1:
        raise ValueError(f"knn needs at least 2 points, got {n}")
    if points.device.type != "cpu":
        return knn_torch(points.detach(), k)
    from scipy.spatial import cKDTree

    p = points.detach().double().numpy()
    dist, idx = cKDTree(p).query(p, k=k + 1)
    return torch.from_numpy(dist[:, 1:] ** 2).to(points.dtype), torch.from_numpy(idx[:, 1:]).long()


def embedding_smoothness(embedding: Tensor, neighbours: Tensor, weights: Tensor) -> Tensor:
    """Mean over Gaussians and neighbours of ``sqrt(w_ij ||z_i - z_j||² + 1e-20)`` (E-D3DGS
    ``weighted_l2_loss_v2``).

    Args:
        embedding: ``[N, D]``; neighbours: ``[N, k]`` indices; weights: ``[N, k]``.
    """
    # index_select, not embedding[neighbours]: the latter's CPU backward (an accumulating index_put_)
    # sums repeated indices in thread order, so identical runs drifted apart; index_add_ does not.
    gathered = embedding.index_select(0, neighbours.reshape(-1)).reshape(*neighbours.shape, -1)
    diff = embedding[:, None, :] - gathered  # [N, k, D]
    return torch.sqrt(diff.square().sum(-1) * weights + 1e-20).mean()


def buggy_temporal_tv(table: Tensor) -> Tensor:
    """The HyperNeRF temporal-embedding "TV" term exactly as E-D3DGS computes it: differences against
    the *last* rows ``w[K-1]`` / ``d[K-2]`` instead of shifted rows (``train.py``). ``table [K, C]``."""
    k = table.shape[0]
    first = table[1:] - table[k - 1]
    second = first[1:] - first[k - 2]
    return second.square().mean()


# -- fields --------------------------------------------------------------------------------------------
class DeformBranch(nn.Module):
    """One E-D3DGS branch: ``[e(t) (Ct), z_i (Cz)] -> hidden (W)`` then one head per deformed attribute.

    Heads are ``ReLU, Linear(W, W), ReLU, Linear(W, out)`` (4DGaussians style); PyTorch default init
    (E-D3DGS never applies its ``initialize_weights``).
    """

    def __init__(
        self,
        temporal_dim: int,
        embedding_dim: int,
        width: int,
        depth: int,
        deform: tuple[str, ...],
        sh_bases: int,
    ) -> None:
        super().__init__()
        self.feature_out = mlp([temporal_dim + embedding_dim] + [width] * max(depth, 1))
        outputs = {name: _HEAD_DIMS.get(name, 3 * sh_bases) for name in deform}
        self.heads = Heads(width, outputs, hidden=(width,), relu_first=True)

    def forward(self, e: Tensor, z: Tensor) -> dict[str, Tensor]:
        """``e [Ct]`` (one time), ``z [N, Cz]`` -> ``{attribute: offset [N, out]}``."""
        h = self.feature_out(torch.cat([e.expand(z.shape[0], -1), z], dim=-1))
        return self.heads(h)


class ED3DGSFields(nn.Module):
    """Temporal table ``[max_embeddings, temporal_dim]``, the two branches and per-camera time offsets."""

    def __init__(self, config: ED3DGSConfig, num_cameras: int) -> None:
        super().__init__()
        c = config
        shape = (c.max_embeddings, c.temporal_dim)
        init = (
            torch.zeros(shape) if c.zero_temporal else torch.randn(shape) * (0.01 / math.sqrt(c.temporal_dim))
        )
        self.temporal = nn.Parameter(init)
        bases = num_sh_bases(c.sh_degree)
        self.coarse = DeformBranch(c.temporal_dim, c.embedding_dim, c.width, c.depth, c.deform, bases)
        self.fine = DeformBranch(c.temporal_dim, c.embedding_dim, c.width, c.depth, c.deform, bases)
        self.offsets = nn.Parameter(torch.zeros(num_cameras)) if num_cameras > 0 else None

    def time_offset(self, camera: Camera | None, training: bool) -> Tensor | float:
        """The camera's learned offset while training; at test the mean of the non-zero offsets."""
        if self.offsets is None:
            return 0.0
        if training and camera is not None:
            if not 0 <= camera.camera_id < self.offsets.shape[0]:
                raise ValueError(
                    f"camera_id {camera.camera_id} has no time offset (table of {self.offsets.shape[0]})"
                )
            return self.offsets[camera.camera_id]
        nonzero = self.offsets[self.offsets != 0]
        return nonzero.mean() if nonzero.numel() else 0.0


# -- config ----------------------------------------------------------------------------------------------
@dataclass
class ED3DGSStrategy(ADCStrategy):
    """3DGS densification as E-D3DGS's ``train.py`` runs it: the screen gradients of a step's views are
    summed before the norm, and a Gaussian seen by any of them counts once (``:158-159, 204-206, 249-250``);
    no extra opacity reset at ``densify_from`` on a white background."""

    batch_stats: str = "summed"
    reset_at_densify_from_if_white: bool = False


@dataclass
class ED3DGSConfig(ExpertConfig):
    """E-D3DGS hyperparameters. Defaults: the N3V protocol used by MoE-GS (``arguments/dynerf/default.py``
    over ``arguments/__init__.py``)."""

    sh_degree: int = 3
    """Maximum SH degree (+1 every 1000 iterations)."""
    max_init_points: int | None = None
    """Keep at most this many initial points (random subset); None keeps all (E-D3DGS: ≤100k MVS points)."""
    embedding_dim: int = 32
    """Per-Gaussian embedding size (``gaussian_embedding_dim``)."""
    temporal_dim: int = 256
    """Temporal embedding size (``temporal_embedding_dim``)."""
    min_embeddings: int = 30
    """Knots of the coarse table and start of the fine schedule (N3V 30; Technicolor 5; HyperNeRF 16-50)."""
    max_embeddings: int = 150
    """Rows of the temporal table, knots of the fine branch at test (N3V 150; Technicolor 25)."""
    coarse_to_fine_until: int | None = 10_000
    """Iteration at which the fine branch reaches ``max_embeddings`` (``c2f_temporal_iter``); None = always
    max (``no_c2f_temporal_embedding``, Technicolor)."""
    coarse_min_embeddings: bool = True
    """The coarse branch reads ``min_embeddings`` knots (``use_coarse_temporal_embedding``, N3V); else it
    follows the fine schedule."""
    zero_temporal: bool = False
    """Zero-initialised temporal table (Technicolor, HyperNeRF); else N(0, 0.01/sqrt(256)) (N3V)."""
    width: int = 128
    """Branch width ``W`` (``net_width``; code default 64, every dataset config 128)."""
    depth: int = 1
    """Linear layers before the heads (``defor_depth``; N3V 1, others 0, which builds the same net)."""
    deform: tuple[str, ...] = DEFORMABLE
    """Deformed attributes (N3V all five; Technicolor without "sh"; HyperNeRF means, scales, quats)."""
    use_anneal: bool = True
    """Ramp the deformation in (``use_anneal``, N3V); off elsewhere (all coefficients 1)."""
    anneal_steps: int = 1000
    """Length of both ramps (hard-coded 1000 in ``deformation.py``)."""
    deform_from: int = 5000
    """Start of the scale / opacity / colour ramp (``deform_from_iter``, N3V 5000)."""
    time_offsets: bool = True
    """Learn one time offset per camera on multi-view scenes (``offsets``)."""
    offsets_lr: float = 2e-5
    """Time-offset learning rate (N3V 2e-5; 0 on the other datasets, i.e. ``time_offsets=False``)."""
    spatial_lr_scale: float | None = None
    """Multiplier of the position / deformation learning rates; None = scene extent (``cameras_extent``)."""
    means_lr: float = 1.6e-4
    means_lr_final: float = 1.6e-6
    means_lr_max_steps: int = 80_000
    """``position_lr_*`` (max steps = iterations in every dataset config)."""
    deformation_lr: float = 1.6e-4
    deformation_lr_final: float = 1.6e-5
    deformation_lr_max_steps: int = 80_000
    """``deformation_lr_*``: MLPs and the temporal table (Technicolor 1.6e-3 -> 1.6e-4)."""
    embedding_lr: float = 2.5e-3
    """Per-Gaussian embedding learning rate (``feature_lr``)."""
    sh0_lr: float = 2.5e-3
    shN_lr: float = 2.5e-3 / 20
    opacities_lr: float = 0.05
    scales_lr: float = 5e-3
    quats_lr: float = 1e-3
    opacity_reg: float = 1e-4
    """Weight of ``sigmoid(mean opacity logit)`` (``opacity_l1_coef_fine``)."""
    smoothness_reg: float = 1.0
    """Weight of the kNN embedding smoothness (``reg_coef``; Technicolor 0.1)."""
    smoothness_neighbours: int = 20
    smoothness_falloff: float = 2000.0
    """Neighbour weight ``exp(-falloff d²)`` (Dynamic3DGaussians' constant)."""
    temporal_tv: float = 0.0
    """Weight of the (buggy, see ``buggy_temporal_tv``) temporal TV (HyperNeRF 1e-4)."""
    lambda_ssim: float = 1.0
    """Weight of ``(1 - SSIM) / 2`` on the multi-view SSIM iterations (``lambda_dssim``; HyperNeRF 0)."""
    random_until: int = 10_000
    """Uniform frames until here; afterwards odd iterations sample frames by error (multi-view only)."""
    consecutive_pairs: bool = False
    """Monocular batches of consecutive training images: ``max(B // 2, 1)`` random ``f`` (with repetition),
    images ``2f`` then ``2f + 1`` modulo the frame count (``loader == 'nerfies'``, ``train.py:110-113``; the
    HyperNeRF recipe); off, monocular batches come from the default sampler."""
    multiview_ssim_iters: int = 5
    """After ``random_until``, the first this many iterations of every 50 reuse one frame and add D-SSIM."""
    strategy: Strategy = field(
        default_factory=lambda: ED3DGSStrategy(
            densify_from=5000,
            densify_until=80_000,
            densify_every=100,
            grad_threshold=3e-4,
            prune_opacity=0.005,
            reset_every=NEVER,
        )
    )
    """Densify/prune every 100 from 5000 (N3V), no opacity reset, no size pruning."""
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=80_000, lambda_dssim=0.0))
    """80k iterations; the loop's D-SSIM is off: E-D3DGS adds it itself on multi-view SSIM iterations."""

    def __post_init__(self) -> None:
        unknown = set(self.deform) - set(DEFORMABLE)
        if unknown or "means" not in self.deform:
            raise ValueError(
                f"ED3DGSConfig.deform must include 'means' and be a subset of {DEFORMABLE}, got {self.deform}"
            )
        if not 1 <= self.min_embeddings <= self.max_embeddings:
            raise ValueError(
                f"need 1 <= min_embeddings <= max_embeddings, got {self.min_embeddings}, "
                f"{self.max_embeddings}"
            )

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "n3v": DatasetPreset("paper", "arguments/dynerf/default.py over arguments/__init__.py"),
        "technicolor": DatasetPreset("paper-technicolor", "arguments/technicolor/default.py"),
        "hypernerf": DatasetPreset("paper-hypernerf", "arguments/hypernerf/default.py"),
        "dnerf": DatasetPreset(
            "paper-hypernerf",
            "adaptation: the original has no D-NeRF config; its monocular (HyperNeRF) recipe is used",
            adapted=True,
        ),
    }
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "white"}
    """``white_background`` is forced on for every dataset (``arguments/__init__.py:54``, ``train.py:46``)."""
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {
        "n3v": {
            "resample": "lanczos",  # scene/cameras.py:128 original_image.resize(img_wh, Image.LANCZOS)
            "points": "mvs100k",  # scene/dataset_readers.py:293 points3D_downsample.ply (README.md:59-61)
        },
        "n3v:coffee_martini": {"exclude": ("cam13",)},  # README.md:43: remove cam13.mp4 and its pose
        # scene/dataset_readers.py:352 the same file name: the window's first frame's dense cloud
        # (script/pre_technicolor.py:160-169, :259; downsample_point.py:7-11 at most 100k points)
        "technicolor": {"points": "mvs100k"},
    }
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {
        # arguments/dynerf/flame_steak.py:4-5
        "n3v:flame_steak": {"strategy.grad_threshold": 2e-4},
        # arguments/technicolor/<Scene>.py:3-9 (Train.py:3-13): longer schedules, reg_coef 0.1
        **{
            f"technicolor:{name}": {
                "train.iterations": steps,
                "strategy.densify_until": steps,
                "means_lr_max_steps": steps,
                "deformation_lr_max_steps": steps,
                "smoothness_reg": 0.1,
            }
            for name, steps in (
                ("birthday", 100_000),
                ("painter", 100_000),
                ("fabien", 120_000),
                ("theater", 120_000),
            )
        },
        "technicolor:train": {
            "deformation_lr": 5e-3,  # Train.py:3
            "deformation_lr_final": 5e-5,  # Train.py:4
            "train.iterations": 120_000,  # Train.py:7
            "strategy.densify_until": 120_000,  # Train.py:9
            "means_lr_max_steps": 120_000,  # Train.py:11
            "deformation_lr_max_steps": 120_000,  # Train.py:12
            "smoothness_reg": 0.1,  # Train.py:13
        },
        # arguments/hypernerf/vrig-<scene>.py:3-14 (knots, coarse-to-fine, schedule lengths)
        **{
            f"hypernerf:{name}": {
                "min_embeddings": lo,
                "max_embeddings": hi,
                "coarse_to_fine_until": c2f,
                "train.iterations": steps,
                "strategy.densify_until": steps,
                "means_lr_max_steps": steps,
                "deformation_lr_max_steps": steps,
            }
            for name, lo, hi, c2f, steps in (
                ("3dprinter", 20, 100, 20_000, 60_000),
                ("broom", 20, 100, 20_000, 60_000),
                ("chicken", 16, 80, 10_000, 60_000),
                ("peel-banana", 50, 250, 40_000, 80_000),
            )
        },
    }

    DEFAULT_DATASET: ClassVar[str | None] = "n3v"

    @classmethod
    def paper_technicolor(cls) -> ED3DGSConfig:
        """``arguments/technicolor/default.py`` (line numbers in the comments)."""
        return cls(
            depth=0,  # :7 (builds the same net as 1)
            deform=("means", "scales", "quats", "opacities"),  # :9-11 (no_dc: no SH head)
            min_embeddings=5,  # :13
            max_embeddings=25,  # :14
            coarse_to_fine_until=None,  # :19 no_c2f_temporal_embedding
            use_anneal=False,  # :22
            zero_temporal=True,  # :23
            deformation_lr=1.6e-3,  # :50
            deformation_lr_final=1.6e-4,  # :51
            time_offsets=False,  # :72 offsets_lr 0
            random_until=60_000,  # :73
            strategy=ED3DGSStrategy(
                densify_from=500,  # :35-36
                densify_until=80_000,  # :32
                densify_every=100,  # :37
                grad_threshold=3e-4,  # :39-40
                prune_opacity=0.005,  # :42-43
                reset_every=NEVER,  # :33
            ),
            train=TrainConfig(iterations=80_000, lambda_dssim=0.0),  # :29
        )

    @classmethod
    def paper_hypernerf(cls) -> ED3DGSConfig:
        """``arguments/hypernerf/default.py`` over ``arguments/__init__.py`` (defaults of the fields the
        vrig configs leave alone; they set knots and schedule lengths per scene); its batch of 2 is a pair
        of consecutive training images (``train.py:110-113``), in the loader's order."""
        return cls(
            depth=0,  # :7
            deform=("means", "scales", "quats"),  # :9-11 (no_do, no_dc)
            coarse_to_fine_until=20_000,  # arguments/__init__.py:93 (vrig configs override)
            zero_temporal=True,  # :16
            use_anneal=False,  # :17
            deform_from=0,  # arguments/__init__.py:94
            time_offsets=False,  # :60 offsets_lr 0 (monocular anyway)
            means_lr_max_steps=20_000,  # arguments/__init__.py:107
            deformation_lr_max_steps=80_000,  # :41
            temporal_tv=1e-4,  # :62
            lambda_ssim=0.0,  # :57
            multiview_ssim_iters=0,  # :58
            consecutive_pairs=True,  # ModelParams loader "nerfies" (:2)
            strategy=ED3DGSStrategy(
                densify_from=500,  # :25-26
                densify_until=15_000,  # arguments/__init__.py:128
                densify_every=100,  # :27
                grad_threshold=2e-4,  # :29-30
                prune_opacity=0.005,  # :31-32
                reset_every=NEVER,  # :23
            ),
            train=TrainConfig(iterations=30_000, batch_size=2, lambda_dssim=0.0),  # :22; __init__.py:102
        )

    @classmethod
    def quick_fields(cls, paper: ED3DGSConfig) -> dict[str, Any]:
        """CPU minutes: the dataset's recipe with every schedule moved to the same fraction of a 600-step
        run (``quick_step``), densification until 75% of it, a narrower network."""
        steps = paper.train.iterations

        def at(step: int | None) -> int | None:
            return None if step is None else quick_step(step, steps)

        return {
            "max_init_points": QUICK_POINTS,  # E-D3DGS: up to 100k MVS points
            "width": 64,  # the code default (arguments/__init__.py:76); every dataset config uses 128
            "coarse_to_fine_until": at(paper.coarse_to_fine_until),
            "anneal_steps": 50,  # 1000 would leave the deformation ramping over most of the run
            "deform_from": at(paper.deform_from),
            "means_lr_max_steps": at(paper.means_lr_max_steps),
            "deformation_lr_max_steps": at(paper.deformation_lr_max_steps),
            "random_until": at(paper.random_until),
            "strategy.densify_from": at(paper.strategy.densify_from),
            "strategy.densify_until": int(QUICK_ITERATIONS * 0.75),  # the last densified Gaussians train
            "strategy.densify_every": 100,  # the original interval (see static.QUICK_DENSIFY)
            # N3V batch 1 (arguments/dynerf/default.py:20), HyperNeRF 2 (hypernerf/default.py:22) -> 1
            "train.batch_size": 1,  # (CPU cost; one view per step)
            # a pair would be 2 views a step (max(1 // 2, 1) draws): one view, from the default sampler
            **({"consecutive_pairs": False} if paper.consecutive_pairs else {}),
        }


# -- multi-view view sampler -----------------------------------------------------------------------------
class _ViewTable(nn.Module):
    """E-D3DGS's multi-view sampling state: far-apart consecutive cameras and error-guided frames.

    Saved with the expert so that a resumed run samples the same way: the buffer ``errors [C, F]`` (last L1
    of each camera x frame, 100 until seen) and, as extra state, ``last_camera`` and ``kept_frame`` (-1 =
    none). The camera bookkeeping is on the host: a step reads the device only to draw a frame by error.
    """

    def __init__(self, views: list[View]) -> None:
        super().__init__()
        cams = sorted({v.camera.camera_id for v in views})
        frames = sorted({v.camera.frame for v in views})
        self.cam_pos = {c: i for i, c in enumerate(cams)}
        self.frame_pos = {f: i for i, f in enumerate(frames)}
        self.index = {
            (self.cam_pos[v.camera.camera_id], self.frame_pos[v.camera.frame]): k for k, v in enumerate(views)
        }
        centres = {}
        for v in views:
            centres.setdefault(v.camera.camera_id, v.camera.center)
        c = torch.stack([centres[k] for k in cams])
        distances = torch.cdist(c, c)  # [C, C]
        unique = torch.unique(distances)
        self.min_distance = float(unique[int(unique.numel() * 0.5)])  # median unique pair distance
        self.far = []  # per camera: the others at least the median pair distance away (else all cameras)
        for last in range(len(cams)):
            far = (distances[last] >= self.min_distance).nonzero(as_tuple=True)[0]
            far = far[far != last]
            self.far.append(far.tolist() if far.numel() else list(range(len(cams))))
        self.register_buffer("errors", torch.full((len(cams), len(frames)), 100.0))
        self.last_camera, self.kept_frame = 0, -1

    def get_extra_state(self) -> dict:
        return {"last_camera": self.last_camera, "kept_frame": self.kept_frame}

    def set_extra_state(self, state: dict) -> None:
        self.last_camera, self.kept_frame = state["last_camera"], state["kept_frame"]

    def _camera(self, generator: torch.Generator) -> int:
        """A camera at least the median pair distance from the previous one (E-D3DGS ``sample_camera``)."""
        pool = self.far[self.last_camera]
        self.last_camera = pool[int(torch.randint(len(pool), (1,), generator=generator, device="cpu"))]
        return self.last_camera

    def _frame(self, by_error: bool, generator: torch.Generator) -> int:
        """Uniform, or ∝ the min-max normalised per-frame error summed over cameras (``get_idx_by_error``)."""
        if self.kept_frame >= 0:
            return self.kept_frame
        num = self.errors.shape[1]
        if not by_error:
            return int(torch.randint(num, (1,), generator=generator, device="cpu"))
        e = self.errors.sum(0).cpu()  # the draw runs on the sampler's generator, on the host
        e = (e - e.min()) / (e.max() - e.min()).clamp_min(1e-12)
        if e.sum() <= 0:
            return int(torch.randint(num, (1,), generator=generator, device="cpu"))
        return int(torch.multinomial(e / e.sum(), 1, generator=generator))

    def sample(self, step: int, batch: int, config: ED3DGSConfig, generator: torch.Generator) -> list[int]:
        by_error = step >= config.random_until and step % 2 == 0
        picks = []
        for _ in range(batch):
            cam, frame = self._camera(generator), self._frame(by_error, generator)
            if (cam, frame) not in self.index:  # camera missing at that frame: any camera of the frame
                cam = next(c for (c, f) in self.index if f == frame)
            picks.append(self.index[(cam, frame)])
        self.kept_frame = frame if ssim_step(step, config) else -1
        return picks

    def record(self, camera: Camera, error: Tensor | float) -> None:
        self.errors[self.cam_pos[camera.camera_id], self.frame_pos[camera.frame]] = error


def ssim_step(step: int, config: ED3DGSConfig) -> bool:
    """Whether iteration ``step`` reuses its frame on the next iteration and adds D-SSIM (multi-view)."""
    return (
        step >= config.random_until
        and config.multiview_ssim_iters > 0
        and step % 50 < config.multiview_ssim_iters
    )


# -- expert ------------------------------------------------------------------------------------------------
class ED3DGSExpert(Expert):
    """E-D3DGS: canonical 3DGS + per-Gaussian ``embedding [N, 32]`` + ``ED3DGSFields``."""

    name = "ed3dgs"
    config_class = ED3DGSConfig

    def __init__(
        self,
        config: ED3DGSConfig,
        splats: nn.ParameterDict,
        fields: ED3DGSFields,
        spatial_lr_scale: float,
        views: _ViewTable | None,
    ) -> None:
        super().__init__(config, splats, fields)
        self.spatial_lr_scale = spatial_lr_scale
        self.views = views
        self.step = 0  # the training step (``on_step``; a resume replays it)
        # the smoothness neighbours: found for the means of the last change of N, which are checkpointed
        self.register_buffer("knn_means", None, persistent=False)  # [N, 3]
        self.register_buffer("knn_index", None, persistent=False)  # [N, k]
        self.register_buffer("knn_weights", None, persistent=False)  # [N, k]

    def get_extra_state(self) -> dict:
        return {"knn_means": self.knn_means}

    def set_extra_state(self, state: dict) -> None:
        means = state["knn_means"]
        self.knn_means = None if means is None else means.to(self.splats["means"].device)
        self.knn_index = self.knn_weights = None  # found again for those means

    @classmethod
    def from_scene(cls, scene: Scene, config: ED3DGSConfig) -> ED3DGSExpert:
        points = thin_points(scene_points(scene), config.max_init_points, config.train.seed)
        splats = init_splats(
            points, config.sh_degree, extra={"embedding": torch.zeros(len(points), config.embedding_dim)}
        )
        splats["scales"].data.clamp_(max=1.0)  # E-D3DGS create_from_pcd clamps the log-scale at 1
        multiview = scene.multiview and config.time_offsets
        num_cameras = 1 + max(v.camera.camera_id for v in scene.train + scene.test) if multiview else 0
        scale = config.spatial_lr_scale if config.spatial_lr_scale is not None else scene.extent
        table = _ViewTable(scene.train) if scene.multiview else None
        return cls(config, splats, ED3DGSFields(config, num_cameras), scale, table)

    # -- training hooks ---------------------------------------------------------------------------------
    def on_step(self, step: int) -> bool:
        self.step = step
        return False

    def select_views(
        self, step: int, views: list[View], batch_size: int, generator: torch.Generator
    ) -> list[int] | None:
        """Multi-view: far-apart cameras, error-guided frames. Monocular: consecutive pairs
        (``consecutive_pairs``), else None (the default sampler)."""
        if self.views is None:
            if self.config.consecutive_pairs:
                frames = len({view.camera.frame for view in views})
                return consecutive_pairs(len(views), frames, batch_size, generator)
            return None
        return self.views.sample(step, batch_size, self.config, generator)

    def observe(self, step: int, view: View, rgb: Tensor, target: Tensor, out: RenderOutput) -> Tensor | None:
        """Record the view's L1 for error-guided sampling; D-SSIM ``λ (1 - SSIM) / 2`` on SSIM iterations."""
        if self.views is None:
            return None
        self.views.record(view.camera, l1(rgb.detach(), target))
        c = self.config
        extra_every_10 = (
            c.multiview_ssim_iters == 0 and step >= c.random_until and step % 2 == 0 and step % 10 == 0
        )
        if c.lambda_ssim > 0 and (ssim_step(step, c) or extra_every_10):
            return c.lambda_ssim * dssim(rgb, target) / 2
        return None

    # -- deformation -----------------------------------------------------------------------------------
    def knots(self) -> tuple[int, int]:
        """(coarse, fine) knot counts at the current step, in training and at test alike (the original's
        ``int_lininterp(iter)`` in both, ``scene/deformation.py:80``, ``render.py:54``): a model evaluated
        before ``coarse_to_fine_until`` reads fewer knots than the finished one."""
        c = self.config
        fine = knots_at(self.step, c.min_embeddings, c.max_embeddings, c.coarse_to_fine_until)
        return (c.min_embeddings if c.coarse_min_embeddings else fine), fine

    def coefficients(self) -> dict[str, float]:
        """Anneal factor of each deformed attribute at the current step (1 without ``use_anneal``)."""
        c, step = self.config, self.step
        if not c.use_anneal:
            return dict.fromkeys(DEFORMABLE, 1.0)
        a = ramp(step, 0, c.anneal_steps)
        late = ramp(step, c.deform_from, c.anneal_steps)
        return {"means": a, "quats": a, "scales": a * late, "opacities": a * late, "sh": late}

    def splat_inputs_key(self, camera: Camera) -> float:
        """In eval mode every camera gets the mean time offset: the inputs depend on the camera only
        through its time."""
        return camera.time

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        return self.deform(self.splats, t, camera)

    def deform(
        self, splats: Mapping[str, Tensor], t: float, camera: Camera | None = None, raw_quats: bool = False
    ) -> GaussianFrame:
        """The activated Gaussians at ``t`` of the canonical parameters ``splats`` (with ``embedding``);
        ``raw_quats``: the deformed quaternions before normalisation (MoDE mixes those)."""
        s, f = splats, self.fields
        time = t + f.time_offset(camera, self.training)
        coef = self.coefficients()
        raw = {
            "means": s["means"],
            "scales": s["scales"],
            "quats": s["quats"],
            "opacities": s["opacities"],
            "sh": torch.cat([s["sh0"], s["shN"]], dim=1),
        }
        for branch, knots in zip((f.coarse, f.fine), self.knots(), strict=True):
            e = temporal_embedding(f.temporal, time, knots)
            for name, d in branch(e, s["embedding"]).items():
                raw[name] = raw[name] + d.reshape(raw[name].shape) * coef[name]
        sh = raw.pop("sh")
        raw.update(sh0=sh[:, :1], shN=sh[:, 1:])
        overrides = {"quats": raw["quats"]} if raw_quats else {}
        degree = active_sh_degree(self.step, self.config.sh_degree, self.config.train.sh_degree_interval)
        return activate(raw, degree, **overrides)

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        c, s = self.config, self.splats
        loss = c.opacity_reg * torch.sigmoid(s["opacities"].mean())
        if c.smoothness_reg > 0:
            if self.knn_means is None or self.knn_means.shape[0] != s["means"].shape[0]:
                self.knn_means, self.knn_index = s["means"].detach().clone(), None
            if self.knn_index is None:
                d2, self.knn_index = knn(self.knn_means, c.smoothness_neighbours)
                self.knn_weights = torch.exp(-c.smoothness_falloff * d2)
            loss = loss + c.smoothness_reg * embedding_smoothness(
                s["embedding"], self.knn_index, self.knn_weights
            )
        if c.temporal_tv > 0:
            loss = loss + c.temporal_tv * buggy_temporal_tv(self.fields.temporal)
        return loss

    def param_groups(self) -> list[ParamGroup]:
        c, sc, s, f = self.config, self.spatial_lr_scale, self.splats, self.fields
        deformation = [f.temporal, *f.coarse.parameters(), *f.fine.parameters()]
        constant = [
            ("embedding", c.embedding_lr),
            ("sh0", c.sh0_lr),
            ("shN", c.shN_lr),
            ("opacities", c.opacities_lr),
            ("scales", c.scales_lr),
            ("quats", c.quats_lr),
        ]
        groups = splat_param_groups(s, c, sc, constant)
        groups.append(
            ParamGroup(
                "deformation",
                deformation,
                c.deformation_lr * sc,
                lr_final=c.deformation_lr_final * sc,
                max_steps=c.deformation_lr_max_steps,
            )
        )
        if f.offsets is not None:
            groups.append(ParamGroup("offsets", [f.offsets], c.offsets_lr))
        return groups

    def strategy(self) -> Strategy:
        return self.config.strategy
