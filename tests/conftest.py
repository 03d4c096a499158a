"""Shared test set-up: fixed seeds, CPU threads, and real-data lookup through ``MOEGS_DATA``."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
import torch

from moegs.paths import data_root
from moegs.threads import start_cpu_workers

torch.set_num_threads(2)
start_cpu_workers()  # the first parallel region is not a test's (moegs.threads)


@pytest.fixture(autouse=True)
def _fixed_seeds():
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)
    yield


def real_data(relative: str) -> Path:
    """Path of a staged real dataset under ``MOEGS_DATA``; skips the test with the reason when absent."""
    root = data_root()
    if root is None or not (root / relative).exists():
        pytest.skip(f"real data '{relative}' not found (MOEGS_DATA={root}); see README 'Data'")
    return root / relative


@pytest.fixture(scope="session")
def mutant_root() -> Path:
    return real_data("dnerf/mutant")


@pytest.fixture(scope="session")
def basketball_root() -> Path:
    return real_data("panoptic/basketball")


@pytest.fixture(scope="session")
def lpips_root() -> Path:
    return real_data("lpips_weights/lpips_tf/alex")


@pytest.fixture
def gpus(monkeypatch):
    """``gpus(n)``: torch sees ``n`` GPUs (0: a machine without CUDA); nothing else about CUDA is touched."""

    def see(n: int) -> None:
        monkeypatch.setattr(torch.cuda, "is_available", lambda: n > 0)
        monkeypatch.setattr(torch.cuda, "device_count", lambda: n)
        monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
        monkeypatch.setattr(torch.version, "cuda", "12.4" if n else None)

    return see
