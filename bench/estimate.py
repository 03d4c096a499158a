"""What a plan costs before it runs (``bench.all --dry-run``): H100 GPU-hours and CPU-hours per build.

A build costs ``iterations x passes x megapixels x rate``: the iterations its recipe runs at the preset,
the passes of one iteration (an STG segment or a per-frame MCMC model each trains its own model), the
megapixels of one training image, and the seconds an iteration costs per megapixel.

**GPU rates** are the originals' own reported speeds (``SPEEDS``, each with its source), at the size they
were measured, converted to an H100 with ``H100_SPEEDUP``: an H100 taken as 2x an A6000 and 2.5x an RTX
3090 (specs/gpu_training.md section 6; plausible range 1.5-2.5x an A6000). An expert without a reported
speed borrows the nearest documented one, and ``RATES`` says so. A router step renders every expert once
without gradients: ``ROUTER_FACTOR`` times their training steps, which puts the paper's N3V router (5000
steps over E-D3DGS, STG and Ex4DGS) at 5% of its experts' training, the paper's bound ("less than 5%",
tex:2247). A distillation step costs the student's (the teacher's renders are cached).

**CPU rates** (``CPU_RATES``) were derived once (``derive_cpu_rates``) from the committed quick and
standard runs (reports/summary.json and reports/standard/summary.json, ``compute`` rows: 97 builds on an
AMD EPYC, 2 workers of one thread each) divided by the work of the same builds: seconds per iteration per
megapixel of one such worker. They come from images of about 0.01 megapixels and short runs, so a
paper-scale CPU figure is an order of magnitude (months), not a schedule.

Scenes: a stand-in's size is its generator spec's; a real scene's is ``NATIVE`` times the loader's
``resolution_scale`` (frames: the loader's window, else ``NATIVE``'s). Scene builds cost nothing here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from bench.datasets import get_dataset
from bench.presets import BenchPreset
from bench.tasks import Task


@dataclass(frozen=True)
class Speed:
    """A reported training speed: ``ms`` per iteration on ``gpu`` at ``width x height``."""

    ms: float
    gpu: str
    width: int
    height: int
    source: str

    @property
    def h100_rate(self) -> float:
        """H100 seconds per iteration per megapixel."""
        return self.ms / 1000 / H100_SPEEDUP[self.gpu] / (self.width * self.height / 1e6)


H100_SPEEDUP = {"H100": 1.0, "A6000": 2.0, "RTX 3090": 2.5}
"""How many times faster an H100 trains than each GPU (assumed; see the module docstring)."""

SPEEDS = {
    "4dgs-dnerf": Speed(
        21, "RTX 3090", 800, 800, "4DGaussians README: D-NeRF in 8 min = 3k coarse + 20k fine iterations"
    ),
    "4dgs-n3v": Speed(
        318,
        "A6000",
        1352,
        1014,
        "paper tex:2241 (A6000, tex:642): 1.5 h per N3V scene, 17k iterations, batch 2",
    ),
    "ed3dgs-n3v": Speed(189, "A6000", 1352, 1014, "paper tex:2240: 4.2 h per N3V scene, 80k iterations"),
    "stg-n3v": Speed(
        158, "A6000", 1352, 1014, "paper tex:2241: 2.2 h per N3V scene over STG's 50-frame segments (spec §5)"
    ),
    "mode-n3v": Speed(
        240, "A6000", 1352, 1014, "paper Table XI (tex:1252-1257): MoDE 2.2 h per N3V scene, 33k iterations"
    ),
    "3dgs-n3v": Speed(
        25,
        "A6000",
        1352,
        1014,
        "3DGStream issue #5: 10-15 min per N3V frame of 3DGS, 30k iterations (GPU "
        "not stated: taken as an A6000)",
    ),
}

MONO = "no monocular speed reported: its N3V one"
DEFORM = "no reported speed: 4DGaussians' (the nearest documented deformation-field expert)"
RATES: dict[tuple[str, bool], tuple[str, str]] = {
    # (expert, multi-view dataset): (reported speed, what is borrowed)
    ("fourdgs", True): ("4dgs-n3v", ""),
    ("fourdgs", False): ("4dgs-dnerf", ""),
    ("ed3dgs", True): ("ed3dgs-n3v", ""),
    ("ed3dgs", False): ("ed3dgs-n3v", MONO),
    ("stg", True): ("stg-n3v", ""),
    ("stg", False): ("stg-n3v", MONO),
    ("ex4dgs", True): ("ed3dgs-n3v", "no speed in the paper: E-D3DGS's (Ex4DGS claims ~0.6 h on N3V itself)"),
    ("ex4dgs", False): ("ed3dgs-n3v", "no speed in the paper: E-D3DGS's N3V one"),
    ("deformable", True): ("4dgs-n3v", DEFORM),
    ("deformable", False): ("4dgs-dnerf", DEFORM),
    ("grid4d", True): ("4dgs-n3v", DEFORM),
    ("grid4d", False): ("4dgs-dnerf", DEFORM),
    ("mcmc", True): ("3dgs-n3v", ""),
    ("mcmc", False): ("3dgs-n3v", MONO),
    ("static", True): ("3dgs-n3v", ""),
    ("static", False): ("3dgs-n3v", MONO),
    ("mode", True): ("mode-n3v", ""),
    ("mode", False): ("mode-n3v", MONO),
}
"""The reported speed each expert's GPU rate uses on a multi-view / monocular dataset
(``Dataset.multiview``), and what it borrows. Another expert (a plugin) borrows 4DGaussians'."""

