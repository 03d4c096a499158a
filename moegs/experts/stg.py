"""STG, Spacetime Gaussian Feature Splatting (Li et al., CVPR 2024).

Each Gaussian lives around its own time ``μτ`` and moves on a polynomial. With ``Δt = t - μτ``::

    μ(t) = μ + b1 Δt + b2 Δt² + b3 Δt³           cubic polynomial per axis (motion [N, 9])
    q(t) = normalize(q + Δt ω)                    linear rotation velocity
    o(t) = sigmoid(o) exp(-(Δt / exp(sτ))²)       temporal radial-basis opacity

``Δt`` is detached in the motion, the rotation and the features, so ``μτ`` learns only through the
opacity. Colour models (``STGConfig.color``):

* ``"full"``: 9 splatted channels ``[albedo, specular, Δt · f_t]`` decoded per pixel with the camera
  rays (``stg_decoder.FeatureDecoder``; ``decode(features, camera)``);
* ``"sh"``: SH degree 3, the variant MoE-GS trained on N3V (``thirdparty/polynomial`` in MoE-GS-studio:
  RAdam, no decoder, the Ex4DGS rasteriser with its 0.1 dilation);
* ``"lite"``: raw per-Gaussian RGB (STG lite).

Time is the segment's local time ``(j - start) / D``. ``STGSegments`` answers any global time with the
model of the segment holding it (MoE-GS: two 150-frame models on N3V);
``moegs.train.segments.train_segments`` trains them with the one training loop. Each step renders two
cameras of one timestamp (STG ``batch = 2``).

Sources: ``oppo-us-research/SpacetimeGaussians`` @ 427abfc (``thirdparty/gaussian_splatting/scene/
oursfull.py``, ``renderer/__init__.py``, ``train.py``, ``helper_train.py``, ``configs/``);
``specs/experts_noncanonical.md`` section 1; ``specs/official_moegs.md`` sections 8-9.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.points import knn_mean_distance
from moegs.data.scene import PointCloud, Scene, View
from moegs.experts import stg_guided
from moegs.experts.base import (
    QUICK_ITERATIONS,
    DatasetPreset,
    Expert,
    ExpertConfig,
    ParamGroup,
    SplatInputs,
    check_keep,
    render_splat_inputs,
    splat_param_groups,
)
from moegs.experts.gaussian_params import activate, active_sh_degree, init_splats
from moegs.experts.static import QUICK_POINTS, scene_points, thin_points
from moegs.experts.stg_decoder import FeatureDecoder
from moegs.gaussians import GaussianFrame
from moegs.render import RenderOutput
from moegs.train.config import TrainConfig
from moegs.train.strategy import NEVER, ADCStrategy, Strategy, ops

COLOR_MODELS = ("full", "sh", "lite")
TIME_EPS = 1e-6  # times within this of a segment start belong to it (float32 vs float64 frame times)


# -- formulas ----------------------------------------------------------------------------------------
def polynomial_motion(means: Tensor, motion: Tensor, dt: Tensor) -> Tensor:
    """``μ + b1 Δt + b2 Δt² + b3 Δt³``; ``means [N, 3]``, ``motion [N, 9]`` = [b1, b2, b3], ``dt [N, 1]``."""
    return means + motion[:, 0:3] * dt + motion[:, 3:6] * dt**2 + motion[:, 6:9] * dt**3


def linear_rotation(quats: Tensor, omega: Tensor, dt: Tensor) -> Tensor:
    """``normalize(q + Δt ω)``; ``quats, omega [N, 4]``, ``dt [N, 1]``."""
    return nn.functional.normalize(quats + dt * omega, dim=-1)


def temporal_opacity(opacity_logits: Tensor, dt: Tensor, log_scale: Tensor) -> Tensor:
    """``sigmoid(o) exp(-(Δt / exp(sτ))²)``; all ``[N]`` (STG ``trbfunction``)."""
    return torch.sigmoid(opacity_logits) * torch.exp(-((dt / torch.exp(log_scale)) ** 2))


def segment_index(t: float, starts: list[float]) -> int:
    """Index of the segment holding normalised time ``t`` for sorted segment ``starts`` (the first
    segment also takes times before it, the last one times after its end)."""
    if not starts:
        raise ValueError("segment_index needs at least one segment")
    return max(0, bisect.bisect_right(starts, t + TIME_EPS) - 1)


def segment_bounds(times: list[float], frames_per_segment: int | None) -> list[tuple[float, float]]:
    """``[(start, stop)]`` normalised-time windows of consecutive ``frames_per_segment`` frames.

    ``times`` are the scene's sorted distinct frame times; ``stop`` is the next segment's first time
    (the last segment ends one frame step after its last frame), so local time ``(t - start) / (stop -
    start)`` is STG's ``(j - start) / D``.
    """
    if not times:
        raise ValueError("segment_bounds needs at least one time")
    step = (times[-1] - times[0]) / (len(times) - 1) if len(times) > 1 else 1.0
    size = frames_per_segment or len(times)
    if size < 1:
        raise ValueError(f"frames_per_segment must be >= 1, got {frames_per_segment}")
    starts = times[::size]
    stops = [*starts[1:], times[-1] + step]
    return list(zip(starts, stops, strict=True))


# -- config ----------------------------------------------------------------------------------------------
@dataclass
class STGConfig(ExpertConfig):
    """STG hyperparameters. Defaults: the full model with the N3V settings (``configs/n3d_full``,
    ``arguments/__init__.py``); ``color="sh"`` gives MoE-GS's N3V variant."""

    color: str = "full"
    """Colour model: ``"full"`` (features + decoder), ``"sh"`` (MoE-GS N3V) or ``"lite"`` (raw RGB)."""
    decoder_activation: str = "sigmoid"
    """Full model: ``"sigmoid"`` (N3V ``sandwich``) or ``"clamp"`` (Technicolor ``sandwichnoact``)."""
    sh_degree: int = 3
    """SH degree of the ``"sh"`` variant (+1 every 1000 iterations)."""
    segment_frames: int | None = 50
    """Frames per segment model (STG's ``duration``: 50, ``configs/n3d_full/*.json:7``, ``:8`` in
    coffee_martini and flame_salmon_1, ``configs/techni_full/*.json:10``; MoE-GS N3V: 150); None = one
    model for the whole scene. ``moegs.train.entry.train_recipe`` trains a longer scene in segments."""
    max_init_points: int | None = None
    """Keep at most this many initial points (random subset); None keeps all (STG: every frame's SfM)."""
    thin_later_frames: bool = False
    """Keep every point of the cloud's first time and, of each later time's points, the quarter farthest
    from their nearest neighbour (:func:`keep_isolated_later_points`), before ``max_init_points``: STG's
    ``"preprocesspoints": 3`` (``configs/techni_full/{Birthday,Theater,Train}.json:6``; 0, nothing done, in
    Fabien and Painter, in every ``techni_lite`` and ``n3d_full`` config)."""
    trbf_scale_init: float = 0.0
    """Initial log temporal scale ``sτ`` (``-trbfslinit``: 0 on N3V, -2 on Technicolor)."""
    spatial_lr_scale: float | None = None
    """Multiplier of the position / motion learning rates; None = scene extent (``cameras_extent``)."""
    means_lr: float = 1.6e-4
    means_lr_final: float = 1.6e-6
    means_lr_max_steps: int = 30_000
    motion_lr: float = 1.6e-4 * 0.5 * 3.5
    """Polynomial coefficients: ``position_lr_init · 0.5 · movelr`` (movelr 3.5), times the extent;
    constant."""
    features_lr: float = 2.5e-3
    """Albedo + specular features (``feature_lr``); SH DC in the ``"sh"`` variant; RGB in ``"lite"``."""
    features_t_lr: float = 1e-3
    shN_lr: float = 2.5e-3 / 20
    opacities_lr: float = 0.05
    scales_lr: float = 1.5e-3
    """N3V configs 1.5e-3 (3e-3 coffee_martini / flame_salmon_1); code default and Technicolor 5e-3."""
    quats_lr: float = 1e-3
    omega_lr: float = 1e-4
    trbf_center_lr: float = 1e-4
    trbf_scale_lr: float = 0.03
    decoder_lr: float = 1e-4
    optimizer: str = "adam"
    """``"adam"`` (STG); ``"radam"`` for the MoE-GS SH variant."""
    antialiased: bool = False
    """Render with the Ex4DGS 0.1 dilation (MoE-GS SH variant); STG's own rasteriser uses 0.3."""
    views_per_step: int = 2
    """Cameras of one timestamp per step (STG ``batch = 2``; 1 on monocular data)."""
    strategy: Strategy = field(default_factory=lambda: STGStrategy())
    train: TrainConfig = field(default_factory=lambda: TrainConfig(iterations=25_000, lambda_dssim=0.2))
    """Loss 0.8 L1 + 0.2 (1 - SSIM). STG trains 30k iterations but reports the checkpoint of
    ``test_iteration`` (``configs/n3d_full/*.json:6``: 25k); training to it with the 30k position decay
    (``means_lr_max_steps``) reproduces that checkpoint (saved before its densify and step)."""

    def __post_init__(self) -> None:
        if self.color not in COLOR_MODELS:
            raise ValueError(f"STGConfig.color must be one of {COLOR_MODELS}, got {self.color!r}")
        if self.views_per_step < 1:
            raise ValueError(f"STGConfig.views_per_step must be >= 1, got {self.views_per_step}")

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "n3v": DatasetPreset(
            "paper-n3v", "configs/n3d_full/*.json over thirdparty/gaussian_splatting/arguments"
        ),
        "technicolor": DatasetPreset("paper-technicolor", "configs/techni_full/*.json"),
    }
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "black"}
    """Black (``thirdparty/gaussian_splatting/arguments/__init__.py:69``; ``train.py:91``)."""
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {
        # every frame's COLMAP points of the window, each at its time (dataset_readers.py:816-836, N3V;
        # :913-932, Technicolor)
        "n3v": {"points": "frames"},
        "technicolor": {"points": "frames"},
    }
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {
        # densify mode 2 (configs/n3d_full/<scene>.json:4-7; helper_train.py:233-256): opacity pruning up to
        # 8900, the ω mask only to 8999, nothing after 9000; evaluated at test_iteration (:6)
        **{
            f"n3v:{name}": {
                "scales_lr": 3e-3,
                "strategy.prune_until": 9000,
                "strategy.omega_mask_until": 8999,
                "strategy.z_prune_every": None,
                "strategy.bbox_prune_at": None,
                "train.iterations": steps,
            }
            for name, steps in (("coffee_martini", 10_000), ("flame_salmon", 12_000))
        },
        # "preprocesspoints": 3 (configs/techni_full/<Scene>.json:6; train.py:60 hands it to the model,
        # scene/oursfull.py:155-156 thins in create_from_pcd); Fabien and Painter set 0
        **{f"technicolor:{name}": {"thin_later_frames": True} for name in ("birthday", "theater", "train")},
    }

    @classmethod
    def presets(cls) -> dict[str, Callable[[], STGConfig]]:
        return {**super().presets(), "moe_sh": cls.moe_sh}

    @classmethod
    def paper_n3v(cls) -> STGConfig:
        """The defaults plus N3V's z < 4.5 prunes (``train.py:149-152``; ``helper_train.py:223-226``)."""
        return cls(strategy=STGStrategy(prune_z_below=4.5))

    @classmethod
    def paper_technicolor(cls) -> STGConfig:
        """``configs/techni_full/*.json`` (densify mode 3): scaling lr 5e-3 (:4), ``trbfslinit`` 2 (:5),
        12 densification events (:9), the clamping decoder ``sandwichnoact`` (:11); only the bbox prune."""
        return cls(
            decoder_activation="clamp",
            trbf_scale_init=-2.0,
            scales_lr=5e-3,
            strategy=STGStrategy(max_densify_events=12, omega_mask_from=None, z_prune_every=None),
        )

    @classmethod
    def moe_sh(cls) -> STGConfig:
        """MoE-GS's N3V STG† as its README describes it (SH degree 3, Ex4DGS rasteriser, two 150-frame
        segments), with RAdam: the optimiser of the authors' stored router stage, their STG† pretraining
        code is not stored, so RAdam is unverified (the bench's STG† keeps STG's Adam)."""
        return cls(color="sh", optimizer="radam", antialiased=True, segment_frames=150)

    @classmethod
    def own_frame_fields(cls, config: STGConfig, dataset: str, real: bool) -> dict[str, Any]:
        """The z < 4.5 prune holds in real N3V's LLFF world frame only."""
        own = dataset == "n3v" and real
        return {} if own or config.strategy.prune_z_below is None else {"strategy.prune_z_below": None}

    @classmethod
    def quick_fields(cls, paper: STGConfig) -> dict[str, Any]:
        """CPU minutes: 600 iterations; densification 20-360 every 50 with at most 6 events (STG 500-9000
        every 100, 6 events on N3V, 12 on Technicolor) and one reset at 180 (STG 3000 and 6000); the later
        steps at the same place relative to the densification window (x 360 / 9000)."""
        s = paper.strategy

        def at(step: int | None) -> int | None:
            return None if step is None or step >= NEVER else round(step * 360 / s.densify_until)

        return {
            "max_init_points": QUICK_POINTS,
            "means_lr_max_steps": QUICK_ITERATIONS,
            "strategy.densify_from": 20,
            "strategy.densify_until": 360,
            "strategy.densify_every": 50,
            "strategy.max_densify_events": min(s.max_densify_events, 6),  # 10 every 25 grew 93k Gaussians
            "strategy.prune_until": 360,
            "strategy.reset_at": (180,),
            "strategy.omega_mask_from": at(s.omega_mask_from),
            "strategy.omega_mask_until": at(s.omega_mask_until) if s.omega_mask_until < NEVER else NEVER,
            "strategy.z_prune_every": at(s.z_prune_every),
            "strategy.bbox_prune_at": at(s.bbox_prune_at),
            "strategy.guided_from": at(s.guided_from),
            "strategy.guided_gap": at(s.guided_gap),
        }


