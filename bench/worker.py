"""Run one task in this process: ``python -m bench.worker <job.json>`` (or ``run_job`` via submitit).

A job file holds the task, the workspace root, the thread count and the log path. A build leaves its
artefact in the store (or ``<key>.failed.json``); an evaluation writes its result JSON atomically,
``status: "failed"`` with the traceback when it raises. The exit status is 0 on success.

A ``cuda`` task runs on the first GPU the process sees (the local executor gives each worker one GPU
through ``CUDA_VISIBLE_DEVICES``); its artefacts and results record the GPU's model.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bench.cells import kind_module
from bench.cells import scene as scene_kind
from bench.codedeps import loaded_modules
from bench.context import Context
from bench.keys import file_sha256, versions
from bench.results import SCHEMA, now, write_json_atomic, write_result
from bench.store import Workspace
from bench.tasks import Task
from moegs.threads import start_cpu_workers

THREADS_ENV = "MOEGS_BENCH_THREADS"


def write_job(workspace: Workspace, task: Task, threads: int | None) -> Path:
    """The job file of ``task`` (what the worker process reads)."""
    path = workspace.job_path(task)
    write_json_atomic(
        path,
        {
            "task": task.to_dict(),
            "key": task.key,
            "workspace": str(workspace.root),
            "threads": threads,
            "log": str(workspace.log_path(task)),
            "code_version": task.code_version,
        },
    )
    return path


@contextmanager
def _redirect(log_path: Path | None):
    """Send this process's stdout/stderr (including C-level writes) to ``log_path``."""
    if log_path is None:
        yield
        return
    log_path.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(log_path, "a") as fh:
        os.dup2(fh.fileno(), 1)
        os.dup2(fh.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def _start_threads(threads: int | None) -> None:
    """Set torch's thread count (the job's, else ``$MOEGS_BENCH_THREADS``), then start the threads before
    the cell computes, so that every worker process computes alike (``moegs.threads``)."""
    threads = threads or (int(os.environ[THREADS_ENV]) if os.environ.get(THREADS_ENV) else None)
    if threads:
        import torch

        torch.set_num_threads(threads)
    start_cpu_workers()


def task_device(task: Task):
    """The ``torch.device`` of ``task``: the CPU, or the first GPU this process sees for ``cuda``
    (``ValueError`` in one line when it sees none)."""
    from moegs.device import resolve_device

    return resolve_device("cuda:0" if task.device == "cuda" else task.device)


def _evaluate(task: Task, ctx: Context, log: Path) -> dict[str, Any]:
    start = time.perf_counter()
    base = {
        "schema": SCHEMA,
        "key": task.key,
        "task": task.to_dict(),
        "identity": task.identity(),
        "log": str(log),
        "created": now(),
    }
    try:
        scene_meta = ctx.meta(scene_kind.task_for(task))
        loaded = time.perf_counter()
        payload = kind_module(task.kind).run(task, ctx)
        check_finite_metrics(payload["metrics"])
        files_dir = ctx.workspace.files_dir(task)
        files = {name: file_sha256(files_dir / name) for name in payload.get("files", [])}
        result = {
            **base,
            "status": "ok",
            "metrics": payload["metrics"],
            "metric_profile": payload.get("metric_profile"),
            "per_view": payload.get("per_view", []),
            "details": payload.get("details", {}),
            "files": files,
            "scene": {k: scene_meta.get(k) for k in ("scene", "summary", "stand_in", "real", "input_hash")}
            | {"kwargs": dict(task.scene_kwargs)},
            "artifacts": ctx.used,
            "preset": ctx.preset.to_dict(),
            "device": ctx.device_record(),
            "hashes": {
                "task_key": task.key,
                "scene_input": scene_meta.get("input_hash"),
                "checkpoints": {k: v["files"] for k, v in ctx.used.items() if v["files"]},
            },
            "timings": {
                "total_s": time.perf_counter() - start,
                "load_s": loaded - start,
                "eval_s": time.perf_counter() - loaded,
            },
            "versions": versions(),
            "modules_loaded": loaded_modules(),
        }
    except Exception as err:
        result = {
            **base,
            "status": "failed",
            "metrics": {},
            "artifacts": ctx.used,
            "device": ctx.device_record(),
            "error": f"{type(err).__name__}: {err}",
            "traceback": traceback.format_exc(),
            "timings": {"total_s": time.perf_counter() - start},
            "versions": versions(),
        }
        write_result(ctx.workspace.result_path(task), result)
        raise
    write_result(ctx.workspace.result_path(task), result)
    return result


def check_finite_metrics(metrics: dict[str, Any]) -> None:
    """``ValueError`` naming the metrics that are NaN or infinite (None means not applicable)."""
    bad = {k: v for k, v in metrics.items() if isinstance(v, float) and not math.isfinite(v)}
    if bad:
        raise ValueError(f"non-finite metric(s) {bad}: the cell failed, no number enters a table")


def _build(task: Task, ctx: Context, log: Path) -> dict[str, Any]:
    try:
        ctx.artifact(task)
    except Exception as err:
        write_json_atomic(
            ctx.workspace.failure_path(task),
            {
                "key": task.key,
                "task": task.to_dict(),
                "error": f"{type(err).__name__}: {err}",
                "traceback": traceback.format_exc(),
                "log": str(log),
                "created": now(),
            },
        )
        raise
    return {"key": task.key, "status": "ok"}


def run_job(job_file: str | Path, redirect: bool = False) -> dict[str, Any]:
    """Run the task of ``job_file``; ``redirect`` sends output to the job's log (submitit path)."""
    job = json.loads(Path(job_file).read_text())
    task = Task.from_dict(job["task"])
    if task.key != job["key"]:
        edited = "library code" if task.code_version != job["code_version"] else "preset"
        raise RuntimeError(
            f"{job_file}: task key changed since the job was written ({edited} edited during the run; "
            f"run bench.all again): {job['key']} -> {task.key}"
        )
    workspace = Workspace(job["workspace"])
    log = Path(job["log"])
    with _redirect(log if redirect else None):
        print(
            f"[bench] {time.strftime('%H:%M:%S')} {task.action} {task.slug} on {task.device} key={task.key}",
            flush=True,
        )
        _start_threads(job.get("threads"))
        ctx = Context(workspace, task.preset, progress=False, device=task_device(task))
        ctx.task = task
        if task.action == "build":
            return _build(task, ctx, log)
        result = _evaluate(task, ctx, log)
        return {"key": task.key, "status": result["status"]}


def _append_traceback(job_file: str | Path) -> None:
    """Append the exception being handled to the log of ``job_file`` (when it names one)."""
    try:
        log = json.loads(Path(job_file).read_text()).get("log")
    except (OSError, ValueError):
        return
    if log:
        with open(log, "a") as fh:
            fh.write(traceback.format_exc())


def run_jobs(job_files: list[str | Path], redirect: bool = True) -> list[str]:
    """Run several job files one after another (a packed Slurm job): per job ``""`` when it succeeded, else
    its error in one line (its traceback goes to its log); one failure does not stop the others."""
    errors = []
    for job_file in job_files:
        try:
            run_job(job_file, redirect)
            errors.append("")
        except Exception as err:  # noqa: BLE001 - reported per task, with the traceback in its log
            _append_traceback(job_file)
            errors.append(f"{type(err).__name__}: {err}".splitlines()[0])
    return errors


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m bench.worker <job.json>", file=sys.stderr)
        return 2
    try:
        run_job(args[0])
    except Exception:
        traceback.print_exc()
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
