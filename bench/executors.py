"""Executors: start one task at a time, each in its own process, and report its outcome as a future.

* ``LocalExecutor``: up to ``jobs`` workers on this machine (``python -m bench.worker <job>`` as a
  subprocess with its output in the task's log).
* ``SubmititExecutor``: submitit (``AutoExecutor``): Slurm on a cluster, or submitit's local executor
  (``cluster="local"``), each task a job running ``bench.worker.run_job``.

Neither schedules anything: ``bench.runner`` submits a task once its dependencies are built, and never
more than ``capacity`` at a time. A failed task is reported with its log path and never stops the others.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
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
        self._pool: ThreadPoolExecutor | None = None

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

    @property
    def capacity(self) -> int:
        """How many tasks run at once."""
        return self.jobs

    def submit(self, task: Task, workspace: Workspace) -> Future:
        """Start ``task`` (queued when ``capacity`` tasks already run); the future gives its ``Outcome``."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self.jobs)
        return self._pool.submit(self._one, task, workspace)

    def interrupt(self) -> None:
        """Ctrl-C: drop the queued tasks and send SIGINT to the running workers (a training worker
        writes its checkpoint first); :meth:`close` then waits for them."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        with self._lock:
            for proc in self._running:
                proc.send_signal(signal.SIGINT)

    def close(self) -> None:
        """Wait for the running workers and release the pool."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class SubmititExecutor:
    """Tasks as submitit jobs: ``cluster="slurm"`` (or None: auto-detect) or ``"local"`` for testing."""

    name = "slurm"
    capacity = 1_000_000
    """Slurm queues the jobs itself: every ready task is submitted."""

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
        self._executor: Any = None
        self._waiters: ThreadPoolExecutor | None = None

    def submit(self, task: Task, workspace: Workspace) -> Future:
        """Submit ``task`` as a job; the future's result is its ``Outcome`` once the job ends."""
        import submitit

        from bench.worker import run_job

        if self._executor is None:
            self._executor = submitit.AutoExecutor(
                folder=workspace.root / "submitit" / "%j", cluster=self.cluster
            )
            self._executor.update_parameters(**{"timeout_min": 240, "name": "moegs-bench", **self.parameters})
            self._waiters = ThreadPoolExecutor(max_workers=32)
        job_file = write_job(workspace, task, self.threads)
        workspace.log_path(task).parent.mkdir(parents=True, exist_ok=True)
        job = self._executor.submit(run_job, str(job_file), True)
        return self._waiters.submit(self._wait, task, job, workspace.log_path(task), time.perf_counter())

    def _wait(self, task: Task, job: Any, log: Path, start: float) -> Outcome:
        while not job.done():
            time.sleep(self.poll_seconds)
        seconds = time.perf_counter() - start
        try:
            job.result()
        except Exception as err:  # noqa: BLE001 - the job's failure, reported with its logs
            last = str(err).strip().splitlines()[-1] if str(err).strip() else ""
            why = f"{type(err).__name__}: {last} (submitit log: {job.paths.stderr})"
            return Outcome(task, False, log, seconds, why)
        return Outcome(task, True, log, seconds)

    def interrupt(self) -> None:
        """Ctrl-C: nothing to stop here; submitted jobs run on and the next run reuses what they finish."""

    def close(self) -> None:
        if self._waiters is not None:
            self._waiters.shutdown(wait=False, cancel_futures=True)
            self._executor = self._waiters = None


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