# -- densification -----------------------------------------------------------------------------------------
@dataclass
class STGStrategy(ADCStrategy):
    """STG ``controlgaussians`` and the scheduled steps around it (``helper_train.py``, ``train.py``):

    * every ``densify_every`` iterations in (``densify_from``, ``densify_until``): the first
      ``max_densify_events`` events clone/split (no pruning: STG builds the prune mask but never applies
      it) and give every new Gaussian a time centre ``μτ ~ U(0, 1)``; later events prune opacity <
      ``prune_opacity`` while ``step < prune_until``;
    * opacity reset to ``min(o, 0.01)`` at the iterations ``reset_at``;
    * from ``omega_mask_from`` (8001) to ``omega_mask_until``: only "moving" Gaussians (``‖b1‖₁`` > 0.3,
      0.2 < max scale < 0.6, opacity > 0.7) learn ω, only the others learn their base rotation
      (``helper_train.py:196-203,219-222``; ``oursfull.py:432-448``): ω is zeroed for the others and its
      Adam moments for all at the first step, gradients are masked at every later one;
    * world z < ``prune_z_below`` removed before the first render (STG prunes the initial points before
      its loop, ``train.py:149-152``, after the depths of ``strategy_inputs`` were taken from the whole
      cloud) and, after ``densify_until``, every ``z_prune_every`` iterations (at
      ``k z_prune_every + z_prune_every / 2``; N3V, ``helper_train.py:223-226``);
    * at ``bbox_prune_at`` (10000): remove Gaussians outside the initial cloud's box (``helper_train.py:
      177-190,227-228``);
    * error-guided sampling from ``guided_from`` (``moegs.experts.stg_guided``).

    Densify modes of the original: 1 (N3V) = the defaults; 2 (coffee_martini, flame_salmon_1) = prune until
    9000, ω mask to 8999, no late prunes; 3 (Technicolor) = 12 events, bbox prune only.
    The screen-space statistics (gradient, visibility count, largest radius) come from the last view of a
    step only (``batch_stats="last"``): STG hands ``add_densification_stats`` the tensors of its last render
    (``train.py:257-258``), whose gradient is that view's own loss.
    """

    batch_stats: str = "last"

    densify_from: int = 500
    densify_until: int = 9000
    densify_every: int = 100
    grad_threshold: float = 2e-4
    max_densify_events: int = 6
    """``desicnt``: 6 on N3V, 12 on Technicolor."""
    prune_until: int = 7000
    """Opacity pruning after the densification events stops here (modes 1/3: 7000; mode 2: 9000)."""
    reset_at: tuple[int, ...] = (3000, 6000)
    """Opacity resets (``opacity_reset_interval`` 3000 below ``densify_until`` 9000)."""
    omega_mask_from: int | None = 8001
    """First iteration of the ω / rotation split (None: never; Technicolor)."""
    omega_mask_until: int = NEVER
    """Last iteration with masked gradients (mode 1: to the end; mode 2: 8999)."""
    prune_z_below: float | None = None
    """World z below which Gaussians are removed (N3V: 4.5 in its LLFF world frame; None: no z prune)."""
    z_prune_every: int | None = 1000
    """Period of the z prune after ``densify_until`` (None: only the initial prune; modes 2 and 3)."""
    bbox_prune_at: int | None = 10_000
    """Iteration of the bounding-box prune (None: never; mode 2)."""
    guided_from: int | None = 1600
    """``emsstart``: error-guided sampling starts collecting SSIMs here (None: off)."""
    guided_events: int = 2
    """Cameras selected for guided sampling (the two worst)."""
    guided_gap: int = 100
    """Events are more than this many iterations apart."""
    guided_select_ssim: float = 0.91
    """Only cameras whose SSIM is below this are candidates."""
    guided_event_ssim: float = 0.88
    """An event adds Gaussians only when the view's SSIM is below this."""
    guided_quantile: float = 0.6
    """``emsthr``: pixels above this quantile of the error are bad."""
    guided_depths: tuple[float, ...] = (0.7, 7.5)
    """``raystart`` / ``rayends`` with ``farray`` 2: new Gaussians at these multiples of the far depth."""
    time_key: str = "trbf_center"

    @property
    def needs_views(self) -> bool:
        return self.guided_from is not None

    def initialize_state(self, scene_scale: float, white_background: bool = False) -> dict:
        state = super().initialize_state(scene_scale, white_background)
        state.update(events=0, omega_mask=None)
        state["guided"] = {"phase": "off", "ssim": {}, "selected": [], "events": 0, "last": 0}
        return state

    @torch.no_grad()
    def _clone_and_split(self, params, optimizers, state: dict) -> None:
        extent = state["scene_scale"]
        grads = state["grad2d"] / state["count"].clamp(min=1)
        small = torch.exp(params["scales"]).max(dim=1).values <= self.percent_dense * extent
        candidates = grads >= self.grad_threshold
        clone, to_split = candidates & small, candidates & ~small
        n = params["means"].shape[0]
        ops.duplicate(params, optimizers, clone)
        cloned = int(clone.sum())
        to_split = torch.cat([to_split, to_split.new_zeros(cloned)])
        ops.split(params, optimizers, to_split, self.split_samples, self.split_scale_divisor)
        split = int(to_split.sum())
        new = params["means"].shape[0] - (n - split)  # clones and children sit at the end
        if new:
            centres = params[self.time_key]
            centres.data[-new:] = torch.rand(new, device=centres.device, dtype=centres.dtype)
        state["last_refine"] = {"clone": cloned, "split": split}

    def _remove(self, params, optimizers, state: dict, prune: Tensor) -> None:
        """Remove ``prune`` rows and keep the ω mask aligned."""
        if not bool(prune.any()):
            return
        ops.remove(params, optimizers, prune)
        if state["omega_mask"] is not None:
            state["omega_mask"] = state["omega_mask"][~prune]
        self._reset_stats(state, params["means"].shape[0], params["means"].detach())

    @torch.no_grad()
    def _omega_mask(self, params, optimizers, state: dict, step: int) -> None:
        if step == self.omega_mask_from:
            speed = params["motion"][:, 0:3].abs().sum(-1)
            size = torch.exp(params["scales"]).max(-1).values
            moving = (speed > 0.3) & (size > 0.2) & (size < 0.6) & (torch.sigmoid(params["opacities"]) > 0.7)
            state["omega_mask"] = moving
            ops.update_params(
                params,
                optimizers,
                lambda k, v: v * moving[:, None].to(v),
                lambda k, v: torch.zeros_like(v),
                keys=["omega"],
            )
        elif self.omega_mask_from < step <= self.omega_mask_until and state["omega_mask"] is not None:
            moving = state["omega_mask"]
            if params["omega"].grad is not None:
                params["omega"].grad.mul_(moving[:, None].to(params["omega"].grad))
            if params["quats"].grad is not None:
                params["quats"].grad.mul_((~moving)[:, None].to(params["quats"].grad))

    @torch.no_grad()
    def _guided(self, params, optimizers, state: dict, step: int, info: dict) -> None:
        g = state["guided"]
        views = info.get("views", [])
        if step == self.guided_from:
            g["phase"] = "collect"
        if g["phase"] == "collect":
            for v in views:  # each camera's first render
                key = str(v["camera"].camera_id)
                if key not in g["ssim"]:
                    g["ssim"][key] = stg_guided.view_ssim(v["rgb"], v["target"])
            if len(g["ssim"]) >= len(state["far_depth"]):
                worst = sorted((s, c) for c, s in g["ssim"].items() if s < self.guided_select_ssim)
                picked = [c for _, c in worst[: self.guided_events]]
                g["selected"] = picked if len(picked) >= self.guided_events else []
                g["phase"] = "selected" if g["selected"] else "done"
            return
        if g["phase"] != "selected" or not views or step <= self.guided_from:
            return
        last = views[-1]
        cam, key = last["camera"], str(last["camera"].camera_id)
        if key not in g["selected"] or step - g["last"] <= self.guided_gap:
            return
        g["selected"].remove(key)
        g["events"] += 1
        g["last"] = step
        if not g["selected"]:
            g["phase"] = "done"
        if stg_guided.view_ssim(last["rgb"], last["target"]) >= self.guided_event_ssim:
            return
        pixels = stg_guided.error_pixels(last["rgb"], last["target"], self.guided_quantile)
        depth = state["far_depth"].get(key, 0.0)
        if len(pixels) == 0 or depth <= 0:
            return
        points = stg_guided.pixel_points(cam, pixels, depth, self.guided_depths)
        colours = last["target"][pixels[:, 0], pixels[:, 1]].repeat(len(self.guided_depths), 1)
        ops.append(params, optimizers, stg_guided.new_rows(params, points, colours, state["trbf_scale_init"]))
        self._reset_stats(state, params["means"].shape[0], params["means"].detach())
        if state["omega_mask"] is not None:
            pad = state["omega_mask"].new_zeros(len(points))
            state["omega_mask"] = torch.cat([state["omega_mask"], pad])
        state["last_refine"] = {"guided": len(points)}

    def step_pre_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        if step == 1 and self.prune_z_below is not None:  # before the first render (train.py:149-152)
            self._remove(params, optimizers, state, params["means"][:, 2] < self.prune_z_below)

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        if step < self.densify_until:
            self._update_stats(params, state, info)
            if self.densifies(step):
                if state["events"] < self.max_densify_events:
                    self._clone_and_split(params, optimizers, state)
                    state["events"] += 1
                elif step < self.prune_until:
                    self._remove(
                        params, optimizers, state, torch.sigmoid(params["opacities"]) < self.prune_opacity
                    )
                self._reset_stats(state, params["means"].shape[0], params["means"].detach())
        if self.omega_mask_from is not None and step >= self.omega_mask_from:
            self._omega_mask(params, optimizers, state, step)
        late = step >= self.densify_until and self.z_prune_every
        if late and self.prune_z_below is not None and step % self.z_prune_every == self.z_prune_every // 2:
            self._remove(params, optimizers, state, params["means"][:, 2] < self.prune_z_below)
        if step == self.bbox_prune_at:
            lo, hi = state["bbox"]
            xyz = params["means"]
            self._remove(params, optimizers, state, ((xyz < lo) | (xyz > hi)).any(-1))
        if step in self.reset_at:
            ops.reset_opacity(params, optimizers, self.reset_value)
        if self.guided_from is not None and step >= self.guided_from:
            self._guided(params, optimizers, state, step, info)


