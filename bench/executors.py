"""Executors: start one task at a time, each in its own process, and report its outcome as a future.

* ``LocalExecutor``: up to ``jobs`` workers on this machine (``python -m bench.worker <job>`` as a
  subprocess with its output in the task's log). With ``gpus``, ``jobs_per_gpu`` workers per GPU, each
  started with ``CUDA_VISIBLE_DEVICES`` naming its one GPU (round robin over the GPUs).
* ``SubmititExecutor``: submitit (``AutoExecutor``): Slurm on a cluster, or submitit's local executor
  (``cluster="local"``), each task a job running ``bench.worker.run_job``, or ``pack`` tasks per job run
  one after another (``bench.worker.run_jobs``).

A local worker exits with the bench: on Linux it is started with ``PR_SET_PDEATHSIG`` (SIGTERM, which a
training worker answers with a checkpoint), so a bench killed with ``kill -9`` leaves no worker running.

Neither schedules anything: ``bench.runner`` submits a task once its dependencies are built, and never
more than ``capacity`` at a time. A failed task is reported with its log path and never stops the others.
"""

from __future__ import annotations

import ctypes
import functools
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
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


PR_SET_PDEATHSIG = 1
"""``prctl`` option (``linux/prctl.h``): the signal a process gets when the thread that started it ends."""


@functools.cache
def _prctl() -> Callable[..., int] | None:
    """libc's ``prctl`` (None where there is none: not Linux), looked up before any fork: the child only
    calls it."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError, TypeError):
        return None


def exit_with_parent(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """A ``preexec_fn`` that sends ``sig`` to the child when this process (its starting thread) ends, and
    ends a child whose parent is gone already; None where ``prctl`` is missing."""
    prctl, parent = _prctl(), os.getpid()
    if prctl is None:
        return None

    def arm() -> None:  # in the child, between fork and exec: no imports, no locks
        prctl(PR_SET_PDEATHSIG, int(sig))
        if os.getppid() != parent:
            os._exit(1)

    return arm


def visible_gpu(index: int) -> str:
    """The ``CUDA_VISIBLE_DEVICES`` value that shows a worker the ``index``-th GPU this process sees."""
    seen = os.environ.get("CUDA_VISIBLE_DEVICES")
    if seen is None:
        return str(index)
    return [d.strip() for d in seen.split(",") if d.strip()][index]


class LocalExecutor:
    """Up to ``jobs`` tasks at a time on this machine, each in a fresh Python process; with ``gpus`` (indices
    of the GPUs this process sees), ``len(gpus) * jobs_per_gpu`` at a time, each on one GPU."""

    name = "local"

    def __init__(
        self,
        jobs: int = 1,
        threads: int | None = None,
        timeout: float | None = None,
        gpus: Sequence[int] = (),
        jobs_per_gpu: int = 1,
    ) -> None:
        if jobs < 1:
            raise ValueError(f"LocalExecutor: jobs must be >= 1, got {jobs}")
        if jobs_per_gpu < 1:
            raise ValueError(f"LocalExecutor: jobs_per_gpu must be >= 1, got {jobs_per_gpu}")
        self.gpus = list(gpus)
        self.jobs = len(self.gpus) * jobs_per_gpu if self.gpus else jobs
        self.threads = threads or max(1, (os.cpu_count() or 1) // self.jobs)
        self.timeout = timeout
        self._slots: queue.Queue[int] = queue.Queue()
        for slot in range(self.jobs if self.gpus else 0):  # a GPU per worker slot, round robin
            self._slots.put(self.gpus[slot % len(self.gpus)])
        self._running: set[subprocess.Popen] = set()
        self._lock = threading.Lock()
        self._pool: ThreadPoolExecutor | None = None

    def worker_env(self, gpu: int | None = None) -> dict[str, str]:
        """The environment of a worker: its threads, the repository on the path, and its GPU if any."""
        env = {
            **os.environ,
            "OMP_NUM_THREADS": str(self.threads),
            THREADS_ENV: str(self.threads),
            "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        }
        if gpu is not None:
            env["CUDA_VISIBLE_DEVICES"] = visible_gpu(gpu)
        return env

    def _one(self, task: Task, workspace: Workspace) -> Outcome:
        if not self.gpus:
            return self._run(task, workspace, None)
        gpu = self._slots.get()  # the pool has one thread per slot: never waits
        try:
            return self._run(task, workspace, gpu)
        finally:
            self._slots.put(gpu)

    def _run(self, task: Task, workspace: Workspace, gpu: int | None) -> Outcome:
        job = write_job(workspace, task, self.threads)
        log = workspace.log_path(task)
        log.parent.mkdir(parents=True, exist_ok=True)
        env = self.worker_env(gpu)
        start = time.perf_counter()
        with open(log, "w") as fh:
            proc = subprocess.Popen(
                [sys.executable, "-m", "bench.worker", str(job)],
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=REPO,
                preexec_fn=exit_with_parent(),
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
    """Tasks as submitit jobs: ``cluster="slurm"`` (or None: auto-detect) or ``"local"`` for testing.

    ``pack > 1`` runs up to that many ready tasks in one job, one after another: the tasks submitted within
    ``pack_wait`` seconds of each other (the runner submits every ready task at once) share a job, whose
    end reports each task's own outcome. ``parameters`` (``timeout_min``, ``gpus_per_node`` ...) are per
    job, so a packed job's time limit must cover its tasks (``bench.all`` multiplies it)."""

    name = "slurm"
    capacity = 1_000_000
    """Slurm queues the jobs itself: every ready task is submitted."""

    def __init__(
        self,
        cluster: str | None = None,
        parameters: dict[str, Any] | None = None,
        threads: int | None = None,
        poll_seconds: float = 2.0,
        pack: int = 1,
        pack_wait: float = 1.0,
    ) -> None:
        if pack < 1:
            raise ValueError(f"SubmititExecutor: pack must be >= 1, got {pack}")
        self.cluster = cluster
        self.parameters = dict(parameters or {})
        self.threads = threads
        self.poll_seconds = poll_seconds
        self.pack, self.pack_wait = pack, pack_wait
        self._executor: Any = None
        self._waiters: ThreadPoolExecutor | None = None
        self._batch: list[tuple[Task, Path, Path, Future]] = []
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()

    def executor(self, workspace: Workspace) -> Any:
        """The submitit executor (made once, with ``parameters``): what every job is submitted to."""
        import submitit

        if self._executor is None:
            self._executor = submitit.AutoExecutor(
                folder=workspace.root / "submitit" / "%j", cluster=self.cluster
            )
            self._executor.update_parameters(**{"timeout_min": 240, "name": "moegs-bench", **self.parameters})
            self._waiters = ThreadPoolExecutor(max_workers=32)
        return self._executor

    def submit(self, task: Task, workspace: Workspace) -> Future:
        """Submit ``task`` as a job (or into the next packed job); the future's result is its ``Outcome``
        once the job ends."""
        from bench.worker import run_job

        executor = self.executor(workspace)
        job_file = write_job(workspace, task, self.threads)
        log = workspace.log_path(task)
        log.parent.mkdir(parents=True, exist_ok=True)
        if self.pack == 1:
            job = executor.submit(run_job, str(job_file), True)
            start = time.perf_counter()
            return self._waiters.submit(lambda: self._outcomes([(task, log)], job, start)[0])
        future: Future = Future()
        with self._lock:
            self._batch.append((task, job_file, log, future))
            if len(self._batch) >= self.pack:
                self._flush_locked()
            elif self._timer is None:
                self._timer = threading.Timer(self.pack_wait, self._flush)
                self._timer.daemon = True
                self._timer.start()
        return future

    def _flush(self) -> None:
        with self._lock:
            self._flush_locked()

    def _flush_locked(self) -> None:
        """Submit the tasks gathered so far as one job (caller holds the lock)."""
        from bench.worker import run_jobs

        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        batch, self._batch = self._batch, []
        if not batch:
            return
        job = self._executor.submit(run_jobs, [str(job_file) for _, job_file, _, _ in batch], True)
        done = self._waiters.submit(
            self._outcomes, [(t, log) for t, _, log, _ in batch], job, time.perf_counter()
        )
        done.add_done_callback(lambda f: _settle([fut for *_, fut in batch], f))

    def _outcomes(self, tasks: list[tuple[Task, Path]], job: Any, start: float) -> list[Outcome]:
        """The outcome of each ``(task, log)`` of ``job``, once it ends."""
        while not job.done():
            time.sleep(self.poll_seconds)
        seconds = time.perf_counter() - start
        try:
            errors = job.result()
        except Exception as err:  # noqa: BLE001 - the job's failure, reported with its logs
            last = str(err).strip().splitlines()[-1] if str(err).strip() else ""
            errors = [f"{type(err).__name__}: {last} (submitit log: {job.paths.stderr})"] * len(tasks)
        if not isinstance(errors, list):  # run_job's dict: the one task succeeded
            errors = [""]
        return [Outcome(t, not why, log, seconds, why) for (t, log), why in zip(tasks, errors, strict=True)]

    def interrupt(self) -> None:
        """Ctrl-C: nothing to stop here; submitted jobs run on and the next run reuses what they finish."""

    def close(self) -> None:
        """Drop the tasks not yet submitted and stop waiting (submitted jobs run on)."""
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            for *_, future in self._batch:
                future.cancel()
            self._batch = []
        if self._waiters is not None:
            self._waiters.shutdown(wait=False, cancel_futures=True)
            self._executor = self._waiters = None


