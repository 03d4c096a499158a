"""``bench.gpu_train`` on the CPU: the report's sections, the parity verdict, runs cut short, staged data."""

from __future__ import annotations

import json
import math

import pytest

from bench import gpu_train
from bench.gpu_train import TOLERANCE, parity_summary

QUICK = ["--device", "cpu", "--quick"]


def test_quick_cpu_run_writes_parity_sync_and_speed(tmp_path):
    out = tmp_path / "t.json"
    assert gpu_train.main([*QUICK, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["status"] == "complete" and data["device"] == "cpu"
    assert list(data["parity"]) == ["static", "router", "distill"]
    assert data["sync"] is None  # host syncs are a CUDA matter
    for name, entry in data["parity"].items():
        # the CPU against itself: the same numbers step by step, so the comparison itself is right
        assert entry["loss"]["device"] == entry["loss"]["cpu"], name
        assert entry["gaussians"]["device"] == entry["gaussians"]["cpu"], name
        assert len(entry["loss"]["cpu"]) == entry["steps"] == 2
        assert entry["summary"]["pass"] and entry["summary"]["max_rel"] == 0.0
    assert list(data["speed"]) == ["router", "static"]  # SPEED's order
    for entry in data["speed"].values():
        assert entry["steps_run"] == 2 and entry["median_ms"] > 0 and entry["p90_ms"] >= entry["median_ms"]
        assert entry["peak_memory_bytes"] is None and entry["reported"] is None
    assert data["parts"]["parity"]["status"] == data["parts"]["speed"]["status"] == "done"


def test_a_run_cut_short_keeps_the_finished_parts(tmp_path, monkeypatch):
    def killed(*args, **kwargs):
        raise KeyboardInterrupt  # as a time limit would stop it, during the speed part

    monkeypatch.setattr(gpu_train, "speed_entry", killed)
    out = tmp_path / "t.json"
    with pytest.raises(KeyboardInterrupt):
        gpu_train.main([*QUICK, "--experts", "static", "--parity-steps", "1", "--json", str(out)])
    data = json.loads(out.read_text())
    assert data["status"] == "running"
    assert data["parts"]["parity"]["status"] == "done" and data["parity"]["static"]["summary"]["pass"]
    assert data["parts"]["speed"]["status"] == "running" and data["speed"] == {}


def test_a_spent_budget_skips_the_speed_runs_and_says_so(tmp_path):
    out = tmp_path / "t.json"
    args = [*QUICK, "--experts", "static,router", "--parts", "speed", "--budget-s", "0", "--json", str(out)]
    assert gpu_train.main(args) == 0
    data = json.loads(out.read_text())
    assert "parity" not in data
    assert data["speed"] == {"router": {"skipped": "budget spent"}, "static": {"skipped": "budget spent"}}
    assert data["parts"]["speed"]["timed"] == 0


LOSS = [0.50, 0.46, 0.41, 0.37, 0.30, 0.33, 0.25, 0.22]
COUNTS = [1000, 1000, 1000, 1200, 1200, 1400, 1400, 1400]


def test_identical_trajectories_pass():
    summary = parity_summary(LOSS, LOSS, COUNTS, COUNTS)
    assert summary["pass"] and summary["failed"] == []
    assert summary["first_step_rel"] == summary["max_rel"] == summary["mean_rel"] == 0.0


@pytest.mark.parametrize(
    ("loss", "counts", "failed"),
    [
        ([LOSS[0] * 1.01, *LOSS[1:]], COUNTS, ["first_step"]),  # 1% off at the first step alone
        ([v * 1.03 for v in LOSS], COUNTS, ["first_step", "mean"]),  # a lasting 3% gap
        ([LOSS[0], *(v * 0.98 for v in LOSS[1:])], COUNTS, ["mean"]),  # the same first step, then 2% off
        (LOSS, [*COUNTS[:-1], 1450], ["final_count"]),  # 3.6% more Gaussians at the end
        ([*LOSS[:-1], math.nan], COUNTS, ["mean"]),  # a NaN fails, it never passes
    ],
)
def test_the_verdict_fails_trajectories_that_differ(loss, counts, failed):
    summary = parity_summary(loss, LOSS, counts, COUNTS)
    assert not summary["pass"] and summary["failed"] == failed


def test_the_verdict_allows_what_the_tolerance_states():
    within = [LOSS[0] * (1 + 0.9 * TOLERANCE.first_step), *(v * (1 - 0.9 * TOLERANCE.mean) for v in LOSS[1:])]
    counts = [*COUNTS[:-1], int(COUNTS[-1] * (1 + 0.9 * TOLERANCE.final_count))]
    assert parity_summary(within, LOSS, counts, COUNTS)["pass"]
    with pytest.raises(ValueError, match="same, non-zero length"):
        parity_summary(LOSS[:-1], LOSS, COUNTS, COUNTS)


def test_speed_runs_start_where_the_expert_deforms():
    from types import SimpleNamespace

    assert gpu_train.first_step(SimpleNamespace(warm_up=3000)) == 3001
    assert gpu_train.first_step(SimpleNamespace(coarse_iterations=3000, deform_from=None)) == 3001
    assert gpu_train.first_step(SimpleNamespace(sh_degree=3)) == 1


def test_reported_speeds_are_derived_from_hours_and_iterations():
    assert gpu_train.reported("fourdgs", "dnerf")["ms"] == pytest.approx(20.9, abs=0.05)  # 8 min / 23k
    assert gpu_train.reported("ed3dgs", "n3v")["ms"] == pytest.approx(189.0)  # 4.2 h / 80k
    assert gpu_train.reported("stg", "n3v")["ms"] == pytest.approx(158.4)  # 2.2 h / 50k
    assert gpu_train.reported("fourdgs", "n3v") is None and gpu_train.reported("deformable", "dnerf") is None
    assert gpu_train.percentile([5.0, 1.0, 3.0, 2.0, 4.0], 90) == 5.0


def test_runs_are_checked_before_any_work(capsys):
    with pytest.raises(SystemExit):
        gpu_train.main([*QUICK, "--experts", "static,nope"])
    assert "nope" in capsys.readouterr().err
    every = gpu_train.parity_names(None)
    assert every[-3:] == ["mode", "router", "distill"] and len(every) == 11


def test_staged_mutant_loads_with_every_third_view(tmp_path, mutant_root):
    from moegs.data import load_scene

    size = gpu_train.stage_dnerf(mutant_root, tmp_path / "mutant", every=30, test_every=10)
    scene = load_scene("dnerf:mutant", path=tmp_path / "mutant", resolution_scale=0.125)
    assert size > 0 and len(scene.train) == 5 and len(scene.test) == 2
    assert scene.train[1].camera.width == 100


def test_sync_warnings_are_counted_at_the_library_line_that_caused_them():
    import warnings

    from moegs.data.scene import ImageCache

    def load():
        warnings.warn(gpu_train.SYNC_MESSAGE, stacklevel=1)  # as torch warns from inside a call
        warnings.warn("something else", stacklevel=1)
        return []

    with pytest.warns(UserWarning, match="something else"), gpu_train.sync_warnings() as found:
        for _ in range(3):  # every one counts, none is deduplicated
            ImageCache(max_items=0, nbytes=len).get("key", load)
    assert len(found) == 3 and len(set(found)) == 1
    assert found[0].startswith("moegs/data/scene.py:") and "test_gpu_train.py" in found[0]