ROUTER_FACTOR = 0.6
"""A router step's cost in training steps of its experts (sum over them); see the module docstring."""

CPU_RATES = {
    "fourdgs": 19.0,
    "grid4d": 24.0,
    "deformable": 18.0,
    "ed3dgs": 13.0,
    "stg": 12.0,
    "ex4dgs": 12.0,
    "mcmc": 1.5,
    "static": 1.5,  # not measured: MCMC's (3DGS per model)
    "mode": 20.0,
    "router": 0.3,
    "distill": 1.1,
}
"""CPU seconds per iteration per megapixel (one worker thread): per expert and ``mode``; ``router`` and
``distill`` are factors on the experts' / student's rate, as on the GPU. ``derive_cpu_rates`` over the
committed quick and standard runs (git e0a5830; the standard run's 3000-8000-iteration builds, with more
Gaussians, cost 2-5x the quick ones' per step: the longer a run, the higher its rate)."""

NATIVE = {
    "n3v": (2704, 2028, 300),
    "technicolor": (2048, 1088, 50),
    "hypernerf": (1920, 1072, 200),  # vrig: 164-513 frames by scene, about 200 taken
    "panoptic": (640, 360, 150),
    "dnerf": (800, 800, 150),  # training times per scene: 50-200 (mutant 150)
}
"""Real scenes at ``resolution_scale`` 1: ``(width, height, frames)``."""


@dataclass(frozen=True)
class Work:
    """What one build computes: ``kind``, the experts it trains or routes (a student, MoDE's name
    ``mode``), ``iterations`` x ``passes`` steps on images of ``megapixels``, on a ``multiview`` dataset."""

    kind: str
    experts: tuple[str, ...]
    iterations: int
    passes: int
    megapixels: float
    multiview: bool

    @property
    def steps(self) -> float:
        """Megapixel-iterations: what a rate multiplies."""
        return self.iterations * self.passes * self.megapixels


def scene_size(task: Task) -> tuple[float, int]:
    """``(megapixels of one training image, frames)`` of ``task``'s scene under its loader arguments."""
    dataset, name = task.scene.split(":", 1)
    kwargs = task.scene_kwargs
    if dataset == "synthetic":
        from moegs.data.synthetic.spec import get_spec

        spec = get_spec(name, kwargs.get("preset", "quick"), **kwargs.get("overrides", {}))
        return spec.width * spec.height / 1e6, spec.num_frames
    width, height, frames = NATIVE[dataset]
    scale = float(kwargs.get("resolution_scale", 1.0))
    if kwargs.get("frames"):
        frames = kwargs["frames"][1] - kwargs["frames"][0]
    return width * height * scale * scale / 1e6, frames


