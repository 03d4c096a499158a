"""Expand specs into slots (row x scene x seed x budget) and the tasks that compute them.

A *slot* is one printed value's ingredient: the evaluation of one row on one scene with one seed
(and budget). Slots whose row kind needs library pieces that do not exist get no task and carry
``"not implemented yet: <pieces>"``. The build tasks (scenes, experts, routers ...) that the
evaluations need are collected with their dependency depth; ``bench.runner`` schedules them and the
evaluations as one graph.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bench.cells import NOT_COMPUTED, kind_module, missing_pieces
from bench.datasets import get_dataset
from bench.keys import digest
from bench.presets import BenchPreset
from bench.registry import get_spec, list_specs
from bench.scenes import SceneRef, load_kwargs, resolve_scenes
from bench.spec import Row, Spec
from bench.tasks import Task

NOT_IMPLEMENTED = "not implemented yet"


@dataclass
class Slot:
    """One (row, scene, seed, budget column) of a spec."""

    row: str
    scene: SceneRef | None
    seed: int
    budget_column: str | None
    task: Task | None
    status: str
    """``"planned"``, ``"external"``, ``"qualitative"`` or ``"not implemented yet: ..."``."""
    missing: tuple[str, ...] = ()
    """The library pieces the row's kind lacks."""


@dataclass
class SpecPlan:
    spec: Spec
    scenes: list[SceneRef]
    seeds: list[int]
    slots: list[Slot] = field(default_factory=list)

    def slots_of(self, row: str) -> list[Slot]:
        return [s for s in self.slots if s.row == row]

    def averaged_seeds(self) -> dict[str, list[int]]:
        """``{scene name: seeds}`` of the scenes whose printed values are means over several seeds (not
        a stability run's, whose columns are min / max / average)."""
        if self.spec.axis == "seeds":
            return {}
        seeds: dict[str, set[int]] = {}
        for s in self.slots:
            if s.scene is not None and s.task is not None:
                seeds.setdefault(s.scene.name, set()).add(s.seed)
        return {name: sorted(v) for name, v in seeds.items() if len(v) > 1}

    @property
    def uses_stand_in(self) -> bool:
        return any(not s.real for s in self.scenes)


@dataclass
class Plan:
    preset: BenchPreset
    specs: list[SpecPlan]
    device: str = "cpu"
    """The device kind every task of the plan runs on (``bench.tasks.DEVICE_KINDS``)."""

    def eval_tasks(self) -> list[Task]:
        """Unique evaluation tasks in spec order."""
        seen: dict[str, Task] = {}
        for sp in self.specs:
            for slot in sp.slots:
                if slot.task is not None:
                    seen.setdefault(slot.task.key, slot.task)
        return list(seen.values())

    def build_levels(self) -> list[list[Task]]:
        """Build tasks needed by the evaluations, grouped by dependency depth (level 0 first)."""
        depth: dict[str, int] = {}
        tasks: dict[str, Task] = {}

        def visit(task: Task) -> int:
            if task.key not in depth:
                deps = getattr(kind_module(task.kind), "deps", lambda _t: [])(task)
                depth[task.key] = 1 + max((visit(d) for d in deps), default=-1)
                tasks[task.key] = task
            return depth[task.key]

        for ev in self.eval_tasks():
            for art in kind_module(ev.kind).artifacts(ev):
                visit(art)
        levels: list[list[Task]] = [[] for _ in range(max(depth.values(), default=-1) + 1)]
        for key, d in depth.items():
            levels[d].append(tasks[key])
        return levels

    def identity(self) -> dict[str, Any]:
        """What the plan's cells are, checkable without running anything: ``{"specs", "scenes", "tasks",
        "keys_digest"}``, the digest over every build and evaluation key. Each key holds the version of
        the library code its task runs (``bench.codedeps``), so outputs written from this plan are
        current exactly while a new plan of the same specs has the same digest
        (``tests/bench/test_committed_outputs.py``)."""
        keys = {t.key for level in self.build_levels() for t in level} | {t.key for t in self.eval_tasks()}
        return {
            "specs": [sp.spec.id for sp in self.specs],
            "scenes": sorted({ref.name for sp in self.specs for ref in sp.scenes}),
            "tasks": len(keys),
            "keys_digest": digest(sorted(keys)),
        }

    def closure(self, task: Task) -> list[Task]:
        """Every build task an evaluation depends on (transitively)."""
        out: dict[str, Task] = {}

        def visit(t: Task) -> None:
            if t.key not in out:
                out[t.key] = t
                for d in getattr(kind_module(t.kind), "deps", lambda _t: [])(t):
                    visit(d)

        for art in kind_module(task.kind).artifacts(task):
            visit(art)
        return list(out.values())


