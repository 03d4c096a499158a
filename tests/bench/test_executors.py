"""``LocalExecutor``: each task in its own process with its share of the cores, its output in the task's
log; a failure or a timeout is an outcome that says why, Ctrl-C reaches the worker as SIGINT, and a worker
exits when the bench is killed.

The worker here is a shell script standing in for ``python -m bench.worker JOB`` (``FAKE_WORKER`` says
what it does), so these tests run no cell."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

import bench.executors
from bench.executors import LocalExecutor
from bench.keys import REPO
from bench.worker import THREADS_ENV

WORKER = f"""#!/bin/bash
echo "args $*"
echo "threads $OMP_NUM_THREADS ${THREADS_ENV}"
case "$FAKE_WORKER" in
  fail) for i in 1 2 3 4 5; do echo "line $i"; done; exit 3 ;;
  slow) for i in $(seq 300); do sleep 0.1; done ;;
  trap) trap 'echo "got SIGINT"; exit 130' INT; echo started; for i in $(seq 300); do sleep 0.1; done ;;
esac
"""


@pytest.fixture
def fake(tmp_path, monkeypatch):
    """A task, a workspace that puts its log under ``tmp_path``, and the fake worker in place."""
    script = tmp_path / "worker.sh"
    script.write_text(WORKER)
    script.chmod(0o755)
    monkeypatch.setattr(bench.executors, "sys", SimpleNamespace(executable=str(script)))
    monkeypatch.setattr(bench.executors, "write_job", lambda ws, task, threads: tmp_path / "job.json")
    task = SimpleNamespace(key="k", slug="expert-k")
    workspace = SimpleNamespace(log_path=lambda t: tmp_path / "logs" / f"{t.key}.log")
    return task, workspace


def _run(executor: LocalExecutor, task, workspace):
    try:
        return executor.submit(task, workspace).result(timeout=60)
    finally:
        executor.close()


def test_a_worker_gets_its_share_of_the_cores_and_its_log(fake, monkeypatch):
    task, workspace = fake
    monkeypatch.setattr(bench.executors.os, "cpu_count", lambda: 8)
    outcome = _run(LocalExecutor(jobs=2), task, workspace)
    assert outcome.ok and outcome.error == "" and outcome.log == workspace.log_path(task)
    job = outcome.log.parents[1] / "job.json"
    assert outcome.log.read_text().splitlines() == [f"args -m bench.worker {job}", "threads 4 4"]
    assert LocalExecutor(jobs=3, threads=1).threads == 1 and LocalExecutor(jobs=16).threads == 1


def test_a_failed_worker_is_an_outcome_with_the_end_of_its_log(fake, monkeypatch):
    monkeypatch.setenv("FAKE_WORKER", "fail")
    outcome = _run(LocalExecutor(), *fake)
    assert not outcome.ok and outcome.error == "exit status 3: line 3 | line 4 | line 5"


def test_a_worker_past_the_timeout_is_killed_and_failed(fake, monkeypatch):
    monkeypatch.setenv("FAKE_WORKER", "slow")
    start = time.perf_counter()
    outcome = _run(LocalExecutor(timeout=0.5), *fake)
    assert not outcome.ok and outcome.error.startswith("timed out after 0.5s: ")
    assert time.perf_counter() - start < 20  # killed, not waited for (the worker runs 30 s)


@pytest.fixture
def sigint_not_ignored():
    """A process started in the background (``nohup ... &``, as CI may run) ignores SIGINT, its children
    inherit that, and bash cannot trap a signal ignored at its start: let the fake worker see SIGINT."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_sends_sigint_so_a_worker_can_save_its_checkpoint(fake, monkeypatch, sigint_not_ignored):
    task, workspace = fake
    monkeypatch.setenv("FAKE_WORKER", "trap")
    executor = LocalExecutor(threads=2)
    future = executor.submit(task, workspace)
    log = workspace.log_path(task)
    deadline = time.monotonic() + 30
    while "started" not in (log.read_text() if log.is_file() else "") and time.monotonic() < deadline:
        time.sleep(0.05)
    executor.interrupt()
    outcome = future.result(timeout=30)
    executor.close()
    assert not outcome.ok and outcome.error == "exit status 130: threads 2 2 | started | got SIGINT"


def test_jobs_must_be_positive():
    with pytest.raises(ValueError, match="LocalExecutor: jobs must be >= 1, got 0"):
        LocalExecutor(jobs=0)


PARENT = """
import sys, time
from pathlib import Path
from types import SimpleNamespace

import bench.executors as ex

tmp = Path(sys.argv[1])
ex.sys = SimpleNamespace(executable=str(tmp / "worker.sh"))
ex.write_job = lambda ws, task, threads: tmp / "job.json"
workspace = SimpleNamespace(log_path=lambda t: tmp / "logs" / "k.log")
ex.LocalExecutor().submit(SimpleNamespace(key="k", slug="expert-k"), workspace)
time.sleep(300)
"""


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its new parent to reap it has ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_workers_exit_when_the_bench_is_killed(tmp_path):
    """``kill -9`` of the process that runs the executor: its worker gets SIGTERM (PR_SET_PDEATHSIG) and is
    gone within 2 s instead of running on."""
    pid_file = tmp_path / "worker.pid"
    script = tmp_path / "worker.sh"
    script.write_text(
        f'#!/bin/bash\necho $$ > "{pid_file}.tmp"; mv "{pid_file}.tmp" "{pid_file}"; exec sleep 300\n'
    )
    script.chmod(0o755)
    parent = subprocess.Popen([sys.executable, "-c", PARENT, str(tmp_path)], cwd=REPO)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not pid_file.is_file():
            assert parent.poll() is None and time.monotonic() < deadline, "the worker did not start"
            time.sleep(0.05)
        worker = int(pid_file.read_text())
        assert _alive(worker)
        parent.kill()
        parent.wait(timeout=30)
        deadline = time.monotonic() + 2
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(worker), "the worker outlived the killed bench by more than 2 s"
    finally:
        parent.kill()
        parent.wait(timeout=30)
        if worker is not None and _alive(worker):
            os.kill(worker, signal.SIGKILL)
