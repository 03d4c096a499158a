"""``python -m bench.regress``: two pytest-benchmark runs compared case by case on median time, peak
memory and recorded results; exit 1 on a regression, 2 on unusable input."""

from __future__ import annotations

import json
import os

import pytest

from bench.regress import compare, main, newest_runs, read_run, regressions

RENDER = "tests/benchmarks/test_bench_render.py::test_rasterize[20k-256px-fwd-cpu]"
TRAIN = "tests/benchmarks/test_bench_train.py::test_quick_training_steps[grid4d]"


def _run(path, median_render=0.010, peak=300.0, median_train=2.0, loss=0.05, extra_case=None):
    """A pytest-benchmark JSON with one render case (RSS recorded) and one training case (mean_loss)."""
    benchmarks = [
        {
            "fullname": RENDER,
            "stats": {"median": median_render},
            "extra_info": {"n": 20_000, "res": 256, "rss_before_mb": 200.0, "peak_rss_mb": 200.0 + peak},
        },
        {"fullname": TRAIN, "stats": {"median": median_train}, "extra_info": {"mean_loss": loss}},
    ]
    if extra_case:
        benchmarks.append({"fullname": extra_case, "stats": {"median": 1.0}, "extra_info": {}})
    path.write_text(json.dumps({"benchmarks": benchmarks}))
    return path


def test_identical_runs_pass(tmp_path, capsys):
    base, new = _run(tmp_path / "a.json"), _run(tmp_path / "b.json")
    assert main([str(base), str(new)]) == 0
    out = capsys.readouterr().out
    assert "| test_rasterize[20k-256px-fwd-cpu] | x1.00 | 300 -> 300 MB (x1.00) | – |" in out
    assert "| test_quick_training_steps[grid4d] | x1.00 | – | same |" in out


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"median_render": 0.013}, "test_rasterize[20k-256px-fwd-cpu]: median time x1.30 (limit x1.25)"),
        (
            {"peak": 360.0},
            "test_rasterize[20k-256px-fwd-cpu]: peak memory 300 -> 360 MB (x1.20, limit x1.10)",
        ),
        ({"loss": 0.051}, "test_quick_training_steps[grid4d]: results differ (mean_loss)"),
    ],
)
def test_each_kind_of_regression_fails_with_its_reason(tmp_path, capsys, change, reason):
    base, new = _run(tmp_path / "a.json"), _run(tmp_path / "b.json", **change)
    assert main([str(base), str(new)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("REGRESSION tests/benchmarks/") and f"::{reason}\n" in err


def test_thresholds_and_memory_slack(tmp_path):
    base = read_run(_run(tmp_path / "a.json", peak=10.0))
    new = read_run(_run(tmp_path / "b.json", median_render=0.012, peak=11.5))  # x1.15 but 1.5 MB
    changes = compare(base, new)
    assert regressions(changes, time=0.25, memory=0.10) == []
    assert len(regressions(changes, time=0.10, memory=0.10)) == 1  # the time only: 1.5 MB is RSS noise


def test_cases_of_one_run_only_are_listed_not_judged(tmp_path, capsys):
    base = _run(tmp_path / "a.json", extra_case="t.py::gone")
    new = _run(tmp_path / "b.json", extra_case="t.py::added")
    assert main([str(base), str(new)]) == 0
    out = capsys.readouterr().out
    assert "only in the base run: gone" in out and "only in the new run: added" in out


def test_memory_from_nothing_and_cases_without_extra_info(tmp_path):
    base = read_run(_run(tmp_path / "a.json", peak=0.0))
    new = read_run(_run(tmp_path / "b.json", peak=500.0))
    for run in (base, new):
        del run[TRAIN]["extra_info"]
    [render, train] = compare(base, new)
    assert render.memory_mb == (0.0, 500.0) and render.memory == 250.0  # 500 MB over the 2 MB slack
    assert train.memory is None and train.checked == ()
    assert regressions([render, train], time=0.25, memory=0.10) == [
        f"{RENDER}: peak memory 0 -> 500 MB (x250.00, limit x1.10)"
    ]


def test_the_newest_machine_folder_is_compared(tmp_path):
    """pytest-benchmark numbers each machine's runs on its own: a new folder starts again at 0001."""
    old, new = (tmp_path / name for name in ("Linux-CPython-3.11-64bit", "Linux-CPython-3.12-64bit"))
    for folder, count in ((old, 5), (new, 2)):
        folder.mkdir()
        for i in range(1, count + 1):
            _run(folder / f"{i:04d}_abc.json")
    assert newest_runs(tmp_path) == [new / "0001_abc.json", new / "0002_abc.json"]
    for stamp, folder in enumerate((new, old)):  # the newest file decides, whatever the folders' names
        for path in folder.iterdir():
            os.utime(path, (1_000_000 + stamp, 1_000_000 + stamp))
    assert newest_runs(tmp_path) == [old / "0004_abc.json", old / "0005_abc.json"]
    os.utime(new / "0001_abc.json", (2_000_000, 2_000_000))
    assert newest_runs(tmp_path) == [new / "0001_abc.json", new / "0002_abc.json"]
    (new / "0002_abc.json").unlink()
    with pytest.raises(ValueError, match=r"Linux-CPython-3\.12-64bit: 1 autosaved run\(s\), need 2"):
        newest_runs(tmp_path)


def test_default_is_the_two_newest_autosaved_runs(tmp_path, monkeypatch):
    machine = tmp_path / ".benchmarks" / "Linux-CPython-3.11-64bit"
    machine.mkdir(parents=True)
    for i, median in enumerate((0.010, 0.010, 0.020), start=1):
        _run(machine / f"{i:04d}_abc.json", median_render=median)
    assert newest_runs(tmp_path / ".benchmarks") == [machine / "0002_abc.json", machine / "0003_abc.json"]
    monkeypatch.chdir(tmp_path)
    assert main([]) == 1  # 0003 renders twice as slowly as 0002


def test_bad_input_names_the_file(tmp_path, capsys):
    (tmp_path / "bad.json").write_text('{"no": "benchmarks"}')
    assert main([str(tmp_path / "bad.json"), str(tmp_path / "bad.json")]) == 2
    assert f"{tmp_path / 'bad.json'}: not a pytest-benchmark JSON" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.json"), str(tmp_path / "bad.json")]) == 2
    assert "missing.json: no such benchmark JSON" in capsys.readouterr().err
    _run(tmp_path / "zero.json", median_render=0.0)
    assert main([str(tmp_path / "zero.json"), str(tmp_path / "zero.json")]) == 2
    assert f"zero.json: median time not a positive number for ['{RENDER}']" in capsys.readouterr().err
    _run(tmp_path / "inf.json", median_render=float("inf"))
    assert main([str(tmp_path / "inf.json"), str(tmp_path / "inf.json")]) == 2
    assert "inf.json: median time not a positive number" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"0 autosaved run\(s\), need 2"):
        newest_runs(tmp_path / "empty")
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path / "zero.json")])
    assert exit_.value.code == 2
    assert "give two runs (BASE.json NEW.json) or none, got 1" in capsys.readouterr().err
