"""``MoDEExpert``: several canonical deformation experts on ONE shared set of canonical Gaussians, mixed
per Gaussian by a temporal weight spline with top-k gating (paper Sec. "Mixture of Deformation Experts").

    config = MoDEConfig.from_preset("quick")                  # experts=("fourdgs", "ed3dgs")
    mode = MoDEExpert.from_scene(scene, config)               # an Expert: the one training loop trains it

Per frame at time t, for Gaussian i with gates ``G_i(t)`` (``moegs.mode.gating``)::

    A_e(t) = expert_e.deform(canonical, t)      e = 0 is the base: its gradients reach the canonical set,
                                                the others see a detached copy (paper: gradient blocking)
    means, quats, scales = sum_e G_ie(t) A_e(t) (quats renormalised); opacity and SH from the base

Paper vs authors' code (``specs/official_moegs.md`` section 6), each a config field (dataclass defaults:
the paper's wording): mixed attributes (paper: the deformed position, rotation and scale; code: position
and rotation only), one gate for all mixed attributes (paper) or one per attribute (code), std-normalisation
of the scores before the softmax (code only), control points (code configs: 3). Quaternions are mixed as
the experts output them before normalisation, then normalised (code). The paper's numbers come from the
code, so the recipes (``moegs.recipes``) use the ``code`` / ``quick`` presets; ``paper`` / ``quick-paper``
are the wording variants. Members take their ``paper`` recipe for the scene's dataset with the MoDE
code's own member settings on top (``CODE_MEMBER_FIELDS``: its Grid4D is Grid4D's D-NeRF geometry with one
hidden layer on every dataset, its E-D3DGS a 64-wide net without a warm-up), then, at ``quick``, the
member's reductions over the MoDE run's length. Regularisers: the base's only (the code adds no Grid4D or
E-D3DGS term). Training: the base's pipeline (stages, densification, loss); background white
(``arguments_MoDE/__init__.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from copy import deepcopy
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import Scene, View
from moegs.experts import get_expert_class
from moegs.experts.base import QUICK_ITERATIONS, DatasetPreset, Expert, ExpertConfig
from moegs.gaussians import GaussianFrame
from moegs.io.config import tuples_for_lists
from moegs.mode.gating import top_k_gates, warmup_scores, weight_spline
from moegs.train.params import ParamGroup
from moegs.train.strategy.base import Strategy

CANONICAL_EXPERTS = ("fourdgs", "grid4d", "ed3dgs")
"""Experts with ``deform(splats, t, camera)`` on given canonical parameters (MoDE's candidates)."""
MIXABLE = ("means", "quats", "scales")
GATE_KEY = "gate_control"
"""Per-Gaussian spline control weights ``[N, N_w, G]`` in the shared ``splats``."""
CODE_ITERATIONS = 3000 + 30_000
"""The code's run: 4DGaussians' coarse stage then its fine stage (``OptimizationParams``)."""
CODE_MEMBER_FIELDS: dict[str, dict[str, Any]] = {
    # MoE-GS-studio @b1e91217 arguments_MoDE/__init__.py: ModelParams.grid_args (:64-78) and network_args
    # (:79-83), passed to Grid4D by train_hash.py; no MoDE config overrides them, so N3V runs with
    # Grid4D's D-NeRF geometry (bound 1.6) and one hidden layer.
    "grid4d": {
        "spatial_levels": 16,
        "spatial_level_dim": 2,
        "spatial_base": 16,
        "spatial_desired": 2048,
        "spatial_log2_size": 19,
        "temporal_levels": 32,
        "temporal_level_dim": 2,
        "temporal_base": (8, 8, 8),
        "temporal_desired": (32, 32, 16),
        "temporal_log2_size": 19,
        "bound": 1.6,
        "depth": 1,
        "width": 256,
        "directional": True,
        "scale_xyz": 1.0,  # ModelParams.scale_xyz (:84)
        "grid_lr_scale": 50.0,  # OptimizationParams.grid_lr_scale
        "network_lr_scale": 5.0,  # OptimizationParams.network_lr_scale
        "deform_lr_max_steps": 45_000,  # OptimizationParams.deform_lr_max_steps
    },
    # ModelEmbParams (:145-165) and OptimizationParams' embnet_* rates, passed to E-D3DGS by train_emb.py.
    "ed3dgs": {
        "width": 64,  # emb_net_width
        "depth": 1,  # emb_defor_depth
        "min_embeddings": 30,
        "max_embeddings": 150,
        "embedding_dim": 32,  # emb_gaussian_embedding_dim
        "temporal_dim": 256,  # emb_temporal_embedding_dim
        "deform": ("means", "scales", "quats", "sh"),  # emb_no_do=True: opacity not deformed
        "coarse_min_embeddings": False,  # emb_use_coarse_temporal_embedding=False
        "coarse_to_fine_until": 20_000,  # emb_c2f_temporal_iter
        "deform_from": 0,  # emb_deform_from_iter
        "use_anneal": True,
        "zero_temporal": False,
        "deformation_lr_max_steps": 60_000,  # embnet_lr_max_steps
    },
}
"""Settings the MoDE code gives its members regardless of dataset (member -> dotted field -> value)."""


@dataclass
class MoDEConfig(ExpertConfig):
    """MoDE settings; ``train`` drives the whole model (the base expert's pipeline)."""

    experts: tuple[str, ...] = ("fourdgs", "ed3dgs")
    """Deformation experts, the base (canonical-space owner) first."""
    member_preset: str = "paper"
    """Recipe preset (``moegs.recipes``) of every member on the scene's dataset (``paper`` or ``quick``);
    each member's ``train`` is replaced by this config's."""
    member_fields: dict[str, dict[str, Any]] = field(default_factory=lambda: deepcopy(CODE_MEMBER_FIELDS))
    """Member -> fields set on its ``paper`` recipe before any ``quick`` reduction (default: the code's)."""
    control_points: int = 3
    """Spline control points N_w (code default 18; the MoDE configs use 3, coffee_martini 5)."""
    top_k: int = 2
    """Experts kept per Gaussian (code default 2)."""
    mixed: tuple[str, ...] = MIXABLE
    """Deformed attributes mixed across experts: paper ``means, quats, scales``; code ``means, quats``."""
    gate_per_attribute: bool = False
    """One gate per mixed attribute (code: spline channels [0:E] position, [E:2E] rotation) instead of one."""
    std_normalize: bool = False
    """Divide scores by their std across experts before the softmax (code only)."""
    mix_raw_quats: bool = True
    """Mix the experts' deformed quaternions before normalisation, then normalise (code); False mixes the
    unit quaternions."""
    warmup_iterations: int = 3000
    """Random gating for this many iterations after the base starts deforming (code 3000)."""
    control_init_std: float = 0.01
    """Control weights start at ``control_init_std * randn`` (code)."""
    gate_lr: float = 0.005
    """Control-weight Adam rate, decayed exponentially over the base's fine stage, whose steps the code
    counts from 1 again (code ``weight_movelr``)."""
    gate_lr_final: float = 0.0005
    gate_lr_max_steps: int = 20_000

    def __post_init__(self) -> None:
        self.experts = tuple(self.experts)
        self.mixed = tuple(self.mixed)
        self.member_fields = tuples_for_lists(self.member_fields)  # as JSON or --set gave them, lists
        bad = [e for e in self.experts if e not in CANONICAL_EXPERTS]
        if len(self.experts) < 2 or bad:
            raise ValueError(
                f"MoDEConfig.experts needs >= 2 of {CANONICAL_EXPERTS} (base first), got {list(self.experts)}"
            )
        if not set(self.mixed) <= set(MIXABLE) or not self.mixed:
            raise ValueError(f"MoDEConfig.mixed must be a non-empty subset of {MIXABLE}, got {self.mixed}")
        if not 1 <= self.top_k <= len(self.experts):
            raise ValueError(f"MoDEConfig.top_k must be in 1..{len(self.experts)}, got {self.top_k}")
        if self.control_points < 2:
            raise ValueError(f"MoDEConfig.control_points must be >= 2, got {self.control_points}")

    @property
    def num_gates(self) -> int:
        return len(self.experts) * (len(self.mixed) if self.gate_per_attribute else 1)

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {
        "*": DatasetPreset("code", "authors' MoDE code (train_emb.py / train_hash.py, arguments_MoDE/)")
    }
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "white"}
    """``arguments_MoDE/__init__.py`` sets ``white_background=True``."""

    @classmethod
    def presets(cls) -> dict[str, Callable[[], MoDEConfig]]:
        """``code`` (the 4DGaussians pipeline of the authors' code: coarse 3000 + fine 30000 iterations,
        batch 4, position + rotation mixed with one gate each, std-normalised scores), ``paper`` (the same
        pipeline with the paper's wording), and their CPU reductions ``quick`` / ``quick-paper``."""

        def paper() -> MoDEConfig:
            base = get_expert_class("fourdgs").config_class.from_preset("paper-n3v").train
            return cls(train=replace(base, iterations=CODE_ITERATIONS, batch_size=4))

        def code() -> MoDEConfig:
            return replace(paper(), mixed=("means", "quats"), gate_per_attribute=True, std_normalize=True)

        def quick(config: MoDEConfig) -> MoDEConfig:
            from moegs.recipes import with_fields

            return with_fields(config, cls.quick_reductions(config))

        return {
            "code": code,
            "paper": paper,
            "quick": lambda: quick(code()),
            "quick-paper": lambda: quick(paper()),
        }

    @classmethod
    def quick_fields(cls, paper: MoDEConfig) -> dict[str, Any]:
        """CPU minutes: the members' quick recipes, 600 iterations, one view per step."""
        return {
            "member_preset": "quick",
            "warmup_iterations": 100,  # code: 3000 of 30000 fine steps (10 %); here 100 of 450 (22 %)
            "gate_lr_max_steps": QUICK_ITERATIONS,  # as the base decays (4DGaussians means_lr_max_steps)
            "train.batch_size": 1,  # batch 4 -> 1 (CPU cost)
        }


