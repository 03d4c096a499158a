"""``moegs.threads``: a process that starts torch's CPU workers first computes its first ``sqrt`` as it
computes every later one, and the commands that compute start them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

import moegs.cli

# a fresh process: OS threads before and after start_cpu_workers, then how many of 5000 values its first
# sqrt computes differently from its second
FRESH_PROCESS = """
import os, torch
from moegs.threads import start_cpu_workers
torch.set_num_threads(2)
before = len(os.listdir("/proc/self/task"))
start_cpu_workers()
after = len(os.listdir("/proc/self/task"))
x = torch.rand(5000, generator=torch.Generator().manual_seed(0)) + 0.01
first, again = torch.sqrt(x), torch.sqrt(x)
print(after - before, int((first != again).sum()))
"""
PROCESSES = 60


def fresh_process() -> tuple[int, int]:
    out = subprocess.run([sys.executable, "-c", FRESH_PROCESS], capture_output=True, text=True, check=True)
    started, differing = out.stdout.split()
    return int(started), int(differing)


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc (Linux)")
def test_start_cpu_workers_starts_the_second_thread():
    started, _ = fresh_process()
    assert started == 1


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc (Linux)")
def test_the_first_sqrt_of_a_process_is_its_usual_one_once_the_workers_started():
    """Without ``start_cpu_workers`` about one fresh process in twenty computes half of this first ``sqrt``
    differently (``moegs.threads``), so 60 processes would all agree by chance with probability about 5%."""
    differing = [fresh_process()[1] for _ in range(PROCESSES)]
    assert differing == [0] * PROCESSES


def test_commands_that_compute_start_the_workers_first(monkeypatch, tmp_path, capsys):
    calls = []
    monkeypatch.setattr(moegs.cli, "start_cpu_workers", lambda: calls.append(True))
    assert moegs.cli.main(["list"]) == 0
    assert calls == []
    assert moegs.cli.main(["eval", str(tmp_path / "missing")]) == 2  # fails after the workers started
    assert calls == [True]
    assert str(tmp_path / "missing") in capsys.readouterr().err


def test_a_bench_worker_starts_the_threads_after_setting_their_count(monkeypatch):
    import bench.worker

    calls = []
    monkeypatch.setattr(bench.worker, "start_cpu_workers", lambda: calls.append("start"))
    monkeypatch.setattr(torch, "set_num_threads", lambda n: calls.append(n))
    monkeypatch.delenv(bench.worker.THREADS_ENV, raising=False)
    bench.worker._start_threads(3)
    bench.worker._start_threads(None)  # no count given: torch's own, started all the same
    monkeypatch.setenv(bench.worker.THREADS_ENV, "2")
    bench.worker._start_threads(None)
    assert calls == [3, "start", "start", 2, "start"]
