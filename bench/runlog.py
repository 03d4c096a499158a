"""The workspace's record of ``bench.all`` runs: when, on which machine and code, how long, what ran.

A report rendered later from cached cells (``--no-run``) has no run of its own; it lists the runs of its
plan (same keys digest, so the same cells) that the workspace recorded, so a cold run's wall clock and
its machine stay with the outputs built from its cells instead of being typed into prose. A run is
recorded once its cells are done, before its outputs are written, so its own report lists it too. An
interrupted run is not recorded (the run that resumes it is, as ``resumed``), nor is a ``--no-run``
render; a report of the full plan does not list runs of a ``--tables`` subset (another digest).
``<workspace>/runs.json``: ``{"runs": [entry, ...]}``, oldest first, rewritten atomically per run.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any

from bench.keys import git_commit
from bench.readme import machine_line
from bench.results import write_json_atomic

FILE = "runs.json"
SHOWN = 5  # a report lists this many runs of its plan (``recent``), and how many more there are
COUNTS = ("builds_run", "builds_reused", "evals_run", "evals_reused", "failures")
TEXTS = ("finished", "preset", "keys_digest", "machine", "executor")
FIELDS = (*TEXTS, "git", "jobs", *COUNTS, "seconds")


def runs_path(workspace_root: Path) -> Path:
    return workspace_root / FILE


def read_runs(workspace_root: Path) -> list[dict[str, Any]]:
    """Every recorded run, oldest first (none when the file does not exist); ``ValueError`` naming the
    file and the entry when one is not a run of this format."""
    path = runs_path(workspace_root)
    if not path.is_file():
        return []
    try:
        runs = json.loads(path.read_text(encoding="utf-8"))["runs"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as err:
        raise ValueError(f"{path}: not a run record ({{'runs': [...]}}): {err}") from err
    if not isinstance(runs, list):
        raise ValueError(f"{path}: 'runs' must be a list, got {type(runs).__name__}")
    for i, entry in enumerate(runs):
        why = _malformed(entry)
        if why:
            raise ValueError(f"{path}: runs[{i}] {why}; move the file aside to start a new record")
    return runs


def _malformed(entry: Any) -> str:
    """Why ``entry`` is not a run of this format ('' when it is)."""
    if not isinstance(entry, dict):
        return f"is a {type(entry).__name__}, not an object"
    missing = [k for k in FIELDS if k not in entry]
    if missing:
        return f"lacks {missing}"
    number = (int, float)
    wrong = [k for k in TEXTS if not isinstance(entry[k], str)]
    wrong += [
        k for k in (*COUNTS, "seconds") if not isinstance(entry[k], number) or isinstance(entry[k], bool)
    ]
    wrong += [] if entry["jobs"] is None or isinstance(entry["jobs"], int) else ["jobs"]
    wrong += [] if isinstance(entry["git"], dict) else ["git"]
    return f"has fields of the wrong type: {wrong}" if wrong else ""


def record_run(
    workspace_root: Path,
    preset: str,
    identity: dict[str, Any],
    run: dict[str, Any],
    executor: str,
    jobs: int | None,
    seconds: float,
    device: str = "cpu",
) -> dict[str, Any]:
    """Append one ``bench.all`` run of the plan ``identity`` (``Plan.identity``) whose cells are done;
    ``run``: the runner's counts (``bench.all``'s ``run`` dict); ``jobs``: the local executor's parallel
    tasks (None for the others); ``seconds``: the command's wall clock so far (planning and cells, before
    the outputs); ``device``: where the cells ran (``cpu``, ``cuda (1 x <GPU>)``). Returns the entry."""
    entry = {
        "finished": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "preset": preset,
        "specs": identity["specs"],
        "keys_digest": identity["keys_digest"],
        "git": git_commit(),  # {"commit", "dirty"}: dirty when moegs/ had uncommitted changes
        "machine": machine_line(),
        "executor": executor,
        "jobs": jobs,
        "device": device,
        **{k: run[k] for k in COUNTS},
        "failures": len(run["failures"]),  # failed cells are among those run
        "cells_seconds": round(run["seconds"], 1),
        "seconds": round(seconds, 1),
        "minutes_by_kind": by_kind(run.get("kind_seconds") or {}),
    }
    write_json_atomic(runs_path(workspace_root), {"runs": [*read_runs(workspace_root), entry]})
    return entry


def by_kind(kind_seconds: dict[str, float]) -> dict[str, float]:
    """``{"build expert": minutes, ...}``, the largest first (``RunSummary.kind_seconds``)."""
    return {k: round(v / 60, 2) for k, v in sorted(kind_seconds.items(), key=lambda kv: -kv[1])}


def runs_of(workspace_root: Path, keys_digest: str) -> list[dict[str, Any]]:
    """The recorded runs of the plan whose keys digest is ``keys_digest``, oldest first."""
    return [r for r in read_runs(workspace_root) if r["keys_digest"] == keys_digest]


def cache_state(entry: dict[str, Any]) -> str:
    """``cold`` (every cell ran), ``warm`` (cells reused, none newly computed: the ones that ran, if any,
    failed again) or ``resumed`` (some computed, some reused)."""
    computed = entry["builds_run"] + entry["evals_run"] - entry["failures"]
    reused = entry["builds_reused"] + entry["evals_reused"]
    return "cold" if reused == 0 else "warm" if computed <= 0 else "resumed"


def last_computing(history: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The newest run of ``history`` that computed cells (cold or resumed), or None."""
    return next((r for r in reversed(history) if cache_state(r) != "warm"), None)


def recent(history: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The newest ``SHOWN`` runs of ``history``, oldest first; the newest run that computed cells
    (``last_computing``) stays among them however many warm runs came after it."""
    shown = history[-SHOWN:]
    computing = last_computing(history)
    if computing is not None and computing not in shown:
        shown = [computing, *shown[1:]]
    return shown


def took(entry: dict[str, Any], machine: bool = True) -> str:
    """``44.7 min cold (2 jobs, <cpu>)``: the run's wall clock, cache state and machine; without
    ``machine``, its thread count only (``44.7 min cold (2 jobs, 2 CPU threads)``)."""
    minutes = entry["seconds"] / 60
    time = f"{minutes:.1f} min" if minutes >= 1 else f"{entry['seconds']:.0f} s"
    how = f"{entry['jobs']} jobs" if entry["jobs"] else entry["executor"]
    if entry.get("device", "cpu") != "cpu":  # older entries have no device: they ran on the CPU
        how += f" on {entry['device']}"
    if machine:
        return f"{time} {cache_state(entry)} ({how}, {entry['machine']})"
    threads = re.search(r"(\d+) logical CPUs", entry["machine"])
    return f"{time} {cache_state(entry)} ({how}" + (f", {threads[1]} CPU threads)" if threads else ")")


def describe(entry: dict[str, Any]) -> str:
    """One line: ``2026-12-02 07:37: 89 builds + 97 evaluations run, 0 reused, 44.7 min cold (2 jobs,
    <cpu>), git 680b0dc``."""
    failed = f", {entry['failures']} failed" if entry["failures"] else ""
    git = entry["git"]
    version = (git.get("commit") or "?")[:7] + (
        " with uncommitted changes to moegs" if git.get("dirty") else ""
    )
    return (
        f"{entry['finished'][:16]}: {entry['builds_run']} builds + {entry['evals_run']} evaluations run, "
        f"{entry['builds_reused'] + entry['evals_reused']} reused{failed}, {took(entry)}, git {version}"
    )