# -- expert ------------------------------------------------------------------------------------------------
def _point_times(points: PointCloud, window: tuple[float, float], seed: int) -> Tensor:
    """Per-point local birth times: the merged per-frame cloud's ``times`` mapped into ``window``, else
    uniform random in [0, 1) (seeded; the scenes here have no per-frame SfM)."""
    if points.times is not None:
        return (points.times.to(torch.float32) - window[0]) / (window[1] - window[0])
    g = torch.Generator(device="cpu").manual_seed(seed)
    return torch.rand(len(points), generator=g, device="cpu")


def keep_isolated_later_points(points: PointCloud, share: float = 0.25) -> PointCloud:
    """STG's ``"preprocesspoints": 3``: ``interpolate_point`` (``helper_model.py:126-178``, called from
    ``scene/oursfull.py:155-156`` and ``ourslite.py:154-155`` with an ``N`` it overwrites at ``:160``).

    The points are grouped by time, earliest first. The earliest group is kept whole. In every later
    group of ``n`` points, each point's distance to its nearest other point of the group is compared with
    the ``k``-th largest of those distances, ``k = floor(share * n)``, and the point is kept when its
    distance is strictly larger (``:153-163``): ``k - 1`` points when the distances differ. With ``k = 0``
    (fewer than 4 points) the index ``-0`` of the original's sorted distances is the smallest, so the group
    keeps the points farther than the closest pair; a lone point is dropped (the original's 2-NN query has
    no second neighbour there). The result lists the groups earliest first, each in its input order
    (``:170-172``). A cloud without times is a single group: returned as it is.
    """
    if points.times is None or len(points) == 0:
        return points
    stamps, group = torch.unique(points.times, sorted=True, return_inverse=True)
    kept = []
    for g in range(len(stamps)):
        index = (group == g).nonzero(as_tuple=True)[0]
        if g > 0:
            # squared distances order the points as the distances do
            d2 = knn_mean_distance(points.xyz[index].double(), k=1, squared=True)
            take = int(share * len(index))
            threshold = d2.sort().values[len(index) - take if take else 0]
            index = index[d2 > threshold]
        kept.append(index)
    keep = torch.cat(kept)
    return PointCloud(
        points.xyz[keep],
        points.rgb[keep],
        f"{points.source}, later times thinned to their {share:g} most isolated",
        points.times[keep],
    )


