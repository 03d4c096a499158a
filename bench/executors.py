"""Executors: run a batch of independent tasks, each in its own process, and report every outcome.

* ``LocalExecutor``: a ``concurrent.futures`` thread pool, each thread running
  ``python -m bench.worker <job>`` as a subprocess with its output in the task's log.
* ``SubmititExecutor``: submitit (``AutoExecutor``): Slurm on a cluster, or submitit's local executor
  (``cluster="local"``), each task a job running ``bench.worker.run_job``.

Neither schedules anything itself: the runner hands them one dependency level at a time. A failed
task is reported with its log path and never stops the others.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.keys import REPO
from bench.store import Workspace
from bench.tasks import Task
from bench.worker import THREADS_ENV, write_job


@dataclass
class Outcome:
    task: Task
    ok: bool
    log: Path
    seconds: float
    error: str = ""


Progress = Callable[[Outcome], None]


def _tail(path: Path, lines: int = 3) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])


class LocalExecutor:
    """Up to ``jobs`` tasks at a time on this machine, each in a fresh Python process."""

    name = "local"

    def __init__(self, jobs: int = 1, threads: int | None = None, timeout: float | None = None) -> None:
        if jobs < 1:
            raise ValueError(f"LocalExecutor: jobs must be >= 1, got {jobs}")
        self.jobs = jobs
        self.threads = threads or max(1, (os.cpu_count() or 1) // jobs)
        self.timeout = timeout
        self._running: set[subprocess.Popen] = set()
        self._lock = threading.Lock()

    def _one(self, task: Task, workspace: Workspace) -> Outcome:
        job = write_job(workspace, task, self.threads)
        log = workspace.log_path(task)
        log.parent.mkdir(parents=True, exist_ok=True)
        env = {
            **os.environ,
            "OMP_NUM_THREADS": str(self.threads),
            THREADS_ENV: str(self.threads),
            "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        }
        start = time.perf_counter()
        with open(log, "w") as fh:
            proc = subprocess.Popen(
                [sys.executable, "-m", "bench.worker", str(job)],
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=REPO,
            )
            with self._lock:
                self._running.add(proc)
            try:
                code = proc.wait(timeout=self.timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                code = None
            finally:
                with self._lock:
                    self._running.discard(proc)
        seconds = time.perf_counter() - start
        if code == 0:
            return Outcome(task, True, log, seconds)
        why = f"timed out after {self.timeout}s" if code is None else f"exit status {code}"
        return Outcome(task, False, log, seconds, f"{why}: {_tail(log)}")

    def run(self, tasks: list[Task], workspace: Workspace, progress: Progress | None = None) -> list[Outcome]:
        """Run ``tasks``; on Ctrl-C the queued ones are dropped and the running workers get SIGINT (a
        training worker writes its checkpoint first), then ``KeyboardInterrupt`` goes on."""
        outcomes = []
        pool = ThreadPoolExecutor(max_workers=self.jobs)
        try:
            futures = [pool.submit(self._one, t, workspace) for t in tasks]
            for fut in as_completed(futures):
                outcome = fut.result()
                outcomes.append(outcome)
                if progress:
                    progress(outcome)
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            with self._lock:
                for proc in self._running:
                    proc.send_signal(signal.SIGINT)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return outcomes


class SubmititExecutor:
    """Tasks as submitit jobs: ``cluster="slurm"`` (or None: auto-detect) or ``"local"`` for testing."""

    name = "slurm"

    def __init__(
        self,
        cluster: str | None = None,
        parameters: dict[str, Any] | None = None,
        threads: int | None = None,
        poll_seconds: float = 2.0,
    ) -> None:
        self.cluster = cluster
        self.parameters = dict(parameters or {})
        self.threads = threads
        self.poll_seconds = poll_seconds

    def run(self, tasks: list[Task], workspace: Workspace, progress: Progress | None = None) -> list[Outcome]:
        import submitit

        from bench.worker import run_job

        if not tasks:
            return []
        folder = workspace.root / "submitit" / "%j"
        executor = submitit.AutoExecutor(folder=folder, cluster=self.cluster)
        params = {"timeout_min": 240, "name": "moegs-bench", **self.parameters}
        executor.update_parameters(**params)
        jobs, starts = [], {}
        for task in tasks:
            job_file = write_job(workspace, task, self.threads)
            workspace.log_path(task).parent.mkdir(parents=True, exist_ok=True)
            job = executor.submit(run_job, str(job_file), True)
            jobs.append((task, job))
            starts[task.key] = time.perf_counter()
        outcomes = []
        pending = list(jobs)
        while pending:
            still = []
            for task, job in pending:
                if not job.done():
                    still.append((task, job))
                    continue
                log = workspace.log_path(task)
                seconds = time.perf_counter() - starts[task.key]
                try:
                    job.result()
                    outcome = Outcome(task, True, log, seconds)
                except Exception as err:  # noqa: BLE001 - the job's failure, reported with its logs
                    outcome = Outcome(
                        task,
                        False,
                        log,
                        seconds,
                        f"{type(err).__name__}: {str(err).strip().splitlines()[-1] if str(err) else ''}"
                        f" (submitit log: {job.paths.stderr})",
                    )
                outcomes.append(outcome)
                if progress:
                    progress(outcome)
            pending = still
            if pending:
                time.sleep(self.poll_seconds)
        return outcomes


def make_executor(kind: str, jobs: int = 1, **options: Any) -> LocalExecutor | SubmititExecutor:
    """``local`` | ``slurm`` | ``submitit-local`` (submitit's local executor, for tests)."""
    if kind == "local":
        return LocalExecutor(jobs=jobs, timeout=options.get("timeout"))
    if kind in ("slurm", "submitit-local"):
        cluster = "local" if kind == "submitit-local" else options.get("cluster")
        return SubmititExecutor(
            cluster=cluster, parameters=options.get("parameters"), threads=options.get("threads")
        )
    raise ValueError(f"unknown executor {kind!r}; valid: local, slurm, submitit-local")