def _passes(expert: str, config: Any, frames: int) -> int:
    """Models one training step trains: STG's segments, MCMC's per-frame models, else 1."""
    if expert == "mcmc":
        return getattr(config, "num_models", None) or frames
    segment = getattr(config, "segment_frames", None)
    return math.ceil(frames / segment) if expert == "stg" and segment else 1


def work_of(task: Task, preset: BenchPreset) -> Work:
    """The ``Work`` of the build ``task`` at ``preset`` (iterations as its cell would train them)."""
    from bench.cells import distill, mode, moe
    from bench.cells._lib import recipe_of

    ctx = SimpleNamespace(preset=preset)
    megapixels, frames = scene_size(task)
    dataset = task.params.get("dataset")
    multiview = get_dataset(dataset).multiview if dataset else True
    p = task.params
    if task.kind == "expert":
        recipe = recipe_of(ctx, task)
        its, passes = recipe.config.train.iterations, _passes(p["expert"], recipe.config, frames)
        return Work("expert", (p["expert"],), its, passes, megapixels, multiview)
    if task.kind == "mode":
        its = mode.recipe(ctx, task).config.train.iterations
        return Work("mode", ("mode",), its, 1, megapixels, multiview)
    if task.kind == "moe":
        its = moe.router_config(ctx, task).iterations
        return Work("moe", tuple(p["experts"]), its, 1, megapixels, multiview)
    if task.kind == "distill":
        its = distill.config(ctx, task)[1].iterations
        return Work("distill", (p["student"],), its, 1, megapixels, multiview)
    return Work(task.kind, (), 0, 0, megapixels, multiview)


def gpu_rate(expert: str, multiview: bool) -> tuple[float, str]:
    """``(H100 seconds per iteration per megapixel, what it borrows)`` of one expert's training step."""
    speed, note = RATES.get((expert, multiview), RATES[("fourdgs", multiview)])
    if (expert, multiview) not in RATES:
        note = "no reported speed: 4DGaussians'"
    return SPEEDS[speed].h100_rate, note


def gpu_seconds(work: Work) -> float:
    """H100 seconds of one build."""
    if work.kind == "moe":
        return ROUTER_FACTOR * sum(gpu_rate(e, work.multiview)[0] for e in work.experts) * work.steps
    if not work.experts:
        return 0.0
    return gpu_rate(work.experts[0], work.multiview)[0] * work.steps


def cpu_seconds(work: Work) -> float:
    """CPU seconds of one build (one worker thread)."""
    rate = CPU_RATES.get
    if work.kind == "moe":
        return rate("router") * sum(rate(e, rate("fourdgs")) for e in work.experts) * work.steps
    if not work.experts:
        return 0.0
    factor = rate("distill") if work.kind == "distill" else 1.0
    return factor * rate(work.experts[0], rate("fourdgs")) * work.steps


@dataclass
class Estimate:
    """Builds by kind, H100-hours and CPU-hours of a set of builds, and the borrowed speeds they use."""

    builds: dict[str, int]
    gpu_hours: float
    cpu_hours: float
    notes: dict[str, str]


def estimate(builds: Iterable[Task], preset: BenchPreset) -> Estimate:
    """The ``Estimate`` of ``builds`` (build tasks) at ``preset``."""
    counts: dict[str, int] = {}
    gpu = cpu = 0.0
    notes: dict[str, str] = {}
    for task in builds:
        counts[task.kind] = counts.get(task.kind, 0) + 1
        work = work_of(task, preset)
        gpu += gpu_seconds(work)
        cpu += cpu_seconds(work)
        for expert in work.experts:
            note = gpu_rate(expert, work.multiview)[1]
            if note:
                notes[f"{expert} ({'multi-view' if work.multiview else 'monocular'})"] = note
    return Estimate(counts, gpu / 3600, cpu / 3600, notes)