def member_config(name: str, scene: Scene, config: MoDEConfig) -> ExpertConfig:
    """Member ``name``'s config: its ``paper`` recipe for the scene's dataset; where ``config.member_fields``
    has the member, those fields on top (the scene's frame adaptations, such as Grid4D's bound on a
    stand-in, still win) and the code's run length, whose steps they count; then the ``quick`` reductions
    if ``member_preset`` asks for them. ``train`` is ``config``'s."""
    from moegs.recipes import config_for, with_fields

    recipe = config_for(name, scene.name, "paper", dataset=scene.dataset)
    member = recipe.config
    if name in config.member_fields:
        member = with_fields(member, config.member_fields[name])
        member = with_fields(member, recipe.frame_overrides)
        member = replace(member, train=replace(member.train, iterations=CODE_ITERATIONS))
    if config.member_preset == "quick":
        member = with_fields(member, type(member).quick_reductions(member))
    return replace(member, train=config.train)


def _member(name: str, scene: Scene, config: MoDEConfig) -> Expert:
    return get_expert_class(name).from_scene(scene, member_config(name, scene, config))


class MoDEExpert(Expert):
    """The base expert, the other deformation experts and the shared canonical ``splats`` (which also
    hold every member's per-Gaussian extras and the gate control weights)."""

    name = "mode"
    config_class = MoDEConfig

    def __init__(self, config: MoDEConfig, members: list[Expert], splats: nn.ParameterDict) -> None:
        super().__init__(config, splats, nn.ModuleList(members))
        self.canonical_keys = tuple(k for k in members[0].splats if k != GATE_KEY)
        self.deform_from = -1  # first step at which the base deforms (checkpointed: extra state)
        self.step = 0
        for m in members:
            m.splats = splats  # one ParameterDict: densification keeps everyone's rows in step

    @classmethod
    def from_scene(cls, scene: Scene, config: MoDEConfig) -> MoDEExpert:
        members = [_member(name, scene, config) for name in config.experts]
        shared = dict(members[0].splats.items())
        n = shared["means"].shape[0]
        for m in members[1:]:  # per-Gaussian extras (E-D3DGS embeddings), sized to the base's points
            for key, value in m.splats.items():
                if key not in shared:
                    shape = (n, *value.shape[1:])
                    shared[key] = nn.Parameter(value.new_zeros(shape), requires_grad=value.requires_grad)
        generator = torch.Generator().manual_seed(config.train.seed)
        control = config.control_init_std * torch.randn(
            n, config.control_points, config.num_gates, generator=generator
        )
        shared[GATE_KEY] = nn.Parameter(control)
        return cls(config, members, nn.ParameterDict(shared))

    @property
    def members(self) -> list[Expert]:
        return list(self.fields)

    @property
    def base(self) -> Expert:
        return self.fields[0]

    # -- gating ------------------------------------------------------------------------------------------
    def gates(self, t: float) -> Tensor:
        """``[N, G]`` gates at ``t``: random scores during the warm-up while training, the spline after."""
        c, control = self.config, self.splats[GATE_KEY]
        e = len(c.experts)
        groups = c.num_gates // e
        start = self.deform_from
        warm = self.training and (start < 0 or self.step < start + c.warmup_iterations)
        if warm:
            scores = warmup_scores(control.shape[0] * groups, e, control).view(-1, c.num_gates)
        else:
            scores = weight_spline(control, t)
        parts = scores.view(-1, groups, e)
        return top_k_gates(parts, c.top_k, c.std_normalize).view(-1, c.num_gates)

    # -- frames ------------------------------------------------------------------------------------------
    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        raw = self.config.mix_raw_quats and "quats" in self.config.mixed
        base_frame = self.base.deform(self.splats, t, camera, raw_quats=raw)
        if not getattr(self.base, "deforming", True):
            return base_frame  # the base's static (coarse) stage: no deformation at all
        detached = {k: (v.detach() if k in self.canonical_keys else v) for k, v in self.splats.items()}
        frames = [base_frame] + [m.deform(detached, t, camera, raw_quats=raw) for m in self.members[1:]]
        gates = self.gates(t)
        e = len(frames)
        mixed = {}
        for a, attr in enumerate(self.config.mixed):
            g = gates[:, a * e : (a + 1) * e] if self.config.gate_per_attribute else gates
            value = sum(g[:, i : i + 1] * getattr(f, attr) for i, f in enumerate(frames))
            mixed[attr] = nn.functional.normalize(value, dim=-1) if attr == "quats" else value
        return replace(base_frame, **mixed)

    # -- training hooks ------------------------------------------------------------------------------------
    def on_step(self, step: int) -> bool:
        self.step = step
        changed = [m.on_step(step) for m in self.members]
        if self.deform_from < 0 and getattr(self.base, "deforming", True):
            self.deform_from = step
        return any(changed)

    def get_extra_state(self) -> dict:
        return {"deform_from": self.deform_from}

    def set_extra_state(self, state: dict) -> None:
        self.deform_from = state["deform_from"]

    def param_groups(self) -> list[ParamGroup]:
        """The base's groups, each other member's groups without the canonical tensors (renamed
        ``<member>.<group>``), and the gate control weights. Every schedule restarts where the base's do
        (4DGaussians: the fine stage, whose iterations the code counts from 1 again)."""
        groups = list(self.base.param_groups())
        restart = max(g.start_step for g in groups)
        owned = {id(p) for g in groups for p in g.params}
        for m in self.members[1:]:
            for g in m.param_groups():
                params = [p for p in g.params if id(p) not in owned]
                if params:
                    start = max(g.start_step, restart)
                    groups.append(replace(g, name=f"{m.name}.{g.name}", params=params, start_step=start))
                    owned.update(id(p) for p in params)
        c = self.config
        groups.append(
            ParamGroup(
                GATE_KEY,
                [self.splats[GATE_KEY]],
                c.gate_lr,
                lr_final=c.gate_lr_final,
                max_steps=c.gate_lr_max_steps,
                start_step=restart,
            )
        )
        return groups

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        return self.base.regularization(step, frame)

    def strategy(self) -> Strategy | None:
        return self.base.strategy()

    def select_views(self, step: int, views: list[View], batch_size: int, generator: torch.Generator):
        return self.base.select_views(step, views, batch_size, generator)

    def view_groups(self, views: list[View]) -> list[int] | None:
        return self.base.view_groups(views)