def _variants(spec: Spec) -> list[tuple[str | None, float | None]]:
    if spec.axis == "budgets":
        return [(col, float(frac)) for col, frac in spec.budgets.items()]
    return [(None, None)]


def stability_scenes(preset: BenchPreset) -> set[str]:
    """Names of the scenes whose seed spread a stability run (a spec on the ``seeds`` axis) measures."""
    out: set[str] = set()
    for spec_id in list_specs("tables"):
        spec = get_spec(spec_id)
        if spec.axis == "seeds" and spec.dataset:
            out.update(s.name for s in resolve_scenes(spec.dataset, preset, spec.scenes))
    return out


def _scene_seeds(
    spec: Spec, scene: SceneRef, seeds: list[int], preset: BenchPreset, measured: set[str]
) -> list[int]:
    """The seeds a table trains on ``scene``: ``preset.table_seeds`` of the table on any scene;
    ``preset.scene_seeds`` where no stability run measures the scene's spread (``measured``: every real
    scene, a stand-in without one; their mean is printed, their spread is the scene's noise); the spec's
    elsewhere and always in figures and stability runs."""
    if spec.figure or spec.axis == "seeds":
        return seeds
    wanted = preset.table_seeds.get(spec.id, 0)
    if scene.name not in measured:
        wanted = max(wanted, preset.scene_seeds)
    return list(range(wanted)) if wanted > len(seeds) else seeds


def _slots(
    spec: Spec,
    row: Row,
    scenes: list[SceneRef],
    seeds: list[int],
    preset: BenchPreset,
    measured: set[str],
    device: str,
) -> list[Slot]:
    if row.kind in NOT_COMPUTED:
        return [Slot(row.name, None, 0, None, None, row.kind)]
    gone = missing_pieces(row.kind, dict(row.params))
    status = f"{NOT_IMPLEMENTED}: {', '.join(gone)}" if gone else "planned"
    out = []
    for scene in scenes:
        expert_config = get_dataset(scene.dataset).expert_config
        for seed in _scene_seeds(spec, scene, seeds, preset, measured):
            for column, budget in _variants(spec):
                params = {**row.params, "dataset": scene.dataset}
                if budget is not None and budget != 1.0:
                    params["budget"] = budget
                if expert_config:
                    params["expert_config"] = expert_config
                task = (
                    None
                    if gone
                    else Task(
                        "eval",
                        row.kind,
                        params,
                        scene.name,
                        load_kwargs(scene, preset),
                        preset.name,
                        seed,
                        device,
                    )
                )
                out.append(Slot(row.name, scene, seed, column, task, status, tuple(gone)))
    return out


def plan_spec(spec: Spec, preset: BenchPreset, device: str = "cpu") -> SpecPlan:
    """Slots of one spec under ``preset``, its tasks on ``device`` (``cpu`` or ``cuda``)."""
    scenes = resolve_scenes(spec.dataset, preset, spec.scenes) if spec.dataset else []
    seeds = list(range(preset.seeds)) if spec.axis == "seeds" else list(spec.seeds)
    sp = SpecPlan(spec, scenes, seeds)
    measured = stability_scenes(preset) if preset.scene_seeds > len(seeds) else set()
    for row in spec.rows:
        sp.slots += _slots(spec, row, scenes, seeds, preset, measured, device)
    return sp


def make_plan(specs: list[str | Spec], preset: BenchPreset, device: str = "cpu") -> Plan:
    """The plan of several specs (ids in any accepted spelling, or ``Spec`` objects) on ``device``."""
    specs = [s if isinstance(s, Spec) else get_spec(s) for s in specs]
    return Plan(preset, [plan_spec(s, preset, device) for s in specs], device)