class STGExpert(Expert):
    """One STG model of the scene's time window ``[start, stop)``, which it maps to STG's local time
    ``(t - start) / (stop - start)`` (``(j - start) / D`` for frame ``j``)."""

    name = "stg"
    config_class = STGConfig

    def __init__(
        self,
        config: STGConfig,
        splats: nn.ParameterDict,
        decoder: FeatureDecoder | None,
        spatial_lr_scale: float,
        window: tuple[float, float],
    ) -> None:
        super().__init__(config, splats, decoder)
        self.spatial_lr_scale = spatial_lr_scale
        self.window = window
        self.active_sh_degree = 0

    @classmethod
    def from_scene(cls, scene: Scene, config: STGConfig) -> STGExpert:
        """A model of the whole ``scene`` (segments: ``moegs.train.segments.train_segments``)."""
        points = scene_points(scene)
        if config.thin_later_frames:
            points = keep_isolated_later_points(points)
        points = thin_points(points, config.max_init_points, config.train.seed)
        window = segment_bounds(sorted({v.camera.time for v in scene.train}), None)[0]
        times = _point_times(points, window, config.train.seed)
        n = len(points)
        extra = {
            "motion": torch.zeros(n, 9),
            "omega": torch.zeros(n, 4),
            "trbf_center": times,
            "trbf_scale": torch.full((n,), config.trbf_scale_init),
        }
        if config.color == "full":
            extra["features"] = torch.cat([points.rgb, points.rgb], dim=1).float()
            extra["features_t"] = torch.zeros(n, 3)
        elif config.color == "lite":
            extra["rgb"] = points.rgb.float().clone()
        splats = init_splats(points, config.sh_degree, extra=extra)
        splats["scales"].data.clamp_(-10.0, 1.0)  # STG create_from_pcd clamps the log-scale to [-10, 1]
        if config.color != "sh":
            del splats["sh0"], splats["shN"]
        decoder = FeatureDecoder(config.decoder_activation) if config.color == "full" else None
        scale = config.spatial_lr_scale if config.spatial_lr_scale is not None else scene.extent
        return cls(config, splats, decoder, scale, window)

    # -- rendering ------------------------------------------------------------------------------------
    def on_step(self, step: int) -> bool:
        self.active_sh_degree = active_sh_degree(
            step, self.config.sh_degree, self.config.train.sh_degree_interval
        )
        return False

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        s = self.splats
        start, stop = self.window
        dt = (t - start) / (stop - start) - s["trbf_center"]  # [N], local time
        dt_motion = dt.detach()[:, None]
        geometry = {
            "means": polynomial_motion(s["means"], s["motion"], dt_motion),
            "quats": linear_rotation(s["quats"], s["omega"], dt_motion),
            "opacities": temporal_opacity(s["opacities"], dt, s["trbf_scale"]),
        }
        if self.config.color == "sh":
            return activate(s, self.active_sh_degree, **geometry)
        colors = (
            torch.cat([s["features"], dt_motion * s["features_t"]], dim=1)
            if self.config.color == "full"
            else s["rgb"]
        )
        return GaussianFrame(scales=torch.exp(s["scales"]), colors=colors, **geometry)

    def decode(self, features: Tensor, camera: Camera) -> Tensor:
        return self.fields(features, camera) if self.config.color == "full" else features

    def splat_inputs(self, camera: Camera, background: Tensor | None) -> SplatInputs:
        """9 feature channels over ``FeatureDecoder.background`` for the full model (decoded per view),
        SH or RGB otherwise."""
        frame = self.frame(camera.time, camera)
        if self.config.color != "full":
            return SplatInputs(frame, background, self.config.antialiased, near=self.config.near)
        if background is not None:
            background = self.fields.background(background)
        decode = partial(self.decode, camera=camera)
        return SplatInputs(frame, background, self.config.antialiased, decode, near=self.config.near)

    def splat_inputs_key(self, camera: Camera) -> Hashable:
        """The time, except for the full model, whose feature decoder reads the camera."""
        return super().splat_inputs_key(camera) if self.config.color == "full" else camera.time

    # -- training ---------------------------------------------------------------------------------------
    def select_views(
        self, step: int, views: list[View], batch_size: int, generator: torch.Generator
    ) -> list[int]:
        """One random timestamp and ``views_per_step`` distinct cameras of it (STG ``batch = 2``)."""
        by_time: dict[float, list[int]] = {}
        for i, v in enumerate(views):
            by_time.setdefault(v.camera.time, []).append(i)
        times = sorted(by_time)
        members = by_time[times[int(torch.randint(len(times), (1,), generator=generator, device="cpu"))]]
        k = min(self.config.views_per_step, len(members))
        order = torch.randperm(len(members), generator=generator, device="cpu")[:k]
        return [members[i] for i in order.tolist()]

    def param_groups(self) -> list[ParamGroup]:
        c, sc, s = self.config, self.spatial_lr_scale, self.splats
        colour = {
            "full": [("features", c.features_lr), ("features_t", c.features_t_lr)],
            "sh": [("sh0", c.features_lr), ("shN", c.shN_lr)],
            "lite": [("rgb", c.features_lr)],
        }[c.color]
        constant = [
            *colour,
            ("motion", c.motion_lr * sc),
            ("opacities", c.opacities_lr),
            ("scales", c.scales_lr),
            ("quats", c.quats_lr),
            ("omega", c.omega_lr),
            ("trbf_center", c.trbf_center_lr),
            ("trbf_scale", c.trbf_scale_lr),
        ]
        groups = splat_param_groups(s, c, sc, constant, optimizer=c.optimizer)
        if self.config.color == "full":
            groups.append(
                ParamGroup("decoder", list(self.fields.parameters()), c.decoder_lr, optimizer=c.optimizer)
            )
        return groups

    def strategy(self) -> Strategy:
        return self.config.strategy

    @torch.no_grad()
    def strategy_inputs(self, scene: Scene) -> dict:
        """The initial cloud's box (bbox prune), ``sτ`` of new Gaussians and, with guided sampling, each
        training camera's far depth at the first frame under the initial model (STG's census)."""
        means = self.splats["means"].detach()
        out = {
            "bbox": [means.min(0).values, means.max(0).values],
            "trbf_scale_init": self.config.trbf_scale_init,
        }
        if isinstance(self.config.strategy, STGStrategy) and self.config.strategy.guided_from is not None:
            first = min(v.camera.time for v in scene.train)
            out["far_depth"] = {}
            for view in scene.train:
                if view.camera.time == first:
                    _, rendered, _ = self.render(view.camera, scene.background)
                    depth = stg_guided.far_depth(rendered.depth, rendered.alpha)
                    out["far_depth"][str(view.camera.camera_id)] = depth
        return out


