"""``python -m bench.profile``: exclusive timers and the training-step breakdown on a generated scene."""

from __future__ import annotations

import json
import time

import pytest

from bench import profile


def test_nested_time_goes_to_the_inner_category_only(monkeypatch):
    clock = [100.0]  # a clock the test advances: exact seconds, no sleeping
    monkeypatch.setattr(time, "perf_counter", lambda: clock[0])  # the time module bench.profile reads
    timers = profile.ExclusiveTimers()
    with timers.timing("other"):
        clock[0] += 2.0
        with timers.timing("fields"):
            clock[0] += 5.0
            with timers.timing("raster fwd"):
                clock[0] += 1.0
        clock[0] += 3.0
    assert timers.seconds["fields"] == 5.0 and timers.seconds["raster fwd"] == 1.0
    assert timers.seconds["other"] == 5.0
    assert sum(timers.seconds.values()) == 11.0  # every second counted once


def test_breakdown_covers_the_step_and_restores_what_it_wrapped(tmp_path, capsys, monkeypatch):
    from moegs.data.scene import View
    from moegs.render import pipeline
    from moegs.train.loop import TrainingRun

    steps, iteration = [], TrainingRun.iteration
    monkeypatch.setattr(
        TrainingRun, "iteration", lambda run, step: steps.append(step) or iteration(run, step)
    )
    before = (View.image, pipeline.project, pipeline._composite)
    out = tmp_path / "profile.json"
    assert profile.main(["--expert", "static", "--scene", "synthetic:dnerf_like", "--steps", "4",
                         "--warmup", "2", "--json", str(out)]) == 0  # fmt: skip
    assert steps == [1, 2, 3, 4, 5, 6]  # the warm-up steps, then the timed ones: each step once, in order
    assert (View.image, pipeline.project, pipeline._composite) == before
    (result,) = json.loads(out.read_text())
    assert set(result["share"]) == set(profile.CATEGORIES) and result["steps"] == [3, 6]
    assert sum(result["share"].values()) == pytest.approx(1.0, abs=0.02)
    assert result["share"]["raster fwd"] > 0 and result["share"]["optimizer"] > 0
    assert result["flops_per_step"]["rasterizer"] > 0 and result["floor_ms"] > 0
    printed = capsys.readouterr().out
    assert "raster bwd" in printed and "the floor is" in printed


def test_bad_arguments_exit_2_naming_them(capsys):
    with pytest.raises(SystemExit) as err:
        profile.main(["--expert", "static", "--scene", "synthetic:dnerf_like", "--steps", "0"])
    assert (
        err.value.code == 2
        and "argument --steps: expected a positive integer, got '0'" in capsys.readouterr().err
    )