def plan_estimates(plan) -> tuple[dict[str, Estimate], Estimate]:
    """``({spec id: its builds' Estimate}, the Estimate of every build of the plan once)``: each table
    alone (tables share builds) and their deduplicated total."""
    per_spec, every = {}, {}
    for sp in plan.specs:
        builds = {b.key: b for s in sp.slots if s.task is not None for b in plan.closure(s.task)}
        per_spec[sp.spec.id] = estimate(builds.values(), plan.preset)
        every.update(builds)
    return per_spec, estimate(every.values(), plan.preset)


KINDS = ("expert", "moe", "mode", "distill")


def render(plan, device: str) -> str:
    """The ``--dry-run`` text: per table its builds by kind, H100-hours and CPU-hours; the total."""
    per_spec, total = plan_estimates(plan)
    head = f"{'table':20s} {'builds':>6s} {'expert/moe/mode/distill':>24s} {'H100-h':>9s} {'CPU-h':>10s}"
    lines = [
        f"dry run: preset {plan.preset.name}, device {device}; estimate from bench/estimate.py "
        "(GPU: the originals' reported speeds on an H100; CPU: the committed runs' seconds per step; "
        "scene builds not counted)",
        head,
    ]

    def row(name: str, e: Estimate) -> str:
        kinds = "/".join(str(e.builds.get(k, 0)) for k in KINDS)
        n = sum(e.builds.get(k, 0) for k in KINDS)
        return f"{name:20s} {n:6d} {kinds:>24s} {e.gpu_hours:9.1f} {e.cpu_hours:10.1f}"

    lines += [row(sid, e) for sid, e in per_spec.items()]
    lines.append(row("total (deduplicated)", total))
    lines.append(
        f"total: {total.gpu_hours:.1f} H100-hours ({total.gpu_hours / 24:.1f} days on one H100), "
        f"{total.cpu_hours:.0f} CPU-hours ({total.cpu_hours / 24:.0f} days of one single-thread worker)"
    )
    lines += [f"  {expert}: {note}" for expert, note in sorted(total.notes.items())]
    return "\n".join(lines)


def derive_cpu_rates(runs: Iterable[tuple[Any, dict[str, Any]]]) -> dict[str, float]:
    """CPU rates from finished runs, each ``(plan, compute)``: its report's ``compute`` rows
    (``bench.signals.compute_rows``: minutes per kind and what, over ``count`` builds) and its plan, whose
    builds of the same groups give the work. Experts and MoDE first (seconds over megapixel-iterations,
    pooled over the runs), then the router and distillation factors on them. How ``CPU_RATES`` were made,
    from the committed quick and standard runs (reports/summary.json, reports/standard/summary.json)."""
    from bench.signals import _build_label

    groups: list[tuple[str, float, list[Work]]] = []  # (kind, seconds, works)
    for plan, compute in runs:
        seconds = {(r["kind"], r["what"]): r["minutes"] * 60 for r in compute["builds"]}
        work: dict[tuple[str, str], list[Work]] = {}
        for task in {t.key: t for level in plan.build_levels() for t in level}.values():
            label = (task.kind, _build_label({"kind": task.kind, "params": dict(task.params)}))
            if label in seconds:
                work.setdefault(label, []).append(work_of(task, plan.preset))
        groups += [(kind, seconds[(kind, what)], items) for (kind, what), items in work.items()]
    pooled: dict[str, list[float]] = {}
    for kind, spent, items in groups:
        if kind in ("expert", "mode"):
            total = pooled.setdefault(items[0].experts[0], [0.0, 0.0])
            total[0] += spent
            total[1] += sum(w.steps for w in items)
    rates = {name: spent / steps for name, (spent, steps) in pooled.items()}
    for kind, key in (("moe", "router"), ("distill", "distill")):
        spent = sum(s for k, s, _ in groups if k == kind)
        base = sum(
            sum(rates.get(e, 0.0) for e in w.experts) * w.steps
            for k, _, items in groups
            if k == kind
            for w in items
        )
        if base:
            rates[key] = spent / base
    return rates