# -- segments ---------------------------------------------------------------------------------------------
def segment_scene(scene: Scene, start: float, stop: float) -> Scene:
    """The views of ``scene`` with ``start <= time < stop``, times mapped to ``(t - start) / (stop - start)``;
    points with ``times`` are kept only inside the window (renormalised the same way)."""
    if not stop > start:
        raise ValueError(f"segment needs stop > start, got [{start}, {stop})")

    def local(views: list[View]) -> list[View]:
        return [
            replace(v, camera=v.camera.at_time((v.camera.time - start) / (stop - start)), cache=None)
            for v in views
            if start - TIME_EPS <= v.camera.time < stop - TIME_EPS
        ]

    train = local(scene.train)
    if not train:
        raise ValueError(f"{scene.name}: no training view in the time window [{start}, {stop})")
    points = scene.points
    if points is not None and points.times is not None:
        keep = (points.times >= start - TIME_EPS) & (points.times < stop - TIME_EPS)
        points = PointCloud(
            points.xyz[keep],
            points.rgb[keep],
            f"{points.source}, [{start:.3f}, {stop:.3f})",
            (points.times[keep] - start) / (stop - start),
        )
    frames = len({v.camera.time for v in train})
    return replace(
        scene,
        name=f"{scene.name}[{start:.3f},{stop:.3f})",
        train=train,
        test=local(scene.test),
        num_frames=frames,
        points=points,
        meta={**scene.meta, "segment": [start, stop]},
    )


