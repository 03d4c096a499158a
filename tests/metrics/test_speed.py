"""The speed/memory protocol with dummy render functions."""

from __future__ import annotations

import json
import mmap
import time

import numpy as np
import pytest
import torch

from moegs.metrics import SpeedResult, measure_render


def test_times_only_the_render_with_warmup(monkeypatch):
    clock = [0]  # nanoseconds, advanced by the render itself: exact times, no sleeping
    monkeypatch.setattr(time, "perf_counter_ns", lambda: clock[0])  # the time module measure_render reads
    calls = []

    def render(view):
        calls.append(view)
        clock[0] += 250_000_000 if len(calls) == 1 else 2_000_000 * (1 + view)  # a slow first call
        return torch.zeros(4)

    res = measure_render(render, views=[0, 1, 2], warmup=2, repeats=3)
    assert isinstance(res, SpeedResult)
    assert len(calls) == 2 + 3 * 3
    assert res.samples_ms == [[2.0] * 3, [4.0] * 3, [6.0] * 3]  # the slow first call was a warm-up
    assert res.per_view_ms == [2.0, 4.0, 6.0]
    assert res.ms_per_view_median == pytest.approx(np.median(res.per_view_ms))
    assert res.fps_median == pytest.approx(1000 / res.ms_per_view_median)
    assert res.device.startswith("cpu (") and res.warmup == 2 and res.repeats == 3
    json.dumps(res.to_dict())


def test_a_slow_view_or_repeat_does_not_move_the_median(monkeypatch):
    """Medians over repeats, then over views: one stall (a page fault, another process) is not the speed."""
    clock = [0]
    monkeypatch.setattr(time, "perf_counter_ns", lambda: clock[0])
    ms = {0: [2.0, 2.0, 9.0], 1: [4.0, 4.0, 4.0], 2: [30.0, 30.0, 30.0]}  # per view, per repeat

    def render(view):
        clock[0] += int(ms[view].pop(0) * 1e6) if ms[view] else 0
        return torch.zeros(1)

    res = measure_render(render, views=[0, 1, 2], warmup=0, repeats=3, device="cpu")
    assert res.per_view_ms == [2.0, 4.0, 30.0]
    assert res.ms_per_view_median == 4.0 and res.fps_median == pytest.approx(250.0)


def test_device_inferred_from_nested_output():
    from dataclasses import dataclass

    @dataclass
    class Out:
        info: dict
        image: torch.Tensor

    res = measure_render(lambda v: Out({"n": 1}, torch.ones(2)), views=["a"], warmup=1, repeats=1)
    assert res.device.startswith("cpu")


def test_cpu_peak_rss_delta():
    def render(view):
        # Fresh anonymous pages, touched: malloc could instead hand back memory that is already
        # resident after a long test session, which (rightly) does not grow the resident set.
        size = 64 * 2**20
        with mmap.mmap(-1, size) as buf:
            buf[::4096] = b"\x01" * (size // 4096)
            return buf[0]

    res = measure_render(render, views=[0, 1], warmup=1, repeats=2, device="cpu")
    if res.memory_kind != "cpu_rss_peak_delta":
        pytest.skip("peak RSS cannot be reset here (/proc/self/clear_refs); only a lower bound is reported")
    assert 50 < res.peak_memory_mb < 400, res.peak_memory_mb


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_peak_allocated():
    def render(view):
        return torch.ones(16 * 2**20 // 4, device="cuda").sum()

    res = measure_render(render, views=[0], warmup=1, repeats=2)
    assert res.memory_kind == "cuda_max_allocated" and res.device.startswith("cuda")
    assert res.peak_memory_mb >= 16


def test_exceptions():
    with pytest.raises(ValueError, match=r"^measure_render: `views` is empty$"):
        measure_render(lambda v: None, [])
    with pytest.raises(ValueError, match=r"^measure_render: `device=None` infers the device"):
        measure_render(lambda v: None, [0], warmup=0)
    with pytest.raises(ValueError, match=r"^measure_render: need warmup >= 0 and repeats >= 1"):
        measure_render(lambda v: None, [0], repeats=0)
