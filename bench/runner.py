"""Run a plan: build the missing artefacts level by level, then evaluate the cells without a result.

Finished work is skipped (artefacts marked DONE, result JSONs that are valid and ``ok``), so an
interrupted run resumes where it stopped. Failures are collected with their log paths; tasks whose
dependencies failed are not started and get a ``failed`` result naming the dependency.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

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

    @property
    def ok(self) -> bool:
        return not self.failures and not self.blocked


def _deps(task: Task) -> list[Task]:
    return getattr(kind_module(task.kind), "deps", lambda _t: [])(task)


def _say(message: str) -> None:
    tqdm.write(message, file=sys.stderr)


def _run_batch(
    executor: LocalExecutor | SubmititExecutor,
    tasks: list[Task],
    workspace: Workspace,
    label: str,
    show: bool,
) -> list[Outcome]:
    if not tasks:
        return []
    bar = tqdm(total=len(tasks), desc=label, disable=not show, dynamic_ncols=True, file=sys.stderr)

    def progress(outcome: Outcome) -> None:
        bar.update(1)
        status = "ok" if outcome.ok else "FAILED"
        bar.set_postfix_str(f"{status} {outcome.task.slug} ({outcome.seconds:.0f}s)")
        if not outcome.ok:
            _say(f"FAILED {outcome.task.action} {outcome.task.slug}: {outcome.error}\n  log: {outcome.log}")

    outcomes = executor.run(tasks, workspace, progress)
    bar.close()
    return outcomes


def execute(
    plan: Plan, workspace: Workspace, executor: LocalExecutor | SubmititExecutor, progress: bool = True
) -> RunSummary:
    """Build and evaluate everything the plan needs that is not already done."""
    start = time.perf_counter()
    summary = RunSummary()
    dead: dict[str, str] = {}  # build key -> reason
    levels = plan.build_levels()
    for depth, level in enumerate(levels):
        todo = []
        for task in level:
            if workspace.is_built(task):
                summary.builds_reused += 1
                continue
            gone = [d for d in _deps(task) if d.key in dead]
            if gone:
                dead[task.key] = f"dependency {gone[0].slug} failed ({dead[gone[0].key]})"
                summary.blocked[task.key] = dead[task.key]
                continue
            todo.append(task)
        outcomes = _run_batch(executor, todo, workspace, f"build level {depth + 1}/{len(levels)}", progress)
        summary.builds_run += len(todo)
        for o in outcomes:
            if not o.ok:
                summary.failures.append(o)
                dead[o.task.key] = f"log {o.log}"

    todo = []
    for task in plan.eval_tasks():
        path = workspace.result_path(task)
        try:
            if load_valid(path, task) is not None:
                summary.evals_reused += 1
                continue
        except ResultError as err:
            summary.invalid_results.append(str(err))
            _say(f"WARNING invalid result file, recomputing: {err}")
        gone = [b for b in plan.closure(task) if b.key in dead]
        if gone:
            reason = f"dependency {gone[0].slug} failed ({dead[gone[0].key]})"
            summary.blocked[task.key] = reason
            write_result(
                path,
                {
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
                },
            )
            continue
        todo.append(task)
    outcomes = _run_batch(executor, todo, workspace, "evaluate", progress)
    summary.evals_run = len(todo)
    summary.failures += [o for o in outcomes if not o.ok]
    summary.seconds = time.perf_counter() - start
    return summary