class STGSegments(nn.Module):
    """Segment models answering any global time: ``frame(t)`` picks the segment holding ``t`` and queries it
    at local time ``(t - start) / (stop - start)``; ``decode`` and ``render`` pick it by ``camera.time``."""

    name: ClassVar[str] = "stg"

    def __init__(self, models: list[STGExpert], bounds: list[tuple[float, float]]) -> None:
        super().__init__()
        if len(models) != len(bounds) or not models:
            raise ValueError(
                f"STGSegments needs one (start, stop) per model, got {len(models)} and {len(bounds)}"
            )
        self.models = nn.ModuleList(models)
        self.bounds = list(bounds)

    def segment(self, t: float) -> int:
        """Index of the segment holding global time ``t``."""
        return segment_index(t, [b[0] for b in self.bounds])

    def locate(self, t: float) -> tuple[STGExpert, float]:
        """The segment model holding global time ``t`` and the local time there."""
        k = self.segment(t)
        start, stop = self.bounds[k]
        return self.models[k], (t - start) / (stop - start)

    @property
    def config(self) -> STGConfig:
        """The segments' shared config."""
        return self.models[0].config

    @property
    def num_gaussians(self) -> int:
        return sum(m.num_gaussians for m in self.models)

    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        model, local = self.locate(t)
        return model.frame(local, camera)

    def splat_inputs(self, camera: Camera, background: Tensor | None) -> SplatInputs:
        """The inputs of the segment model holding ``camera.time``, queried at its local time."""
        model, local = self.locate(camera.time)
        return model.splat_inputs(camera.at_time(local), background)

    def splat_inputs_key(self, camera: Camera) -> Hashable:
        """The segment and its model's key at the local time."""
        model, local = self.locate(camera.time)
        return self.segment(camera.time), model.splat_inputs_key(camera.at_time(local))

    def render(
        self, camera: Camera, background: Tensor | None, backend: str = "auto", return_stats: bool = False
    ) -> tuple[Tensor, RenderOutput, GaussianFrame]:
        return render_splat_inputs(self.splat_inputs(camera, background), camera, backend, return_stats)

    def frame_rows(self, t: float) -> Tensor:
        k = self.segment(t)
        start = sum(m.num_gaussians for m in self.models[:k])
        return torch.arange(
            start, start + self.models[k].num_gaussians, device=self.models[k].splats["means"].device
        )

    def keep_gaussians(self, keep: Tensor) -> None:
        check_keep(keep, self.num_gaussians)
        for model, part in zip(self.models, keep.split([m.num_gaussians for m in self.models]), strict=True):
            model.keep_gaussians(part)
