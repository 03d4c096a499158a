"""Run a plan: every missing artefact and every cell without a result, each as soon as what it needs
is built.

The plan is a graph: an expert build waits for its scene, a router for its experts, a cell for every
artefact it reads. A task starts once its dependencies are built (longest chain of dependents first,
then builds before cells), so a router or a cell never waits for an unrelated expert. Finished work
is skipped (artefacts marked DONE, result JSONs that are valid and ``ok``), so an interrupted run
resumes where it stopped. Failures are collected with their log paths; tasks whose dependencies
failed are not started, and such a cell gets a ``failed`` result naming the dependency.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass, field
from typing import Any

from tqdm.auto import tqdm

from bench.cells import kind_module
from bench.executors import LocalExecutor, Outcome, SubmititExecutor
from bench.keys import versions
from bench.plan import Plan
from bench.results import SCHEMA, ResultError, load_valid, now, write_result
from bench.store import Workspace
from bench.tasks import Task


@dataclass
class RunSummary:
    builds_run: int = 0
    builds_reused: int = 0
    evals_run: int = 0
    evals_reused: int = 0
    failures: list[Outcome] = field(default_factory=list)
    blocked: dict[str, str] = field(default_factory=dict)
    """eval/build key -> why it was not started."""
    invalid_results: list[str] = field(default_factory=list)
    seconds: float = 0.0
    kind_seconds: dict[str, float] = field(default_factory=dict)
    """Seconds of the cells that ran, by ``"<action> <kind>"`` (``build expert``, ``eval moe``): where a
    run's time went."""

    @property
    def ok(self) -> bool:
        return not self.failures and not self.blocked


def _deps(task: Task) -> list[Task]:
    return getattr(kind_module(task.kind), "deps", lambda _t: [])(task)


def _say(message: str) -> None:
    tqdm.write(message, file=sys.stderr)


def heights(graph: dict[str, list[str]]) -> dict[str, int]:
    """Length of the longest chain of dependents below each node of ``graph`` (node -> its dependencies)."""
    dependents: dict[str, list[str]] = {k: [] for k in graph}
    for key, deps in graph.items():
        for d in deps:
            dependents[d].append(key)
    memo: dict[str, int] = {}

    def height(key: str) -> int:
        if key not in memo:
            memo[key] = 1 + max((height(k) for k in dependents[key]), default=-1)
        return memo[key]

    return {k: height(k) for k in graph}


def schedule(
    tasks: dict[str, Task],
    graph: dict[str, list[str]],
    executor: LocalExecutor | SubmititExecutor,
    workspace: Workspace,
    on_outcome: Callable[[Outcome], None],
    on_blocked: Callable[[Task, str], None],
) -> None:
    """Run ``tasks`` (key -> task, in priority order for ties) through ``executor``, each once every
    key in ``graph[key]`` (its dependencies among ``tasks``) finished ok, at most ``executor.capacity``
    at a time, longest chain of dependents first. ``on_outcome(outcome)`` reports each finished task;
    ``on_blocked(task, reason)`` each task not started because a dependency failed (transitively).
    Ctrl-C interrupts the executor's running tasks and goes on as ``KeyboardInterrupt``."""
    order = {k: i for i, k in enumerate(tasks)}
    height = heights(graph)
    waiting, running, ok, dead = dict(tasks), {}, set(), {}
    try:
        while waiting or running:
            changed = True
            while changed:  # a failure blocks every task downstream of it
                changed = False
                for key in list(waiting):
                    bad = next((d for d in graph[key] if d in dead), None)
                    if bad is not None:
                        dead[key] = f"dependency {tasks[bad].slug} failed ({dead[bad]})"
                        on_blocked(waiting.pop(key), dead[key])
                        changed = True
            ready = sorted(
                (k for k in waiting if all(d in ok for d in graph[k])), key=lambda k: (-height[k], order[k])
            )
            for key in ready[: max(0, executor.capacity - len(running))]:
                running[executor.submit(waiting.pop(key), workspace)] = key
            if not running:
                break
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in finished:
                key, outcome = running.pop(future), future.result()
                if outcome.ok:
                    ok.add(key)
                else:
                    dead[key] = f"log {outcome.log}"
                on_outcome(outcome)
    except KeyboardInterrupt:
        executor.interrupt()
        raise
    finally:
        executor.close()


def _failed_result(task: Task, reason: str) -> dict[str, Any]:
    return {
        "schema": SCHEMA,
        "status": "failed",
        "key": task.key,
        "task": task.to_dict(),
        "identity": task.identity(),
        "metrics": {},
        "error": reason,
        "timings": {},
        "versions": versions(),
        "created": now(),
    }


def execute(
    plan: Plan, workspace: Workspace, executor: LocalExecutor | SubmititExecutor, progress: bool = True
) -> RunSummary:
    """Build and evaluate everything the plan needs that is not already done."""
    start = time.perf_counter()
    summary = RunSummary()
    tasks: dict[str, Task] = {}
    graph: dict[str, list[str]] = {}
    for level in plan.build_levels():
        for task in level:
            if workspace.is_built(task):
                summary.builds_reused += 1
            else:
                tasks[task.key] = task
    for key, task in tasks.items():
        graph[key] = [d.key for d in _deps(task) if d.key in tasks]
    for task in plan.eval_tasks():
        try:
            if load_valid(workspace.result_path(task), task) is not None:
                summary.evals_reused += 1
                continue
        except ResultError as err:
            summary.invalid_results.append(str(err))
            _say(f"WARNING invalid result file, recomputing: {err}")
        tasks[task.key] = task
        graph[task.key] = [b.key for b in plan.closure(task) if b.key in tasks]

    bar = tqdm(
        total=len(tasks), desc="build and evaluate", disable=not progress, dynamic_ncols=True, file=sys.stderr
    )

    def on_outcome(outcome: Outcome) -> None:
        bar.update(1)
        bar.set_postfix_str(
            f"{'ok' if outcome.ok else 'FAILED'} {outcome.task.slug} ({outcome.seconds:.0f}s)"
        )
        what = f"{outcome.task.action} {outcome.task.kind}"
        summary.kind_seconds[what] = summary.kind_seconds.get(what, 0.0) + outcome.seconds
        if outcome.task.action == "build":
            summary.builds_run += 1
        else:
            summary.evals_run += 1
        if not outcome.ok:
            summary.failures.append(outcome)
            _say(f"FAILED {outcome.task.action} {outcome.task.slug}: {outcome.error}\n  log: {outcome.log}")

    def on_blocked(task: Task, reason: str) -> None:
        bar.update(1)
        summary.blocked[task.key] = reason
        if task.action != "build":
            write_result(workspace.result_path(task), _failed_result(task, reason))

    try:
        schedule(tasks, graph, executor, workspace, on_outcome, on_blocked)
    finally:
        bar.close()
    summary.seconds = time.perf_counter() - start
    return summary
