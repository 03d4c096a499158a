"""Ex4DGS, fully explicit dynamic Gaussian splatting (Lee et al., NeurIPS 2024).

Two disjoint sets of Gaussians, kept here in one set of per-Gaussian tensors with a ``dynamic`` flag:

* static: ``x(t) = x + d t / D`` (a linear drift ``d`` over the model's duration ``D``: one more than the
  last frame trained so far);
* dynamic: ``K`` keyframes every ``I`` frames. With ``u = t + τs``, ``k = ⌊u / I⌋``, ``δ = (u mod I) / I``
  the position is the cubic Hermite curve through ``P_k, P_{k+1}`` with Catmull-Rom tangents
  ``m_k = (P_{k+1} - P_{k-1}) / 2``, the rotation ``slerp(Q_k, Q_{k+1}, δ)`` and the opacity
  ``sigmoid(o)`` times a two-sided temporal Gaussian around the centres ``c0, c1``.

Time is the integer frame index (``(t - t_first) / frame_step`` of the normalised scene time). Training
starts static on frames ``0..start_duration`` and grows by ``I`` frames every ``grow_every`` iterations,
up to ``τs`` frames past the last one, drawing its views from a shuffled stack of the trained frames'
views; at the first view of the newest frames after each growth that adds keyframes and after
``make_dynamic_interval`` more iterations, and every
``extract_every`` iterations until the densification ends, the static Gaussians that drift most
relative to their distance to the camera become dynamic. A per-Gaussian
error is accumulated by back-tracking the per-pixel L1 / SSIM maps through the splatting weights
(Ex4DGS's "flow" trick: a zero per-Gaussian probe splatted as extra channels whose image gradient is
replaced by the error maps) and drives the keyframe initialisation time and error pruning. The
rasteriser is the 0.1-dilation antialiased mode; RAdam; random background while training.

Sources: ``juno181/Ex4DGS`` @ 7fac649 (``scene/c_gaussian_model.py``, ``utils/interpolations.py``,
``train.py``, ``arguments/__init__.py``, ``configs/N3V/n3v_base.json``); ``specs/experts_noncanonical.md``
section 2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene, View
from moegs.experts.base import (
    NEAR_3DGS,
    QUICK_ITERATIONS,
    DatasetPreset,
    Expert,
    ExpertConfig,
    ParamGroup,
    SplatInputs,
    clip_camera,
    splat_param_groups,
)
from moegs.experts.gaussian_params import active_sh_degree, init_splats, sh_coeffs
from moegs.experts.static import QUICK_POINTS, scene_points, thin_points
from moegs.gaussians import GaussianFrame
from moegs.metrics.ssim import ssim_map
from moegs.render import RenderOutput, rasterize
from moegs.render.projection import eval_sh, quat_to_rotmat, view_dirs
from moegs.train.config import TrainConfig
from moegs.train.set_optim import row_sets
from moegs.train.strategy import NEVER, ADCStrategy, Strategy, ops

STATS = ("err_sum", "ssim_sum", "err_count", "err_min", "err_min_time", "radius_min")
"""Back-tracking statistics kept as non-trainable per-Gaussian entries of ``splats`` (so densification
keeps them aligned): sums of per-view L1 / SSIM and views counted since the last densification, lowest L1
and its frame (-1: never seen with weight > 0.01 since creation), smallest screen radius since the last
densification."""
FRESH = {
    "err_sum": 0.0,
    "ssim_sum": 0.0,
    "err_count": 0.0,
    "err_min": 1000.0,
    "err_min_time": -1.0,
    "radius_min": 1000.0,
}
"""Values of the statistics of a new Gaussian (``densification_postfix`` / split children)."""
RESET_AT_DENSIFY = ("err_sum", "ssim_sum", "err_count", "radius_min")
"""Statistics every densification restarts (``c_gaussian_model.py:830-844,866-872``)."""


# -- formulas ----------------------------------------------------------------------------------------
def keyframe_position(t: float, shift: float, interval: int) -> tuple[int, float]:
    """``(k, δ)`` for frame ``t``: ``u = t + shift``, ``k = ⌊u / I⌋``, ``δ = (u mod I) / I``."""
    u = t + shift
    return int(u // interval), (u % interval) / interval


def catmull_rom(points: Tensor, k: int, delta: float) -> Tensor:
    """Cubic Hermite through ``P_k, P_{k+1}`` with tangents ``(P_{k+1} - P_{k-1}) / 2`` and
    ``(P_{k+2} - P_k) / 2`` (Ex4DGS ``cube_interpolate``). ``points [M, K, 3]`` -> ``[M, 3]``."""
    if not 1 <= k <= points.shape[1] - 3:
        raise ValueError(
            f"keyframe {k} needs neighbours k-1..k+2 inside 0..{points.shape[1] - 1}; "
            "the time lies outside the keyframe range"
        )
    p0, p1, p2, p3 = (points[:, k + i] for i in (-1, 0, 1, 2))
    d2, d3 = delta**2, delta**3
    h00, h10, h01, h11 = 2 * d3 - 3 * d2 + 1, d3 - 2 * d2 + delta, -2 * d3 + 3 * d2, d3 - d2
    return h00 * p1 + h10 * (p2 - p0) / 2 + h01 * p2 + h11 * (p3 - p1) / 2


def slerp(q0: Tensor, q1: Tensor, delta: float) -> Tensor:
    """Ex4DGS ``quat_slerp_interp_uniiterval``: normalised inputs, cosine clamped to ±(1 - 1e-4), weights
    ``sin((1-δ)Ω) / sinΩ`` and ``sin(δΩ) / sinΩ`` renormalised to sum 1, **no** shortest-arc flip.
    ``q0, q1 [M, 4]`` -> ``[M, 4]`` unit quaternions."""
    q0 = q0 / q0.norm(dim=-1, keepdim=True)
    q1 = q1 / q1.norm(dim=-1, keepdim=True)
    cos = (q0 * q1).sum(-1, keepdim=True).clamp(-1 + 1e-4, 1 - 1e-4)
    omega = torch.acos(cos).clamp_min(1e-4)
    sin = torch.sin(omega).clamp_min(1e-4)
    w0, w1 = torch.sin((1 - delta) * omega) / sin, torch.sin(delta * omega) / sin
    total = (w0 + w1).clamp_min(1e-4)
    q = q0 * (w0 / total) + q1 * (w1 / total)
    q = torch.where(q.abs().sum(-1, keepdim=True) > 1e-4, q, q0)
    return q / q.norm(dim=-1, keepdim=True)


def temporal_opacity(centers: Tensor, log_widths: Tensor, t: float, var_min: float) -> Tensor:
    """Ex4DGS ``time_bigaussian`` at keyframe-unit time ``t`` (``(frame + τs) / I``), taken literally.

    Between the centres ``c0, c1`` the factor is 1; elsewhere ``exp(-m² / (e^v + var_min / 2.36)²)`` with
    ``m = min_k (t - c_k)`` and ``v`` the right width if ``t`` exceeds either centre, else the left one.
    ``centers, log_widths [M, 2]`` -> ``[M]``.
    """
    m = (t - centers).min(dim=1).values
    v = torch.where((t > centers).any(dim=1), log_widths[:, 1], log_widths[:, 0])
    factor = torch.exp(-(m**2) / (torch.exp(v) + var_min / 2.36) ** 2)
    inside = (centers[:, 0] - t) * (centers[:, 1] - t) < 0
    return torch.where(inside, torch.ones_like(factor), factor)


def keyframe_count(duration: float, shift: float, interval: int) -> int:
    """Keyframes covering ``duration`` frames (Ex4DGS first extraction: ``⌈(D + 2 τs + 1) / I⌉ + 3``)."""
    return math.ceil((duration + 2 * shift + 1) / interval) + 3


def grown_keyframe_count(model_duration: int, shift: float, time_pad: int, interval: int) -> int:
    """Keyframes a growth to ``model_duration`` requires (``expand_duration``'s ``require_dim``:
    ``⌈(D + τs + 2 pad + 1) / I⌉ + 3``, not the first extraction's formula)."""
    return math.ceil((model_duration + shift + 2 * time_pad + 1) / interval) + 3


def initial_keyframes(x: Tensor, d: Tensor, interval: int, duration: float, count: int) -> Tensor:
    """Keyframes of converted static Gaussians: the two points ``x - d I / D`` and ``x + d (1 + I / D)``
    linearly resized to ``count`` samples (``F.interpolate``, ``align_corners=False``, as the original).
    ``x, d [M, 3]`` -> ``[M, count, 3]``."""
    ends = torch.stack([x - d * interval / duration, x + d * (1 + interval / duration)], dim=2)  # [M, 3, 2]
    return nn.functional.interpolate(ends, size=count, mode="linear").transpose(1, 2)


def extrapolate_keyframes(keys: Tensor, valid: int, average: int = 4) -> Tensor:
    """Keyframes ``valid..K-1`` replaced by a linear extrapolation from the last valid one, as Ex4DGS's
    ``lin_interp_last`` (``c_gaussian_model.py:1264-1269``): its step is the mean offset of the last
    ``a = average`` valid keyframes from the one before them, ``mean_j (P_{v-j} - P_{v-a-1})``, which is
    ``(a + 1) / 2`` times the step of a straight line. ``keys [M, K, C]`` -> ``[M, K, C]``."""
    total = keys.shape[1]
    if valid >= total:
        return keys
    average = max(1, min(average, valid - 1))
    step = (keys[:, valid - average : valid] - keys[:, valid - average - 1 : valid - average]).mean(
        dim=1, keepdim=True
    )
    n = torch.arange(1, total - valid + 1, device=keys.device, dtype=keys.dtype).view(1, -1, 1)
    return torch.cat([keys[:, :valid], keys[:, valid - 1 : valid] + n * step], dim=1)


# -- config ----------------------------------------------------------------------------------------------
N3V_NEAR = 4.0
"""Ex4DGS's N3V near plane, in N3V's world frame (``configs/N3V/n3v_base.json:16``)."""


@dataclass
class Ex4DGSConfig(ExpertConfig):
    """Ex4DGS hyperparameters. Defaults: N3V (``configs/N3V/n3v_base.json`` over
    ``arguments/__init__.py``)."""

    sh_degree: int = 3
    max_init_points: int | None = None
    """Keep at most this many initial points (Ex4DGS: first-frame sparse SfM only)."""
    interval: int = 10
    """Frames between keyframes (``time_interval``)."""
    time_pad: int = 2
    """``time_pad``: 2 on N3V, 3 on Technicolor; ``τs = time_pad + interval``."""
    var_pad: float = 3.0
    """Minimum temporal width in frames (``var_pad``; ``v_min = var_pad / I``)."""
    start_duration: int = 10
    """Frames trained before the first growth (``start_duration``)."""
    grow_from: int = 500
    """Growths and conversions only after this iteration (``extract_from_iter``); the first growth also waits
    one ``grow_every`` (``train.py:262``)."""
    grow_every: int = 400
    """Iterations between growths by ``interval`` frames (``progressive_growing_steps``, N3V 400)."""
    make_dynamic_interval: int = 100
    """Arms a conversion at this offset into a growth period while ``need_extract`` holds: after each growth
    that adds keyframes, and once before the first conversion (it starts true) (``make_dynamic_interval``:
    N3V and every Technicolor config 100, ``configs/N3V/n3v_base.json:27``; ``train.py:257-259, 269-274``;
    the ``~need_extract`` of ``:262`` is always true)."""
    extract_every: int = 3980
    """Extra static-to-dynamic conversions with the step's view while a time bin has errors
    (``extracton_interval``, N3V 3980), only while densifying and not at a densification step (the
    ``elif`` inside ``if iteration < densify_until_iter``, ``train.py:203, 217, 228-232``)."""
    extract_percentile: float = 0.98
    """Quantile of the drift score above which visible static Gaussians become dynamic (Train 0.99)."""
    static_reg: float = 1e-4
    """Weight of ``mean log(||d|| + 0.001)`` (after ``reg_from``)."""
    motion_reg: float = 1e-4
    """Weight of ``mean ||P_0 - P_k||`` over dynamic keyframes (after ``reg_from``)."""
    reg_from: int = 500
    random_background: bool | None = None
    """Random background colour per training render (``random_background``); evaluation uses the scene's.
    None = on for multi-view captures only: on monocular data composited on a synthetic background
    (D-NeRF) the ground truth cannot follow a random background (deviation; Ex4DGS has no such data)."""
    spatial_lr_scale: float | None = None
    """Multiplier of the position learning rates; None = scene extent (``cameras_extent``)."""
    means_lr: float = 1.6e-4
    means_lr_final: float = 1.6e-6
    means_lr_max_steps: int = 30_000
    motion_means_lr: float = 1.6e-4
    """Keyframe positions, times the extent, **constant** (the original schedule never runs)."""
    sh0_lr: float = 2.5e-3
    """SH DC of the static set (``feature_lr``, ``c_gaussian_model.py:432``)."""
    shN_lr: float = 2.5e-3 / 20
    motion_sh0_lr: float = 2.5e-3
    """SH DC of the dynamic set (``feature_motion_lr``, ``c_gaussian_model.py:440``; Technicolor Birthday,
    Painter and Train: 2.5e-4)."""
    motion_shN_lr: float = 2.5e-3 / 20
    """Higher SH bands of the dynamic set (``feature_motion_lr / 20``, ``c_gaussian_model.py:441``)."""
    opacities_lr: float = 0.05
    motion_opacities_lr: float = 0.01
    scales_lr: float = 5e-3
    quats_lr: float = 1e-5
    """Static rotation (1e-5, the code default ``arguments/__init__.py:104``; no config sets it)."""
    motion_quats_lr: float = 1e-3
    drift_lr: float = 1e-4
    centers_lr: float = 0.01
    widths_lr: float = 1e-4
    optimizer: str = "radam"
    """Optimiser of every group: ``torch.optim.RAdam(l, lr=0.001)`` in ``c_gaussian_model.py``."""
    optimizer_eps: float = 1e-8
    """The optimiser's eps (torch's RAdam default, which the original keeps)."""
    adjust_every: int = 1200
    """Widen the temporal widths near the ends and clamp the centres every this many iterations ..."""
    adjust_until: int = 27_000
    """... until here (``adjust_temp_opa``)."""
    near: float | None = NEAR_3DGS
    """Near plane of training and evaluation renders: its rasterizer culls at view depth ``<= min_depth``
    (``submodules/diff_gaussian_rasterization_df/cuda_rasterizer/auxiliary.h:284``), the dataset's
    ``near`` (``gaussian_renderer/__init__.py:55``, ``train.py:138``, ``render.py:135-138``): 0.2 by
    default (``arguments/__init__.py``), N3V 4.0 in its world frame (``configs/N3V/n3v_base.json:16``),
    Technicolor 0.01 (``configs/techni/*.json``)."""
    far: float | None = 300.0
    """Far plane of training and evaluation renders: the rasterizer also culls at view depth ``> max_depth``
    (``auxiliary.h:284``), the dataset's ``far`` (``gaussian_renderer/__init__.py:56``, ``train.py:138``,
    ``render.py:135-138``): 300 by default (``arguments/__init__.py:75``, ``configs/N3V/n3v_base.json:17``),
    100 on Technicolor Fabien and Theater (``configs/techni/Fabien.json:14``, ``Theater.json:14``), where
    the original's units are radius-normalised and ours are not (see ``paper_technicolor``). The
    stand-ins, D-NeRF and Panoptic put their cameras within 5 units of the scene: 300 culls nothing there."""
    strategy: Strategy = field(default_factory=lambda: Ex4DGSStrategy())
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=40_000, lambda_dssim=0.2))
    """N3V: 40k iterations, 0.8 L1 + 0.2 D-SSIM."""

    def __post_init__(self) -> None:
        if isinstance(self.strategy, Ex4DGSStrategy):
            self.strategy.interval = self.interval

    @property
    def shift(self) -> int:
        """``τs = time_pad + interval`` (the cubic interpolation's extra keyframe in front)."""
        return self.time_pad + self.interval

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "n3v": DatasetPreset("paper-n3v", "configs/N3V/n3v_base.json over arguments/__init__.py"),
        "technicolor": DatasetPreset(
            "paper-technicolor", "configs/techni/*.json (time_pad 3; per-scene values)"
        ),
    }
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "white"}
    """Evaluation on white (``render.py:131``); training draws a random background per iteration."""
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {
        "n3v": {
            "resample": "bilinear",  # utils/general_utils.py:23 PILtoTorch(..., resample=2): bilinear
            "points": "sparse",  # scene/dataset_readers.py:558-566 colmap_<start>/sparse/0 of the start frame
        },
        # scene/dataset_readers.py:445, 492-501: colmap_<start_timestamp>/sparse/0, the start frame's points
        "technicolor": {"points": "sparse"},
    }
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {
        # configs/techni/<Scene>.json: densification_interval, densify_until, extract_from_iter, lrs,
        # progressive_growing_steps, extracton_interval, extract_percentile, thresholds, static_reg;
        # adjust_temp_opa runs every 4 densification intervals until densify_until - 3000 (train.py:233-234)
        "technicolor:birthday": {
            "motion_sh0_lr": 2.5e-4,
            "motion_shN_lr": 2.5e-4 / 20,
            "strategy.densify_every": 250,
            "motion_opacities_lr": 1e-4,
            "widths_lr": 1e-3,
            "grow_every": 350,
            "extract_every": 1777,
            "strategy.grad_threshold": 1.5e-4,
            "strategy.dynamic_grad_threshold": 7e-5,
            "reg_from": 450,
            "adjust_every": 1000,
        },
        "technicolor:fabien": {
            "grow_from": 1000,
            "motion_opacities_lr": 0.05,
            "static_reg": 2e-4,
            "far": 100.0,
        },
        "technicolor:painter": {
            "motion_sh0_lr": 2.5e-4,
            "motion_shN_lr": 2.5e-4 / 20,
            "train.iterations": 30_000,
            "strategy.densify_until": 25_000,
            "motion_opacities_lr": 1e-4,
            "widths_lr": 1e-3,
            "strategy.grad_threshold": 2.5e-4,
            "strategy.dynamic_grad_threshold": 8e-5,
            "static_reg": 2e-4,
            "adjust_until": 22_000,
        },
        "technicolor:theater": {
            "grow_from": 1000,
            "motion_opacities_lr": 0.05,
            "strategy.grad_threshold": 2.5e-4,
            "strategy.dynamic_grad_threshold": 8e-5,
            "static_reg": 2e-4,
            "far": 100.0,
        },
        "technicolor:train": {
            "motion_sh0_lr": 2.5e-4,
            "motion_shN_lr": 2.5e-4 / 20,
            "strategy.densify_every": 200,
            "motion_opacities_lr": 1e-4,
            "widths_lr": 1e-3,
            "grow_every": 300,
            "extract_every": 4777,
            "extract_percentile": 0.99,
            "strategy.grad_threshold": 1e-4,
            "strategy.dynamic_grad_threshold": 8e-5,
            "static_reg": 2e-4,
            "reg_from": 400,
            "adjust_every": 800,
        },
    }

    @classmethod
    def paper_n3v(cls) -> Ex4DGSConfig:
        """The defaults with N3V's near plane 4.0 (see ``near``)."""
        return cls(near=N3V_NEAR)

    @classmethod
    def paper_technicolor(cls) -> Ex4DGSConfig:
        """The values all ``configs/techni/*.json`` share: ``time_pad`` 3, temporal-centre lr 1e-3, near
        plane 0.01; and 3777 iterations between extractions, which Fabien, Painter and Theater use
        (Birthday 1777 and Train 4777: ``SCENE_OVERRIDES``). Deviation: the original normalises
        Technicolor scenes by the camera radius (``scene/dataset_readers.py:484-509``; absolute-unit rates
        such as the drift lr differ)."""
        return cls(time_pad=3, centers_lr=1e-3, extract_every=3777, near=0.01)

    @classmethod
    def own_frame_fields(cls, config: Ex4DGSConfig, dataset: str, real: bool) -> dict[str, Any]:
        """N3V's near plane 4.0 holds in real N3V's world frame only; elsewhere the code's default 0.2."""
        return {"near": NEAR_3DGS} if config.near == N3V_NEAR and not (dataset == "n3v" and real) else {}

    @classmethod
    def quick_fields(cls, paper: Ex4DGSConfig) -> dict[str, Any]:
        """CPU minutes: every schedule shrunk from 40k to the static baseline's 600 iterations."""
        return {
            "max_init_points": QUICK_POINTS,
            "grow_from": 30,
            "grow_every": 30,  # 500/400 -> 30/30 so 150 D-NeRF frames are reached at ~450
            "make_dynamic_interval": 8,  # 100 of every 400 -> 8 of every 30
            # 3980 / (400 / 30) ~ 299: off the densification grid, as 3980 is off N3V's 300 (a conversion
            # step must not densify, train.py:217, 228); 300 would fall on every 50 and never convert
            "extract_every": 299,
            "reg_from": 30,
            "means_lr_max_steps": QUICK_ITERATIONS,
            # RAdam -> Adam: RAdam's variance rectification warms up over ~1/(1-β2) = 1000s of steps (plain
            # momentum SGD for 5 steps, ~5% of Adam's step at iteration 10, ~20% at 100, ~50% at 600);
            # negligible over 40k but most of a 600-step run: on mutant RAdam left 20.7 dB, Adam 25.0
            "optimizer": "adam",
            "adjust_every": 120,
            "adjust_until": int(QUICK_ITERATIONS * 0.9),
            "strategy.densify_from": 30,
            "strategy.densify_until": int(QUICK_ITERATIONS * 0.75),
            # N3V 300; every 50 densifies 8 times in the short window: measured on dnerf:mutant (quick,
            # 600 it) 24.53 dB with 6459 Gaussians vs 21.94 dB with 889 at every 100
            "strategy.densify_every": 50,
            "strategy.prune_from": int(QUICK_ITERATIONS * 0.3),
            # no small-radius pruning: 5 px at N3V's 1352x1014 is below one pixel at the quick resolution
            "strategy.small_radius": 0.0,
        }