def _settle(futures: list[Future], done: Future) -> None:
    """Give each task's future its outcome from ``done`` (the packed job's list of outcomes)."""
    if done.cancelled():
        for future in futures:
            future.cancel()
        return
    for i, future in enumerate(futures):
        if not future.set_running_or_notify_cancel():  # dropped by close()
            continue
        if done.exception() is not None:
            future.set_exception(done.exception())
        else:
            future.set_result(done.result()[i])


def make_executor(kind: str, jobs: int = 1, **options: Any) -> LocalExecutor | SubmititExecutor:
    """``local`` | ``slurm`` | ``submitit-local`` (submitit's local executor, for tests). Options:
    ``timeout``, ``gpus``, ``jobs_per_gpu`` (local); ``cluster``, ``parameters``, ``threads``, ``pack``."""
    if kind == "local":
        return LocalExecutor(
            jobs=jobs,
            timeout=options.get("timeout"),
            gpus=options.get("gpus", ()),
            jobs_per_gpu=options.get("jobs_per_gpu", 1),
        )
    if kind in ("slurm", "submitit-local"):
        cluster = "local" if kind == "submitit-local" else options.get("cluster")
        return SubmititExecutor(
            cluster=cluster,
            parameters=options.get("parameters"),
            threads=options.get("threads"),
            pack=options.get("pack", 1),
        )
    raise ValueError(f"unknown executor {kind!r}; valid: local, slurm, submitit-local")
