"""Safe defaults of ``python -m bench.all``: ``quick`` without a preset; ``--tiny``, ``--quick``,
``--standard`` and ``--paper`` as shorthands of ``--preset`` (two different presets: one error line);
before any work the plan (tasks to compute, tasks cached) and an estimate from the task times the
workspace recorded (the same task under older code, else similar tasks scaled, else 'unknown');
``--preset paper`` on the CPU only with ``--yes``."""

from __future__ import annotations

import json

import pytest

import bench.all
import bench.forecast
import bench.runner
from bench.all import build_parser, choose_preset, main
from bench.forecast import Forecast, forecast, plan_lines, records
from bench.plan import make_plan
from bench.presets import get_preset
from bench.store import Workspace


@pytest.fixture
def no_preset_env(monkeypatch):
    monkeypatch.delenv("MOEGS_PRESET", raising=False)


def _dirs(tmp_path) -> list[str]:
    return ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]


# ------------------------------------------------------------------------------------------- presets
@pytest.mark.parametrize(
    ("argv", "env", "expected"),
    [
        ([], None, "quick"),
        ([], "", "quick"),
        ([], "standard", "standard"),
        (["--tiny"], "paper", "tiny"),
        (["--quick"], None, "quick"),
        (["--standard"], None, "standard"),
        (["--paper"], None, "paper"),
        (["--preset", "quick32"], "paper", "quick32"),
        (["--quick", "--preset", "quick"], None, "quick"),  # the same preset twice is no conflict
        (["--tiny", "--tiny"], None, "tiny"),
    ],
)
def test_the_preset_of_a_command_line(argv, env, expected, monkeypatch):
    if env is None:
        monkeypatch.delenv("MOEGS_PRESET", raising=False)
    else:
        monkeypatch.setenv("MOEGS_PRESET", env)
    assert choose_preset(build_parser().parse_args(argv)) == expected


