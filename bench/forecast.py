"""What a ``bench.all`` run will do before it starts: the tasks it computes and those cached, and how
long they took when they or tasks like them ran before.

The workspace records the time of every task it finished: each artefact's ``build_seconds``
(``store/<kind>/<key>/artifact.json``) and each evaluated cell's ``timings.total_s``
(``results/<preset>/<kind>/<key>.json``). A task to compute is timed, in this order, by

1. **its own record**: the same task (action, kind, parameters, scene, loader arguments, preset, seed and
   device) finished before under another code version, so under another key;
2. **similar tasks**: the same action, kind and expert(s) (``Task.slug`` up to the scene) at the same
   preset on the same device, those on the same scene preferred; a training build is scaled by its
   training work (iterations x passes x megapixels, ``bench.estimate.work_of``), the others take the
   mean;
3. otherwise it is **unknown** and left out of the sum, and the estimate says how many are.

The sum is single-worker task time as recorded: a worker's process start (a few seconds per task) and
waits on dependencies are not in it, so ``sum / workers`` is a lower bound of the wall clock. Nothing is
written; ``bench.estimate`` (H100-hours from the originals' reported speeds) is the model for a preset
that has never run here.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.results import ResultError, load_valid
from bench.store import Workspace
from bench.tasks import Task


@dataclass(frozen=True)
class Record:
    """One finished task's time: its ``Task.to_dict`` and the seconds it took."""

    task: dict[str, Any]
    seconds: float


@dataclass
class Forecast:
    """The tasks a plan computes and caches, and the estimate of the computed ones' time."""

    builds_todo: list[Task]
    builds_cached: int
    evals_todo: list[Task]
    evals_cached: int
    seconds: float = 0.0
    """Summed recorded (or scaled) seconds of the timed tasks."""
    own: int = 0
    """Tasks timed by their own earlier record."""
    similar: int = 0
    """Tasks timed by similar recorded tasks."""
    unknown: int = 0
    """Tasks without a record of themselves or of a similar task (not in ``seconds``)."""
    records: int = 0
    """Recorded tasks of the preset and device in the workspace."""

    @property
    def todo(self) -> int:
        return len(self.builds_todo) + len(self.evals_todo)


def cache_state(plan, workspace: Workspace) -> tuple[list[Task], int, list[Task], int]:
    """``(builds to compute, builds cached, evaluations to compute, evaluations cached)`` of ``plan``, as
    ``bench.runner.execute`` will find them (an artefact is cached when finished and intact, a cell when
    its result is valid and ``ok``; a damaged result counts as to compute)."""
    builds, built = [], 0
    for level in plan.build_levels():
        for task in level:
            if workspace.is_built(task):
                built += 1
            else:
                builds.append(task)
    evals, done = [], 0
    for task in plan.eval_tasks():
        try:
            cached = load_valid(workspace.result_path(task), task) is not None
        except ResultError:
            cached = False
        if cached:
            done += 1
        else:
            evals.append(task)
    return builds, built, evals, done