# -- densification -----------------------------------------------------------------------------------------
@dataclass
class Ex4DGSStrategy(ADCStrategy):
    """Ex4DGS ``densify_and_prune``: 3DGS clone/split with per-set thresholds, opacity pruning at 0.01 (of
    ``sigmoid`` of each set's own logit), no resets; plus back-tracking pruning (``error_*``) and removal
    of Gaussians never seen with weight > 0.01 since creation (``err_min_time < 0``) or thinner than
    ``small_radius`` pixels since the last densification.

    Split children of dynamic Gaussians move every keyframe by the same local offset (drawn with twice the
    scale, ``c_gaussian_model.py:925``) rotated by that keyframe's rotation, get centres jittered by
    ``max(|c1 - c0| / 3, 2 / I) N(0, 1)`` and log-widths 2; clones of dynamic Gaussians get the same
    jitter and widths (``:1002-1007``). Split children start with fresh back-tracking statistics, clones
    copy them, and every densification restarts the per-interval ones (``RESET_AT_DENSIFY``). Jittered
    centres are clamped to the bound expert's ``center_bounds`` (``:944, 1006``).
    """

    densify_from: int = 500
    densify_until: int = 30_000
    densify_every: int = 300
    grad_threshold: float = 2e-4
    """Static sets (``densify_grad_threshold``)."""
    dynamic_grad_threshold: float = 1e-4
    prune_opacity: float = 0.01
    reset_every: int = NEVER
    """Ex4DGS never calls its ``reset_opacity``."""
    reset_at_densify_from_if_white: bool = False
    error_prune_from: int = NEVER
    """Back-tracking pruning every 5 densification intervals after this: mean L1 > ``error_l1`` or
    0 < mean SSIM < ``error_ssim``. Never in the original: clone/split zero the accumulators just before
    the rule reads them (``c_gaussian_model.py:830-872`` vs ``1040-1063``); a step turns it on."""
    error_l1: float = 0.08
    error_ssim: float = 0.6
    prune_from: int = 6000
    """``prune_invisible`` / ``prune_small`` at the first iteration of each pass over the training views
    that starts after this (``prune_invisible_interval``, ``arguments/__init__.py:127``;
    ``train.py:117-122, 237-241``, outside the ``densify_until_iter`` block), keeping the densification
    statistics of the rest (``prune_points`` masks them). The expert reports the passes (``start_pass``)
    but the last step's. The original also requires iteration > 3000, which a ``prune_from`` of 6000
    implies."""
    small_radius: float = 5.0
    interval: int = 10
    """Keyframe interval (copied from the config by the expert)."""

    @torch.no_grad()
    def _split(self, params, optimizers, mask: Tensor) -> None:
        index = mask.nonzero(as_tuple=True)[0]
        keep = torch.nonzero_static(~mask, size=mask.shape[0] - index.shape[0])[:, 0]
        dynamic = params["dynamic"][index]
        scales = torch.exp(params["scales"][index])  # [M, 3]
        spread = torch.where(dynamic, 2.0, 1.0)[:, None] * scales  # dynamic: std 2 s
        local = torch.randn(self.split_samples, len(index), 3, device=scales.device) * spread  # [S, M, 3]
        static_rot = quat_to_rotmat(nn.functional.normalize(params["quats"][index], dim=-1))  # [M, 3, 3]
        key_rot = quat_to_rotmat(
            nn.functional.normalize(params["motion_quats"][index], dim=-1)
        )  # [M, K, 3, 3]
        jitter = self._jitter(params["centers"][index])

        def children(key: str, v: Tensor) -> Tensor:
            parents = v[index]
            if key == "means":
                kids = (parents[None] + torch.einsum("mij,smj->smi", static_rot, local)).reshape(-1, 3)
            elif key == "motion_means":
                kids = (parents[None] + torch.einsum("mkij,smj->smki", key_rot, local)).flatten(0, 1)
            elif key == "scales":
                kids = torch.log(scales / self.split_scale_divisor).repeat(self.split_samples, 1)
            elif key == "centers":
                moved = parents[None] + jitter[None, :, None] * torch.randn(
                    self.split_samples, *parents.shape, device=parents.device
                )
                moved = moved.clamp(*self._expert.center_bounds())
                kids = torch.where(dynamic[None, :, None], moved, parents[None]).flatten(0, 1)
            elif key == "widths":
                kids = torch.where(dynamic[:, None], torch.full_like(parents, 2.0), parents).repeat(
                    self.split_samples, 1
                )
            elif key in FRESH:
                kids = v.new_full((self.split_samples * len(index),), FRESH[key])
            else:
                kids = parents.repeat(self.split_samples, *([1] * (v.ndim - 1)))
            return torch.cat([v[keep], kids])

        def moments(key: str, v: Tensor) -> Tensor:
            return torch.cat([v[keep], v.new_zeros((self.split_samples * len(index), *v.shape[1:]))])

        ops.update_params(params, optimizers, children, moments)

    def _jitter(self, centers: Tensor) -> Tensor:
        """Std of the centre jitter of new dynamic Gaussians ``[M]``: ``max(|c1 - c0| / 3, 2 / I)``."""
        return torch.maximum(
            (centers[:, 1] - centers[:, 0]).abs() / 3, torch.full_like(centers[:, 0], 2.0 / self.interval)
        )

    @torch.no_grad()
    def _clone(self, params, optimizers, mask: Tensor) -> None:
        """3DGS clone; copies of dynamic Gaussians get jittered centres and log-widths 2."""
        n = params["means"].shape[0]
        ops.duplicate(params, optimizers, mask)
        copies = torch.arange(n, params["means"].shape[0], device=mask.device)
        dynamic = params["dynamic"][copies]
        if bool(dynamic.any()):
            rows = copies[dynamic]
            c = params["centers"].data[rows]
            jittered = c + self._jitter(c)[:, None] * torch.randn_like(c)
            params["centers"].data[rows] = jittered.clamp(*self._expert.center_bounds())
            params["widths"].data[rows] = 2.0

    @torch.no_grad()
    def _densify_and_prune(self, params, optimizers, state: dict, step: int) -> None:
        extent = state["scene_scale"]
        grads = state["grad2d"] / state["count"].clamp(min=1)
        dynamic = params["dynamic"]
        threshold = torch.where(dynamic, self.dynamic_grad_threshold, self.grad_threshold)
        small = torch.exp(params["scales"]).max(dim=1).values <= self.percent_dense * extent
        candidates = grads >= threshold
        clone, to_split = candidates & small, candidates & ~small
        self._clone(params, optimizers, clone)
        self._split(params, optimizers, torch.cat([to_split, to_split.new_zeros(int(clone.sum()))]))
        prune = base_opacity(params) < self.prune_opacity
        if step > self.error_prune_from and step % (5 * self.densify_every) == 0:
            count = params["err_count"].clamp_min(1)
            l1, ssim = params["err_sum"] / count, params["ssim_sum"] / count
            prune |= (params["err_count"] > 0) & (
                (l1 > self.error_l1) | ((ssim > 0) & (ssim < self.error_ssim))
            )
        self._remove_and_record(params, optimizers, state, clone, to_split, prune)
        for key in RESET_AT_DENSIFY:
            params[key].data.fill_(FRESH[key])

    def __post_init__(self) -> None:
        # training state, not config: the step that started the current pass, and the expert (``bind``)
        self._pass_start = -1
        self._expert: Ex4DGSExpert | None = None

    def bind(self, expert: Ex4DGSExpert) -> Ex4DGSStrategy:
        """Run ``expert``'s schedule events in this strategy's step hooks, where the original runs them
        around the optimiser step (``after_backward``, ``after_update``); returns this strategy."""
        self._expert = expert
        return self

    def start_pass(self, step: int) -> None:
        """Step ``step`` starts a pass over the training views (the original refills its view stack)."""
        self._pass_start = step

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        """``train.py:203-241`` in order: densification, else the interval conversion; ``adjust_temp_opa``;
        pruning at a pass start."""
        super().step_post_backward(params, optimizers, state, step, info)
        if self._expert is not None and self._expert.after_backward(step, optimizers):
            self._restart_dynamic_stats(params, state)
        if self.prune_from < step and step == self._pass_start:
            seen = params["err_min_time"] >= 0
            thin = params["radius_min"] < self.small_radius
            self._remove_keeping_stats(params, optimizers, state, ~seen | thin)

    def step_post_optimizer(self, params, optimizers, state, step: int, info: dict) -> None:
        super().step_post_optimizer(params, optimizers, state, step, info)
        if self._expert is not None and self._expert.after_update(step, optimizers):
            self._restart_dynamic_stats(params, state)

    @staticmethod
    def _restart_dynamic_stats(params, state: dict) -> None:
        """A conversion restarts the dynamic set's densification statistics
        (``c_gaussian_model.py:1213-1220``)."""
        if state["grad2d"] is None:
            return
        dynamic = params["dynamic"]
        for key in ("grad2d", "count", "max_radii"):
            state[key] = state[key].masked_fill(dynamic, 0)


