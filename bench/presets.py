"""Bench scale presets: ``tiny`` (tests), ``quick`` (CPU, every table in about an hour), ``standard`` (CPU,
the real scenes trained far longer, about two hours), ``paper``; ``quick32`` (a diagnostic: quick
with stand-ins twice as long).

A bench preset fixes everything that changes the numbers: which expert config preset is used, the
data scale (resolution, frames, synthetic stand-in size), the training schedules (steps overrides)
and the evaluation protocol (test views, speed repeats, metric profile). It is part of every cell
key, so results of different presets never mix. Any preset other than ``paper`` is *reduced scale*
and every table and report produced from it says so.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from bench.spec import by_name

PRESET_ENV = "MOEGS_PRESET"


@dataclass(frozen=True)
class BenchPreset:
    """One scale of the whole benchmark.

    Attributes:
        name: ``tiny`` | ``quick`` | ``quick32`` | ``standard`` | ``paper``.
        description: one line for captions and the report.
        expert_preset: the experts' own config preset (``Expert.config_class.from_preset``).
        synthetic_preset: ``moegs.data.synthetic`` preset of the stand-in scenes.
        synthetic_overrides: field overrides of the stand-in spec (smaller images, fewer frames).
        real: per dataset, loader keyword arguments for real scenes (resolution, frame window).
        max_real_scenes: at most this many real scenes per dataset (``None``: all present).
        train_steps: override of every expert's training iterations (``None``: the expert preset's).
        router_steps / mode_steps / distill_steps: same for router, MoDE and distillation training.
        seeds: number of repeated trainings on the ``seeds`` axis (Table IX).
        scene_seeds: a table's cells on a scene that no stability run (``seeds`` axis) trains, i.e. every
            real scene and a stand-in without one, train this many seeds (0, 1, ...; at least the spec's):
            the table prints their mean, and that scene's seed spread is the noise its claims are judged
            against (``bench.signals.seed_noise``). It chooses which cells run, not what a cell
            computes, so it is not part of any cell key.
        test_views: evaluate at most this many test views, evenly spaced (``None``: all).
        speed_views / speed_warmup / speed_repeats: the FPS protocol (``moegs.metrics.speed``).
        metric_profile: ``moegs.metrics`` profile name used for every number.
        trajectory_gaussians / trajectory_steps: sampling of the motion-trajectory analysis.
        mdc_views: cameras per time step for multi-view depth consistency.
        reduced: True when the numbers are not at the paper's scale.
        schedule_iterations: per dataset, train every expert on that dataset's *real* scenes with its
            quick schedules stretched to this many iterations (``bench.schedules``; not cut short).
        router_scale: the router's schedule (``moegs.moe.router_preset`` scale): ``None`` follows
            ``expert_preset``; ``"paper"`` is the authors' full schedule (5000 iterations, RAdam).
        real_only: only tables whose scenes are all real run at this preset; the stand-in tables stay
            at ``quick`` (a full run of this preset is the set of real-scene tables).
        table_seeds: per table (spec id), the seeds it trains on every scene, those a stability run
            measures included (``scene_seeds`` leaves them at the spec's one seed): asked for where the
            table's claims compare rows whose difference a stability run's spreads cannot judge (paired
            comparisons of routers, pruning, single pass), and where the extra builds are cheap because the
            stability run already trained its experts at those seeds. Planning only, like ``scene_seeds``.
        own_outputs: a full run writes ``tables/<name>/`` and ``reports/<name>/`` (as a ``real_only``
            preset does), leaving the default layout's outputs alone. It places outputs, never changes a
            number, so it is not part of any cell key.
    """

    name: str
    description: str
    expert_preset: str
    synthetic_preset: str
    synthetic_overrides: dict[str, Any] = field(default_factory=dict)
    real: dict[str, dict[str, Any]] = field(default_factory=dict)
    max_real_scenes: int | None = None
    train_steps: int | None = None
    router_steps: int | None = None
    mode_steps: int | None = None
    distill_steps: int | None = None
    seeds: int = 3
    test_views: int | None = None
    speed_views: int = 3
    speed_warmup: int = 2
    speed_repeats: int = 5
    metric_profile: str = "moegs"
    trajectory_gaussians: int = 256
    trajectory_steps: int = 16
    mdc_views: int = 4
    checkpoint_every: int = 0
    """Write a resumable training checkpoint every this many iterations (0: only at the end)."""
    reduced: bool = True
    schedule_iterations: dict[str, int] = field(default_factory=dict)
    router_scale: str | None = None
    real_only: bool = False
    native_psnr: bool = False
    """Also score real scenes below native resolution upsampled to it (``psnr_native``)."""
    scene_seeds: int = 1
    table_seeds: dict[str, int] = field(default_factory=dict)
    own_outputs: bool = False

    @property
    def separate_outputs(self) -> bool:
        """Whether this preset's outputs go to ``<name>/`` subfolders (``real_only`` or ``own_outputs``)."""
        return self.real_only or self.own_outputs

    def to_dict(self) -> dict[str, Any]:
        """Every field except the ``PLANNING_FIELDS`` and the ``LATER_FIELDS`` left at their default: a
        cell's key hashes this, so adding such a field keeps the keys (and cached results) of the presets
        that do not use it."""
        data = asdict(self)
        for name in PLANNING_FIELDS:
            del data[name]
        for name in LATER_FIELDS:
            if not data[name]:  # every later field's default is empty / None / False
                del data[name]
        return data

    def real_kwargs(self, dataset: str) -> dict[str, Any]:
        """Loader keyword arguments for a real scene of ``dataset`` under this preset."""
        return dict(self.real.get(dataset, {}))

    def steps(self, default: int, override: int | None, budget: float = 1.0) -> int:
        """Training iterations: the override (or ``default``) times the budget, at least 1."""
        base = override if override is not None else default
        return max(1, round(base * budget))

    def stretched(self, dataset: str | None, real: bool) -> int | None:
        """Iterations the experts' schedules are stretched to on a scene of ``dataset`` (None: as is)."""
        return self.schedule_iterations.get(dataset or "") if real else None


LATER_FIELDS = ("schedule_iterations", "router_scale", "real_only", "native_psnr")
"""Fields added after results were cached; omitted from ``to_dict`` at their default."""
PLANNING_FIELDS = ("scene_seeds", "table_seeds", "own_outputs")
"""Fields that choose which cells run or where outputs go, never what one computes; never in
``to_dict``."""

CPU_REAL_SCENES: dict[str, dict[str, Any]] = {
    "dnerf": {"resolution_scale": 1 / 8, "num_points": 5000},
    "panoptic": {"resolution_scale": 1 / 4, "frames": (0, 16), "num_points": 5000},
    "n3v": {"resolution_scale": 1 / 8, "frames": (0, 16), "num_points": 5000},
    "technicolor": {"resolution_scale": 1 / 8, "num_points": 5000},
    "hypernerf": {"resolution_scale": 1 / 8, "num_points": 5000},
}
"""Real-scene loading of the CPU presets (``quick``, ``standard``): resolution, frame window, points."""

QUICK = BenchPreset(
    "quick",
    "quick (CPU): 1/8-resolution real scenes (first frames), quick-preset stand-ins, the experts' "
    "quick schedules, 150 router steps",
    expert_preset="quick",
    synthetic_preset="quick",
    real=CPU_REAL_SCENES,
    max_real_scenes=1,
    # Experts, MoDE and distillation students run their own quick schedules (600 iterations):
    # cutting them (300) ended DeformableGS/Grid4D right at an opacity reset (13.8 dB on mutant).
    router_steps=150,
    seeds=3,
    # Real scenes' seed spread is several times the stand-ins' (basketball: 0.8-3.2 dB over 3 seeds at
    # quick), so the tables of every scene without a stability run (real scenes, the D-NeRF stand-in)
    # print a 3-seed mean judged against their own spread.
    scene_seeds=3,
    # The N3V stand-in's paired tables (routers, pruning, single pass, distillation) train 3 seeds too, so
    # their comparisons of the same experts are judged against the spread of the difference, not Table
    # IX's row spreads. Measured cold: the routers' tables reuse Table IX's experts (10 router builds,
    # about 6 min), distillation's train students and teachers (20 builds, 14.5 min); Tables X and XVIII
    # (12 min) are left to `--seeds 3` (docs/reproduce.md).
    table_seeds={"tab03": 3, "tab05": 3, "tab06": 3, "tab07": 3, "tab08": 3, "tab12": 3, "tab15": 3},
    test_views=8,
    speed_views=2,
    speed_warmup=1,
    speed_repeats=3,
    trajectory_gaussians=128,
    trajectory_steps=12,
    mdc_views=3,
)

STANDARD = replace(
    QUICK,
    name="standard",
    description="standard (CPU): real scenes only (stand-in tables stay at quick), quick recipes with their "
    "schedules stretched to 8000 iterations on D-NeRF (1/8 resolution) and 3000 on Panoptic (1/4, "
    "first 16 frames), the router's full schedule (5000 iterations), every test view",
    max_real_scenes=None,
    # Lengths from the convergence study (reports/convergence): on mutant at 1/8, DeformableGS and
    # Grid4D still gain 3.1 / 2.6 dB from 3000 to 6000 iterations (no knee yet), so the D-NeRF length is
    # set by the two-hour budget of Tables XVI + XVII, not by a plateau: 6000 in the first standard run
    # (at least 2.7 h of builds), 8000 since Grid4D's compiled hash encoding (its 3000-iteration mutant
    # run 9.6 -> 2.2 min) and the router's kept expert inputs (about 1.85x a step). Panoptic steps cost
    # ~4x mutant's (16 frames x 31 cameras at 160x90, more Gaussians), and longer training does not help
    # there without the scene's point cloud (README), hence 3000.
    schedule_iterations={
        "dnerf": 8000,
        "panoptic": 3000,
        "n3v": 3000,
        "technicolor": 3000,
        "hypernerf": 3000,
    },
    router_steps=None,  # the router preset's own schedule (router_scale)
    router_scale="paper",
    test_views=None,
    checkpoint_every=1000,
    real_only=True,
    native_psnr=True,
    scene_seeds=1,  # one standard basketball build is about half an hour
    table_seeds={},
)
"""``quick`` with the real scenes trained longer (see the fields it replaces)."""

QUICK32 = replace(
    QUICK,
    name="quick32",
    description="quick with 32-frame stand-ins "
    "(a diagnostic: what the stand-ins' length does to their tables)",
    synthetic_overrides={"num_frames": 32},
    own_outputs=True,
)
"""``quick`` with stand-ins twice as long (16 -> 32 frames of the same motion, at the same cameras): Ex4DGS
grows its training window 10 frames at a time (``Ex4DGSConfig.interval``), so on 16 frames its schedule
runs two conversions where N3V's 300 frames run many. A diagnostic of the stand-in tables, not the
benchmark (README, "The stand-ins' length")."""

PRESETS: dict[str, BenchPreset] = by_name(
    (
        BenchPreset(
            "tiny",
            "tiny (tests): 1/16-resolution real scenes, 48x36 stand-ins with 6 frames, 40 training steps",
            expert_preset="quick",
            synthetic_preset="quick",
            synthetic_overrides={"width": 48, "height": 36, "num_frames": 6},
            real={
                "dnerf": {"resolution_scale": 1 / 16, "num_points": 2000},
                "panoptic": {"resolution_scale": 1 / 8, "frames": (0, 4), "num_points": 2000},
                "n3v": {"resolution_scale": 1 / 16, "frames": (0, 4), "num_points": 2000},
                "technicolor": {"resolution_scale": 1 / 16, "num_points": 2000},
                "hypernerf": {"resolution_scale": 1 / 8, "num_points": 2000},
            },
            max_real_scenes=1,
            train_steps=40,
            router_steps=20,
            mode_steps=40,
            distill_steps=20,
            seeds=2,
            test_views=3,
            speed_views=1,
            speed_warmup=1,
            speed_repeats=2,
            own_outputs=True,  # never over the committed quick outputs
            trajectory_gaussians=64,
            trajectory_steps=6,
            mdc_views=2,
        ),
        QUICK,
        QUICK32,
        STANDARD,
        BenchPreset(
            "paper",
            "paper protocol: full resolution and frames, the experts' paper schedules",
            expert_preset="paper",
            synthetic_preset="paper",
            real={},
            max_real_scenes=None,
            seeds=5,
            checkpoint_every=2000,
            reduced=False,
        ),
    ),
    "presets",
)


SHORTHANDS = ("tiny", "quick", "standard", "paper")
"""Presets with a flag of their own in ``python -m bench.all`` (``--quick`` is ``--preset quick``)."""


def preset_flag(name: str) -> str:
    """The ``bench.all`` option that chooses preset ``name``: ``--quick``, ``--preset quick32``."""
    return f"--{name}" if name in SHORTHANDS else f"--preset {name}"


DEFAULT_PRESET = "quick"
"""The preset of ``python -m bench.all`` without a preset flag or ``$MOEGS_PRESET``: the CPU preset of
about an hour, never the paper's scale by accident."""


def default_preset() -> str:
    """``$MOEGS_PRESET`` if set (and not empty), else ``DEFAULT_PRESET`` (``quick``)."""
    return os.environ.get(PRESET_ENV) or DEFAULT_PRESET


def get_preset(name: str | None = None) -> BenchPreset:
    """A preset by name (``None``: :func:`default_preset`); ``KeyError`` lists the valid names."""
    key = name or default_preset()
    if key not in PRESETS:
        raise KeyError(f"unknown bench preset {key!r}; valid: {', '.join(PRESETS)}")
    return PRESETS[key]