def _read(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def records(root: Path, preset: str, device: str) -> list[Record]:
    """Every finished task of ``preset`` on ``device`` (``cpu``/``cuda``) the workspace at ``root`` holds a
    time of: artefacts (``build_seconds``) and ``ok`` cells (``timings.total_s``)."""
    found: list[Record] = []
    for meta in sorted(root.glob("store/*/*/artifact.json")):
        if ".partial" in meta.parent.name:
            continue
        data = _read(meta) or {}
        task, seconds = data.get("task"), data.get("build_seconds")
        if isinstance(task, dict) and isinstance(seconds, int | float):
            found.append(Record(task, float(seconds)))
    for path in sorted(root.glob(f"results/{preset}/*/*.json")):
        data = _read(path) or {}
        seconds = (data.get("timings") or {}).get("total_s")
        if (
            data.get("status") == "ok"
            and isinstance(data.get("task"), dict)
            and isinstance(seconds, int | float)
        ):
            found.append(Record(data["task"], float(seconds)))
    return [r for r in found if r.task.get("preset") == preset and r.task.get("device", "cpu") == device]


def _same(task: dict[str, Any]) -> str:
    """What makes two tasks the same apart from the code version (which their keys also hash)."""
    return json.dumps(task, sort_keys=True, default=str)


def _label(task: Task) -> str:
    """``action:kind-expert(s)-extras``: what makes tasks similar (``Task.slug`` up to the scene)."""
    return f"{task.action}:{task.slug.split('@')[0]}"


def _steps(task: Task, preset) -> float:
    """Training work of a build (megapixel-iterations; 0 when not a training build or unknown)."""
    if task.action != "build":
        return 0.0
    from bench.estimate import work_of

    try:
        return work_of(task, preset).steps
    except Exception:  # a plugin expert not installed here, a recipe that no longer exists
        return 0.0


def forecast(plan, workspace: Workspace) -> Forecast:
    """The ``Forecast`` of ``plan`` in ``workspace``: cache state and the estimate from recorded times."""
    builds, built, evals, done = cache_state(plan, workspace)
    out = Forecast(builds, built, evals, done)
    todo = [*builds, *evals]
    if not todo:
        return out
    found = records(workspace.root, plan.preset.name, plan.device)
    out.records = len(found)
    own: dict[str, list[float]] = {}
    similar: dict[str, list[tuple[Task, float]]] = {}
    for record in found:
        own.setdefault(_same(record.task), []).append(record.seconds)
        try:
            task = Task.from_dict(record.task)
        except (KeyError, TypeError, ValueError):
            continue
        similar.setdefault(_label(task), []).append((task, record.seconds))
    steps: dict[int, float] = {}  # training work of each task once (work_of builds its recipe)

    def work(task: Task) -> float:
        if id(task) not in steps:
            steps[id(task)] = _steps(task, plan.preset)
        return steps[id(task)]

    for task in todo:
        seconds = _estimate(task, own, similar, work)
        if seconds is None:
            out.unknown += 1
            continue
        value, exact = seconds
        out.seconds += value
        out.own += exact
        out.similar += not exact
    return out


def _estimate(
    task: Task,
    own: dict[str, list[float]],
    similar: dict[str, list[tuple[Task, float]]],
    work: Callable[[Task], float],
) -> tuple[float, bool] | None:
    """``(seconds, from its own record)`` of ``task``, or None when nothing recorded is like it."""
    mine = own.get(_same(task.to_dict()))
    if mine:
        return sum(mine) / len(mine), True
    like = similar.get(_label(task))
    if not like:
        return None
    here = [
        (t, s) for t, s in like if t.scene == task.scene and dict(t.scene_kwargs) == dict(task.scene_kwargs)
    ]
    like = here or like
    steps = work(task)
    if steps > 0:
        scaled = [(s, work(t)) for t, s in like]
        scaled = [(s, w) for s, w in scaled if w > 0]
        if scaled:
            return sum(s for s, _ in scaled) / sum(w for _, w in scaled) * steps, False
    return sum(s for _, s in like) / len(like), False


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 10 * 60:
        return f"{seconds / 60:.1f} min"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _n(count: int, what: str) -> str:
    return f"{count} {what}{'' if count == 1 else 's'}"


def plan_lines(fc: Forecast, workers: int | None, where: Path, preset: str, device: str) -> list[str]:
    """The plan and its estimate (``bench.all`` prints them before any work): the tasks to compute and
    cached, the estimated task time (and its share per worker), and what the estimate is based on."""
    lines = [
        f"plan: {_n(len(fc.builds_todo), 'build')} to compute, {fc.builds_cached} cached; "
        f"{_n(len(fc.evals_todo), 'evaluation')} to compute, {fc.evals_cached} cached"
    ]
    if not fc.todo:
        lines.append("estimate: nothing to compute, every task is cached")
        return lines
    if fc.unknown == fc.todo:
        lines.append(
            f"estimate: unknown: no recorded time of these or similar tasks (preset {preset}, {device}) "
            f"in {where}; a finished run records them"
        )
        return lines
    bound = "at least" if fc.unknown else "about"
    wall = f", so at least {_duration(fc.seconds / workers)} on {workers} workers" if workers else ""
    lines.append(f"estimate: {bound} {_duration(fc.seconds)} of task time{wall}")
    parts = []
    if fc.own:
        parts.append(f"{_n(fc.own, 'task')} timed by their own earlier run (older code)")
    if fc.similar:
        parts.append(
            f"{_n(fc.similar, 'task')} by similar ones (same kind and experts, training scaled by its steps)"
        )
    if fc.unknown:
        parts.append(f"{fc.unknown} unknown and left out")
    lines.append(
        f"  from {_n(fc.records, 'task time')} recorded in {where} (preset {preset}, {device}): "
        f"{', '.join(parts)}; process starts and dependency waits not counted"
    )
    return lines