def base_opacity(params) -> Tensor:
    """``sigmoid`` of each Gaussian's own set's opacity logit ``[N]`` (no temporal factor)."""
    return torch.sigmoid(torch.where(params["dynamic"], params["motion_opacities"], params["opacities"]))


# -- expert ------------------------------------------------------------------------------------------------
class Ex4DGSExpert(Expert):
    """Ex4DGS: static (drift) and dynamic (keyframe) Gaussians in one ``splats`` with a ``dynamic`` flag."""

    name = "ex4dgs"
    config_class = Ex4DGSConfig

    def __init__(
        self,
        config: Ex4DGSConfig,
        splats: nn.ParameterDict,
        spatial_lr_scale: float,
        first_time: float,
        frame_step: float,
        num_frames: int,
        extent: float,
        multiview: bool,
        num_views: int,
    ) -> None:
        super().__init__(config, splats)
        self.spatial_lr_scale = spatial_lr_scale
        self.first_time, self.frame_step, self.num_frames, self.extent = (
            first_time,
            frame_step,
            num_frames,
            extent,
        )
        self.random_background = (
            config.random_background if config.random_background is not None else multiview
        )
        self.num_views = num_views
        # the schedule's state, on the host (``get_extra_state`` checkpoints it)
        self.duration = float(min(config.start_duration, num_frames))  # the sampling length, in frames
        self.need_extract = True  # arms the next make_dynamic_interval step
        self.view_stack: list[int] = []  # the shuffled pass: views of view_stack[:pass_left] left to draw
        self.pass_left = 0
        self.convert_newest = False  # ``mark_last``
        self.keyframes = 0  # ``keyframe_num``: 0 until the first conversion
        self.register_buffer("bin_errors", torch.zeros(math.ceil(num_frames / config.interval), 2))
        self.active_sh_degree = 0
        self._probe: tuple[Tensor, Tensor, float] | None = None  # (probe image, per-Gaussian probe, frame)
        self._view_frames: tuple[list[View], list[int]] | None = None  # (views, each one's frame)
        self._step_view: View | None = None  # the step's first view: the interval conversion's
        self._armed_view: View | None = None  # ``mark_extract``: the armed conversion's, after the update
        self._backend = "auto"  # the training renders' rasterizer, which the conversions' renders use too

    @classmethod
    def from_scene(cls, scene: Scene, config: Ex4DGSConfig) -> Ex4DGSExpert:
        times = scene.times
        step = float((times[1:] - times[:-1]).median()) if len(times) > 1 else 1.0
        points = thin_points(scene_points(scene), config.max_init_points, config.train.seed)
        n = len(points)
        last = scene.num_frames + config.shift  # the longest sampling length (growths stop there)
        k = max(  # room for the most keyframes a conversion or a growth can ask for
            keyframe_count(last, config.shift, config.interval),
            grown_keyframe_count(last + 1, config.shift, config.time_pad, config.interval),
        )
        stats = {
            "err_sum": torch.zeros(n),
            "ssim_sum": torch.zeros(n),
            "err_count": torch.zeros(n),
            "err_min": torch.full((n,), 1000.0),
            "err_min_time": torch.full((n,), -1.0),
            "radius_min": torch.full((n,), 1000.0),
        }
        extra = {
            "drift": torch.zeros(n, 3),
            "motion_means": points.xyz.float()[:, None].repeat(1, k, 1),
            "motion_quats": torch.tensor([1.0, 0, 0, 0]).repeat(n, k, 1),
            "motion_opacities": torch.logit(torch.full((n,), 0.1)),
            "centers": torch.zeros(n, 2),
            "widths": torch.zeros(n, 2),
        }
        splats = init_splats(points, config.sh_degree, extra=extra)
        for key, value in {"dynamic": torch.zeros(n, dtype=torch.bool), **stats}.items():
            splats[key] = nn.Parameter(value, requires_grad=False)
        scale = config.spatial_lr_scale if config.spatial_lr_scale is not None else scene.extent
        return cls(
            config,
            splats,
            scale,
            float(times[0]),
            step,
            scene.num_frames,
            scene.extent,
            scene.multiview,
            len(scene.train),
        )

    _SCHEDULE = ("duration", "need_extract", "view_stack", "pass_left", "convert_newest", "keyframes")

    def get_extra_state(self) -> dict:
        return {name: getattr(self, name) for name in self._SCHEDULE}

    def set_extra_state(self, state: dict) -> None:
        for name in self._SCHEDULE:
            setattr(self, name, state[name])

    # -- time ---------------------------------------------------------------------------------------------
    def frame_index(self, t: float) -> float:
        """Integer-frame time of normalised scene time ``t`` (Ex4DGS ``timestamp = j - start``)."""
        return (t - self.first_time) / self.frame_step

    def model_duration(self) -> int:
        """The Gaussians' ``duration``: one more than the sampling length ``duration`` (``expand_duration``
        stores ``int(sample_len) + 1``, from the call before training, ``train.py:75``)."""
        return int(self.duration) + 1

    def center_bounds(self) -> tuple[float, float]:
        """Range of the temporal centres of split and cloned dynamic Gaussians, in keyframes:
        ``((τs + 1) / I, (τs + D - 1) / I)`` with ``D`` the model duration (``c_gaussian_model.py:944``)."""
        c = self.config
        return (c.shift + 1) / c.interval, (c.shift + self.model_duration() - 1) / c.interval

    # -- rendering ---------------------------------------------------------------------------------------
    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        s, c = self.splats, self.config
        f = self.frame_index(t)
        means = s["means"] + s["drift"] * f / self.model_duration()
        quats = nn.functional.normalize(s["quats"], dim=-1)
        opacities = torch.sigmoid(s["opacities"])
        idx = row_sets(s["dynamic"]).second
        if idx.numel():
            k, delta = keyframe_position(f, c.shift, c.interval)
            key_q = s["motion_quats"][idx]
            means = means.index_put((idx,), catmull_rom(s["motion_means"][idx], k, delta))
            quats = quats.index_put((idx,), slerp(key_q[:, k], key_q[:, k + 1], delta))
            widths = s["widths"][idx]
            if widths.requires_grad:  # e^v overflows for the initial widths (frames): inf/inf gradients
                widths.register_hook(torch.nan_to_num)  # Ex4DGS nan_to_num's these gradients too
            temporal = temporal_opacity(
                s["centers"][idx], widths, (f + c.shift) / c.interval, c.var_pad / c.interval
            )
            opacities = opacities.index_put((idx,), torch.sigmoid(s["motion_opacities"][idx]) * temporal)
        return GaussianFrame(
            means=means,
            quats=quats,
            scales=torch.exp(s["scales"]),
            opacities=opacities,
            sh=sh_coeffs(s, self.active_sh_degree),
        )

    def splat_inputs(self, camera: Camera, background: Tensor | None) -> SplatInputs:
        frame = self.frame(camera.time, camera)
        return SplatInputs(frame, background, antialiased=True, near=self.config.near, far=self.config.far)

    def splat_inputs_key(self, camera: Camera) -> float:
        """Keyframe interpolation of ``t`` and SH colours: the inputs depend on the camera only through its
        time (the clipping planes apply in ``render``)."""
        return camera.time

    def render(
        self, camera: Camera, background: Tensor | None, backend: str = "auto", return_stats: bool = False
    ) -> tuple[Tensor, RenderOutput, GaussianFrame]:
        """Antialiased render (0.1 dilation). While training: random background and the back-tracking
        probe (3 extra channels, kept in the graph with zero weight; see ``observe``)."""
        camera = clip_camera(camera, self.config.near, self.config.far)
        if not self.training:
            return super().render(camera, background, backend, return_stats)
        self._backend = backend
        frame = self.frame(camera.time, camera)
        if self.random_background:
            background = torch.rand(3, device=frame.device)
        probe = torch.zeros(len(frame), 3, device=frame.device, requires_grad=True)
        rgb = eval_sh(frame.sh, view_dirs(frame.means, camera), self.active_sh_degree)
        probed = frame.with_colors(torch.cat([rgb, probe], dim=1))
        bg = torch.cat([background, background.new_zeros(3)]) if background is not None else None
        out = rasterize(
            probed, camera, background=bg, antialiased=True, return_stats=return_stats, backend=backend
        )
        probe_image = out.image[..., 3:]
        self._probe = (probe_image, probe, self.frame_index(camera.time))
        image = out.image[..., :3] + 0.0 * probe_image.sum(-1, keepdim=True)  # keeps the probe in the graph
        return image, out, frame

    # -- training hooks -----------------------------------------------------------------------------------
    def on_step(self, step: int) -> bool:
        self.active_sh_degree = active_sh_degree(
            step, self.config.sh_degree, self.config.train.sh_degree_interval
        )
        return False

    def observe(self, step: int, view: View, rgb: Tensor, target: Tensor, out: RenderOutput) -> Tensor | None:
        """Back-tracking: the probe image's gradient becomes ``[1, L1, SSIM] / acc`` per pixel, so each
        Gaussian's probe gradient is ``Σ_p w_ip [1, L1_p, SSIM_p] / acc_p``; statistics are updated when it
        arrives. Also records the view's L1 in its time bin for the interval conversion, which drops the
        worst bin (the original records the loss, ``train.py:177``; a conversion only needs a bin with
        errors, and the step's own view has just made one)."""
        if self._probe is None:
            return None
        probe_image, probe, frame = self._probe
        self._probe = None
        with torch.no_grad():
            l1_map = (rgb - target).abs().mean(-1)
            ssim_pix = ssim_map(rgb, target).mean(-1)  # unclamped, as the loss (train.py:149-150)
            acc = out.alpha.clamp_min(1e-4)
            weights = torch.stack([torch.ones_like(acc), l1_map, ssim_pix], dim=-1) / acc[..., None]
            b = min(round(frame) // self.config.interval, self.bin_errors.shape[0] - 1)  # frame k - 1e-6 is k
            self.bin_errors[b] += torch.stack([l1_map.mean(), l1_map.new_ones(())])
        probe_image.register_hook(lambda grad: weights)
        radii = out.info.get("radii")
        errors = step < self.config.strategy.densify_until
        probe.register_hook(lambda grad: self._accumulate(grad, frame, radii, errors))
        return None

    @torch.no_grad()
    def _accumulate(self, grad: Tensor, frame: float, radii: Tensor | None, errors: bool) -> None:
        """Per-Gaussian back-tracked ``grad [N, 3]`` = (weight, L1, SSIM) sums of one view: the error
        statistics when ``errors`` (``add_l1_ssim_stats``, only while densifying, ``train.py:203, 214-215``),
        the smallest radius always (``mark_prune_stats``, ``:199-200``)."""
        s = self.splats
        w = grad[:, 0]
        seen = w > 0
        if errors:
            l1 = grad[:, 1] / w.clamp_min(1e-4)
            ssim = grad[:, 2] / w.clamp_min(1e-4)
            better = seen & (w > 0.01) & (l1 < s["err_min"])
            s["err_sum"].add_(torch.where(seen, l1, 0.0))
            s["ssim_sum"].add_(torch.where(seen, ssim, 0.0))
            s["err_count"].add_(seen.float())
            s["err_min_time"].copy_(torch.where(better, frame, s["err_min_time"]))
            s["err_min"].copy_(torch.where(better, l1, s["err_min"]))
        if radii is not None:
            s["radius_min"].copy_(
                torch.where(seen, torch.minimum(s["radius_min"], radii.float()), s["radius_min"])
            )

    def select_views(
        self, step: int, views: list[View], batch_size: int, generator: torch.Generator
    ) -> list[int]:
        """Progressive schedule (``train.py:116-130``).

        Views are popped from a shuffled stack of the views of the frames trained so far (frame index up
        to the sampling length ``duration``, inclusive: ``scene/__init__.py:271``); an empty stack is
        refilled, which starts a pass (the strategy's pruning clock). A conversion armed by an earlier
        step (``after_update``) is due at the first popped view of the newest ``interval`` frames and runs
        after this step's update. The step's first view is the interval conversion's (``after_backward``).
        """
        frames = self._frames(views)
        picked = [self._pop(step, frames, generator) for _ in range(batch_size)]
        newest = [i for i in picked if frames[i] >= self.duration - self.config.interval]
        self._step_view, self._armed_view = views[picked[0]], None
        if self.convert_newest and newest:
            self._armed_view = views[newest[0]]
            self.convert_newest = False
        return picked

    def _frames(self, views: list[View]) -> list[int]:
        """Each training view's frame index (views sit on frames); computed once per view list."""
        if len(views) != self.num_views:
            raise ValueError(
                f"Ex4DGS was built for {self.num_views} training views, select_views got {len(views)}"
            )
        if self._view_frames is None or self._view_frames[0] is not views:
            self._view_frames = (views, [round(self.frame_index(v.camera.time)) for v in views])
        return self._view_frames[1]

    # -- schedule events, run by the bound strategy (``Ex4DGSStrategy.bind``) -----------------------------
    # The original rewrites its optimiser's tensors in these events (``replace_tensor_to_optimizer``,
    # ``cat_tensors_to_optimizer``, ``prune_points``): the rewritten rows' moments restart at zero, and a
    # tensor rewritten between the backward pass and the update misses that update. ``_restart`` does both.
    def after_backward(self, step: int, optimizers: dict) -> bool:
        """After ``step``'s backward pass, before its update (``train.py:228-234``): the interval conversion
        with the step's view, which rewrites every tensor (the step updates nothing), then
        ``adjust_temp_opa``, which rewrites the temporal centres and widths. Returns whether it converted."""
        c = self.config
        extracts = self._extracts(step)
        if extracts:
            mean = self.bin_errors[:, 0] / self.bin_errors[:, 1].clamp_min(1)
            self.bin_errors[int(mean.argmax())] = 0  # ``get_errorneous_timestamp`` drops the worst bin
            self._restart(optimizers, rows=self.convert(self._step_view.camera))
        if c.adjust_every and step % c.adjust_every == 0 and step < c.adjust_until:
            self._adjust_temporal_opacity(optimizers)
        return extracts

    def after_update(self, step: int, optimizers: dict) -> bool:
        """After ``step``'s update (``train.py:257-283``): at ``make_dynamic_interval`` into a growth period
        while ``need_extract`` holds, arm a conversion; every ``grow_every`` iterations after
        ``max(grow_from, grow_every)``, grow, and arm one (and ``need_extract``) when the growth added
        keyframes; run the conversion due at this step with its view, and return whether it ran. The loop
        skips the last step's update and this with it: in the original, that step's growth or conversion
        comes after the model is saved."""
        c = self.config
        if step > c.grow_from and step % c.grow_every == c.make_dynamic_interval and self.need_extract:
            self.convert_newest, self.need_extract = True, False
        if step > max(c.grow_from, c.grow_every) and step % c.grow_every == 0 and self._grow(optimizers):
            self.convert_newest, self.need_extract = True, True
        armed, self._armed_view = self._armed_view, None
        if armed is not None:
            self._restart(optimizers, rows=self.convert(armed.camera))
        return armed is not None

    def _restart(self, optimizers: dict, rows: Tensor | None = None, keys: list[str] | None = None) -> None:
        """Rewrite ``keys`` (default: every tensor) as the original's optimiser does: zero their moments on
        ``rows [M]`` (None: all rows) and drop their gradients, so an update that follows skips them."""
        ops.update_params(
            self.splats,
            optimizers,
            lambda key, v: v,
            lambda key, v: torch.zeros_like(v) if rows is None else v.index_fill(0, rows, 0),
            keys=keys,
        )

    def _pop(self, step: int, frames: list[int], generator: torch.Generator) -> int:
        """The next view of the stack (``frames``: each view's frame); refills it when empty."""
        if self.pass_left == 0:
            eligible = [i for i, frame in enumerate(frames) if frame <= self.duration]
            order = torch.randperm(len(eligible), generator=generator, device="cpu").tolist()
            self.view_stack = [eligible[i] for i in order]
            self.pass_left = len(eligible)
            strategy = self.config.strategy
            if isinstance(strategy, Ex4DGSStrategy) and step < self.config.train.iterations:  # train.py:237
                strategy.start_pass(step)
        self.pass_left -= 1
        return self.view_stack[self.pass_left]

    def _extracts(self, step: int) -> bool:
        """Whether ``step`` runs the ``extracton_interval`` conversion (``train.py:217, 228-232``: the
        ``elif`` of a densification step, inside ``iteration < densify_until_iter``)."""
        c, strategy = self.config, self.config.strategy
        return bool(
            c.extract_every
            and step > c.grow_from
            and step % c.extract_every == 0
            and step < strategy.densify_until
            and not strategy.densifies(step)
            and self.bin_errors[:, 1].any()
        )

    @torch.no_grad()
    def _grow(self, optimizers: dict) -> bool:
        """Extend the sampling length by ``interval`` frames, up to ``τs`` past the last frame
        (``train.py:263-268``), and the model's duration with it (``expand_duration``). Returns whether
        keyframes were added, which needs dynamic Gaussians and a higher ``grown_keyframe_count``: the new
        ones extrapolate the mean step of the last ``min(K - 2, 4)``; a right temporal width whose centre
        (plus ``τs / I``, as the original) lies within half a keyframe of the new end becomes 1, and the
        centres are clamped to the old duration's last keyframe time. The keyframes and temporal
        opacities restart their moments (``replace_tensor_to_optimizer``)."""
        c, s = self.config, self.splats
        length = min(self.num_frames + c.shift, int(self.duration) + c.interval)
        if length <= self.duration:
            return False
        old = self.model_duration()
        self.duration = float(length)
        new = self.model_duration()
        have, need = self.keyframes, grown_keyframe_count(new, c.shift, c.time_pad, c.interval)
        idx = row_sets(s["dynamic"]).second
        if not idx.numel() or need <= have:
            return False
        average = min(have - 2, 4)
        for key in ("motion_means", "motion_quats"):
            s[key].data[idx] = extrapolate_keyframes(s[key].data[idx], have, average)
        centers, widths = s["centers"].data[idx], s["widths"].data[idx]
        near_end = (centers + c.shift / c.interval > (new + c.shift) / c.interval - 0.5).any(dim=1)
        widths[:, 1].masked_fill_(near_end, 1.0)
        s["widths"].data[idx] = widths
        s["centers"].data[idx] = centers.clamp_max((c.shift + old - 1) / c.interval)
        self.keyframes = need
        self._restart(optimizers, keys=["motion_means", "motion_quats", "centers", "widths"])
        return True

    @torch.no_grad()
    def convert(self, camera: Camera) -> Tensor:
        """Static-to-dynamic conversion (``extract_dynamic_points_from_static``) of the static Gaussians
        that ``camera`` sees drift most (``_drifting``); returns their indices ``[M]``. Whatever it
        converts, the dynamic set's interval statistics restart (``c_gaussian_model.py:1213-1220``)."""
        c, s = self.config, self.splats
        duration = max(self.duration, float(c.interval))
        if self.keyframes == 0:  # set by the first conversion, whatever it converts; growths extend it
            self.keyframes = keyframe_count(duration, c.shift, c.interval)
        idx = self._drifting(camera)
        if idx.numel():
            self._make_dynamic(idx, duration)
        for key in RESET_AT_DENSIFY:
            s[key].data.masked_fill_(s["dynamic"], FRESH[key])
        return idx

    def _drifting(self, camera: Camera) -> Tensor:
        """Indices ``[M]`` of the visible static Gaussians whose score ``||d|| / ||x - T||²`` (``T`` the
        world-to-camera translation, as the original), over its maximum, is above the
        ``extract_percentile`` quantile, with ``||d|| > 1e-6 extent`` and a back-tracked best frame."""
        c, s = self.config, self.splats
        out = rasterize(
            self.frame(camera.time, camera).detach(),
            clip_camera(camera, c.near, c.far),
            antialiased=True,
            return_depth=False,
            return_stats=True,
            backend=self._backend,
        )
        static = ~s["dynamic"] & out.info["visible"]
        if static.sum() < 2:
            return static.new_zeros(0, dtype=torch.long)
        drift = s["drift"].norm(dim=-1)
        score = drift / ((s["means"] - camera.world_to_camera[:3, 3]).norm(dim=-1) ** 2 + 1e-6)
        score = score / (score[static].max() + 1e-6)
        threshold = torch.quantile(score[static], c.extract_percentile)
        chosen = static & (score > threshold) & (drift > 1e-6 * self.extent) & (s["err_min_time"] >= 0)
        return chosen.nonzero(as_tuple=True)[0]

    def _make_dynamic(self, idx: Tensor, duration: float) -> None:
        """Keyframes from the drift, temporal opacity from the back-tracked best frame, for ``idx [M]``."""
        c, s = self.config, self.splats
        total, valid = s["motion_means"].shape[1], self.keyframes
        keys = initial_keyframes(s["means"][idx], s["drift"][idx], c.interval, duration, valid)
        keys = torch.cat([keys, keys.new_zeros(len(idx), total - valid, 3)], dim=1)  # filled by extrapolation
        t = s["err_min_time"][idx]
        lo, hi = (c.shift + 1) / c.interval, (c.shift + duration - 1) / c.interval
        centers = torch.stack(
            [(t / 2 + c.shift) / c.interval, ((duration + t) / 2 + c.shift) / c.interval], dim=1
        )
        values = {
            "motion_means": extrapolate_keyframes(keys, valid),
            "motion_quats": s["quats"][idx][:, None].repeat(1, total, 1),
            "motion_opacities": s["opacities"][idx],
            "centers": centers.clamp(lo, hi),
            "widths": torch.stack([t + c.time_pad, duration - t + c.time_pad], dim=1),
        }
        for key, value in values.items():
            s[key].data[idx] = value
        s["dynamic"][idx] = True
        for key in ("err_min", "err_min_time"):  # new dynamic Gaussians start unseen (cgm:1222-1223)
            s[key].data[idx] = FRESH[key]

    @torch.no_grad()
    def _adjust_temporal_opacity(self, optimizers: dict) -> None:
        """Ex4DGS ``adjust_temp_opa``: double (at least 1) the width on a side whose centre is within 0.2
        keyframes of that end of the trained range, clamp the centres inside it, floor widths at 0.5;
        both restart their moments (``replace_tensor_to_optimizer``)."""
        c, s = self.config, self.splats
        idx = row_sets(s["dynamic"]).second
        if not idx.numel():
            return
        lo, hi = c.shift / c.interval + 0.2, (self.duration + c.shift) / c.interval - 0.2
        centers, widths = s["centers"].data[idx], s["widths"].data[idx]
        new = widths.clone()
        new[:, 1] = torch.where((centers > hi).any(dim=1), widths[:, 1].clamp_min(1) * 2, widths[:, 1])
        new[:, 0] = torch.where((centers < lo).any(dim=1), widths[:, 0].clamp_min(1) * 2, widths[:, 0])
        s["widths"].data[idx] = torch.where(widths < 0.5, torch.full_like(widths, 0.5), new)
        s["centers"].data[idx] = centers.clamp(lo, max(lo, hi))
        self._restart(optimizers, keys=["centers", "widths"])

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        c, s = self.config, self.splats
        loss = s["means"].new_zeros(())
        if step <= c.reg_from:
            return loss
        static, dynamic = row_sets(s["dynamic"])
        if static.numel():
            loss = loss + c.static_reg * torch.log(s["drift"][static].norm(dim=-1) + 0.001).mean()
        if dynamic.numel():
            keys = s["motion_means"][dynamic][:, : self.keyframes]  # train.py:159-161: K columns
            loss = loss + c.motion_reg * (keys[:, :1] - keys[:, 1:]).norm(dim=-1).mean()
        return loss

    def param_groups(self) -> list[ParamGroup]:
        c, sc, s = self.config, self.spatial_lr_scale, self.splats
        constant = [
            ("motion_means", c.motion_means_lr * sc),
            ("sh0", c.sh0_lr),
            ("shN", c.shN_lr),
            ("opacities", c.opacities_lr),
            ("motion_opacities", c.motion_opacities_lr),
            ("scales", c.scales_lr),
            ("quats", c.quats_lr),
            ("motion_quats", c.motion_quats_lr),
            ("drift", c.drift_lr),
            ("centers", c.centers_lr),
            ("widths", c.widths_lr),
        ]
        # the dynamic set counts its own steps, from the first conversion (moegs.train.set_optim)
        groups = splat_param_groups(
            s, c, sc, constant, eps=c.optimizer_eps, optimizer=c.optimizer, second_set=self._dynamic_rows
        )
        own_rates = {"sh0": c.motion_sh0_lr, "shN": c.motion_shN_lr}  # the dynamic set's colour
        return [replace(g, second_lr=own_rates[g.name]) if g.name in own_rates else g for g in groups]

    def _dynamic_rows(self) -> Tensor:
        """The ``dynamic`` flags ``[N]`` of the current splats (densification replaces the tensor; a
        conversion writes it in place, so ``row_sets`` sees both)."""
        return self.splats["dynamic"]

    def strategy(self) -> Strategy:
        """The config's ``Ex4DGSStrategy``, bound to this expert: its step hooks run the conversions,
        growths and temporal-opacity adjustments (``after_backward``, ``after_update``)."""
        strategy = self.config.strategy
        if not isinstance(strategy, Ex4DGSStrategy):
            raise ValueError(
                "Ex4DGS trains with an Ex4DGSStrategy, whose step hooks run its conversions and growth; "
                f"config.strategy is a {type(strategy).__name__}"
            )
        return strategy.bind(self)