@pytest.mark.parametrize(
    ("argv", "env", "message"),
    [
        (["--quick", "--paper"], None, "error: --quick and --paper name different presets; give one"),
        (["--preset", "paper", "--tiny"], None, "error: --tiny and --preset paper name different presets"),
        (["--tiny", "--standard", "--tiny"], None, "error: --tiny and --standard name different presets"),
        (
            [],
            "huge",
            "error: $MOEGS_PRESET=huge: unknown bench preset; valid: tiny, quick, quick32, standard",
        ),
    ],
)
def test_conflicting_presets_are_one_line_before_any_work(argv, env, message, monkeypatch, tmp_path, capsys):
    if env is None:
        monkeypatch.delenv("MOEGS_PRESET", raising=False)
    else:
        monkeypatch.setenv("MOEGS_PRESET", env)
    assert main(["--tables", "17", *_dirs(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and len(err.splitlines()) == 1
    assert not (tmp_path / "ws").exists() and not (tmp_path / "out").exists()


def test_without_a_preset_the_bench_runs_quick(no_preset_env, tmp_path, capsys, gpus):
    gpus(0)
    assert main(["--tables", "17", "--dry-run", *_dirs(tmp_path)]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("dry run: preset quick, device cpu;")
    assert f"[bench] preset quick, device cpu; 1 spec(s): tab17; workspace {tmp_path / 'ws'}" in err


# ------------------------------------------------------------------------------ plan and estimate
def test_a_dry_run_prints_the_plan_and_an_unknown_estimate_in_a_new_workspace(tmp_path, capsys, gpus):
    gpus(0)
    assert main(["--tiny", "--tables", "17", "--dry-run", *_dirs(tmp_path)]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("[bench] no real")]
    ws = tmp_path / "ws"
    assert err == [
        f"[bench] preset tiny, device cpu; 1 spec(s): tab17; workspace {ws}",
        "[bench] plan: 4 builds to compute, 0 cached; 3 evaluations to compute, 0 cached",
        f"[bench] estimate: unknown: no recorded time of these or similar tasks (preset tiny, cpu) in {ws}; "
        "a finished run records them",
    ]
    assert not ws.exists()  # planning reads the workspace, never writes it


def _record_build(root, folder: str, task: dict, seconds: float) -> None:
    path = root / "store" / task["kind"] / folder / "artifact.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"task": task, "build_seconds": seconds, "key": folder}))


def _record_eval(root, name: str, task: dict, seconds: float, status: str = "ok") -> None:
    path = root / "results" / task["preset"] / task["kind"] / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    timings = {"total_s": seconds} if status == "ok" else {}
    path.write_text(json.dumps({"task": task, "status": status, "timings": timings}))


def test_the_estimate_uses_each_tasks_own_earlier_time(tmp_path):
    """Records of the same tasks under other keys (older code; no DONE, so not cached) time them."""
    plan = make_plan(["tab17"], get_preset("tiny"))
    ws = Workspace(tmp_path / "ws")
    builds = [t for level in plan.build_levels() for t in level]
    for i, task in enumerate(builds):
        _record_build(ws.root, f"old{i}", task.to_dict(), 10.0 * (i + 1))
    first, second, third = plan.eval_tasks()
    _record_eval(ws.root, "old-a", first.to_dict(), 3.0)
    _record_eval(ws.root, "old-b", first.to_dict(), 5.0)  # two records of one task: their mean
    _record_eval(ws.root, "old-c", second.to_dict(), 99.0, status="failed")  # a failed cell has no time
    cuda = {**third.to_dict(), "device": "cuda"}
    _record_eval(ws.root, "old-d", cuda, 1.0)  # another device never times a task
    assert len(records(ws.root, "tiny", "cpu")) == 6
    fc = forecast(plan, ws)
    assert (len(fc.builds_todo), fc.builds_cached, len(fc.evals_todo), fc.evals_cached) == (4, 0, 3, 0)
    assert (fc.own, fc.similar, fc.unknown, fc.records) == (5, 0, 2, 6)
    assert fc.seconds == pytest.approx(10 + 20 + 30 + 40 + 4)
    lines = plan_lines(fc, 2, ws.root, "tiny", "cpu")
    assert lines[1] == "estimate: at least 1.7 min of task time, so at least 52 s on 2 workers"
    assert lines[2].startswith(f"  from 6 task times recorded in {ws.root} (preset tiny, cpu): 5 tasks timed")


def test_similar_tasks_are_scaled_by_their_training_work(tmp_path, monkeypatch):
    """A build of the same kind and expert with another seed, twice the training work: half its time."""
    monkeypatch.setattr(bench.forecast, "_steps", lambda task, preset: float(task.seed + 1))
    plan = make_plan(["tab17"], get_preset("tiny"))
    ws = Workspace(tmp_path / "ws")
    expert = next(t for level in plan.build_levels() for t in level if t.kind == "expert")
    _record_build(ws.root, "other-seed", {**expert.to_dict(), "seed": 1}, 40.0)
    fc = forecast(plan, ws)
    assert (fc.own, fc.similar, fc.unknown) == (0, 1, 6) and fc.seconds == pytest.approx(20.0)


def test_a_cached_plan_has_nothing_to_estimate(tmp_path, monkeypatch):
    plan = make_plan(["tab17"], get_preset("tiny"))
    ws = Workspace(tmp_path / "ws")
    monkeypatch.setattr(Workspace, "is_built", lambda self, task: True)
    monkeypatch.setattr(bench.forecast, "load_valid", lambda path, task: {"status": "ok"})
    fc = forecast(plan, ws)
    assert plan_lines(fc, 2, ws.root, "tiny", "cpu") == [
        "plan: 0 builds to compute, 4 cached; 0 evaluations to compute, 3 cached",
        "estimate: nothing to compute, every task is cached",
    ]


def test_the_estimate_lines_say_what_they_are_based_on(tmp_path):
    fc = Forecast([object()] * 3, 1, [object()] * 2, 0, 5400.0, own=1, similar=3, unknown=0, records=12)
    assert plan_lines(fc, None, tmp_path, "quick", "cuda") == [
        "plan: 3 builds to compute, 1 cached; 2 evaluations to compute, 0 cached",
        "estimate: about 1.5 h of task time",
        f"  from 12 task times recorded in {tmp_path} (preset quick, cuda): 1 task timed by their own "
        "earlier run (older code), 3 tasks by similar ones (same kind and experts, training scaled by its "
        "steps); process starts and dependency waits not counted",
    ]


# --------------------------------------------------------------------------------- paper on the CPU
class Started(Exception):
    """Raised where the run would start computing."""


def _start(*args, **kwargs):
    raise Started


def test_the_paper_preset_on_the_cpu_prints_its_plan_and_stops_without_yes(
    tmp_path, monkeypatch, capsys, gpus
):
    gpus(0)
    monkeypatch.setattr(bench.all, "execute_interruptibly", _start)
    assert main(["--paper", "--tables", "17", *_dirs(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert any(line.startswith("[bench] plan: ") for line in err)
    assert any(line.startswith("[bench] estimate: ") for line in err)
    assert err[-1].startswith("error: --preset paper on the CPU: about ")
    assert err[-1].endswith("; pass --yes to run it on the CPU anyway")
    assert not (tmp_path / "ws").exists() and not (tmp_path / "out").exists()


def test_the_paper_preset_on_the_cpu_runs_with_yes_after_printing_the_plan(
    tmp_path, monkeypatch, capsys, gpus
):
    gpus(0)
    monkeypatch.setattr(bench.all, "execute_interruptibly", _start)
    with pytest.raises(Started):
        main(["--paper", "--yes", "--tables", "17", "--jobs", "1", *_dirs(tmp_path)])
    err = capsys.readouterr().err
    assert "[bench] plan: " in err and "[bench] estimate: " in err and "error:" not in err
