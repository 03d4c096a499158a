"""``bench.runlog``: every ``bench.all`` run is recorded in its workspace, and a report (its own and any
rendered later from the cached cells with ``--no-run``) lists the runs of its plan, so a cold run's wall
clock stays with the outputs built from its cells."""

from __future__ import annotations

import html
import json

import pytest

import bench.runner
from bench.all import main
from bench.runlog import (
    SHOWN,
    cache_state,
    describe,
    read_runs,
    recent,
    record_run,
    runs_of,
    runs_path,
    took,
)
from bench.runner import RunSummary

COUNTS = {
    "builds_run": 3,
    "builds_reused": 0,
    "evals_run": 2,
    "evals_reused": 0,
    "failures": [],
    "seconds": 12.34,
}
WARM = {"builds_run": 0, "evals_run": 0, "builds_reused": 3, "evals_reused": 2}


def _record(root, digest="d1", **counts):
    identity = {"specs": ["tab17"], "keys_digest": digest, "tasks": 5}
    return record_run(root, "tiny", identity, {**COUNTS, **counts}, "local", 2, 75.0)


def test_runs_are_appended_and_filtered_by_plan(tmp_path):
    assert read_runs(tmp_path) == []
    first = _record(tmp_path)
    _record(tmp_path, digest="other")
    warm = _record(tmp_path, **WARM, seconds=1.0)
    assert [r["keys_digest"] for r in read_runs(tmp_path)] == ["d1", "other", "d1"]
    assert runs_of(tmp_path, "d1") == [first, warm]
    assert first["seconds"] == 75.0 and first["cells_seconds"] == 12.3 and first["jobs"] == 2
    assert first["machine"] and first["specs"] == ["tab17"] and set(first["git"]) == {"commit", "dirty"}


def test_cache_state_and_description(tmp_path):
    cold = _record(tmp_path)
    warm = _record(tmp_path, **WARM)
    resumed = _record(tmp_path, builds_run=2, builds_reused=1, failures=["x"])
    failed_again = _record(
        tmp_path, builds_run=1, evals_run=0, builds_reused=2, failures=["x"]
    )  # computed nothing new
    states = [cache_state(e) for e in (cold, warm, resumed, failed_again)]
    assert states == ["cold", "warm", "resumed", "warm"]
    line = describe(cold)
    assert ": 3 builds + 2 evaluations run, 0 reused, 1.2 min cold (2 jobs, " in line
    assert "1 failed" in describe(resumed) and "failed" not in line
    clean, dirty = (
        {**cold, "machine": "cpu", "git": {"commit": "0123456789", "dirty": d}} for d in (False, True)
    )
    assert describe(clean).endswith("1.2 min cold (2 jobs, cpu), git 0123456")
    assert describe(dirty).endswith(
        "1.2 min cold (2 jobs, cpu), git 0123456 with uncommitted changes to moegs"
    )
    assert took({**clean, "seconds": 45.4}) == "45 s cold (2 jobs, cpu)"  # under a minute: seconds
    assert took({**clean, "jobs": None, "executor": "slurm"}) == "1.2 min cold (slurm, cpu)"


def test_warm_reruns_do_not_hide_the_run_that_computed_the_cells(tmp_path):
    cold = _record(tmp_path)
    warms = [_record(tmp_path, **WARM, seconds=float(i)) for i in range(SHOWN + 2)]  # distinct entries
    shown = recent(read_runs(tmp_path))
    assert len(shown) == SHOWN and shown[0] == cold and shown[1:] == warms[-(SHOWN - 1) :]
    assert recent(read_runs(tmp_path)[:3]) == [cold, *warms[:2]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", r"runs\.json: not a run record"),
        ('{"runs": {}}', r"runs\.json: 'runs' must be a list"),
        ('{"runs": [{"finished": "x"}]}', r"runs\.json: runs\[0\] lacks \['preset', "),
    ],
)
def test_a_damaged_record_names_its_file_and_entry(tmp_path, content, message):
    runs_path(tmp_path).write_text(content, encoding="utf-8")
    with pytest.raises(ValueError, match=message):
        read_runs(tmp_path)


@pytest.mark.parametrize(
    ("change", "wrong"),
    [
        ({"git": "680b0dc"}, "git"),
        ({"seconds": "75"}, "seconds"),
        ({"jobs": 1.5}, "jobs"),
        ({"failures": True}, "failures"),
    ],
)
def test_an_entry_of_another_format_is_refused(tmp_path, change, wrong):
    entry = _record(tmp_path)
    runs_path(tmp_path).write_text(json.dumps({"runs": [entry, {**entry, **change}]}))
    with pytest.raises(ValueError, match=rf"runs\[1\] has fields of the wrong type: \['{wrong}'\]"):
        read_runs(tmp_path)


def test_a_record_that_is_not_text_names_its_file(tmp_path):
    runs_path(tmp_path).write_bytes(b"\xff\xfe{")
    with pytest.raises(ValueError, match=r"runs\.json: not a run record"):
        read_runs(tmp_path)


def _tab17(tmp_path, *extra):
    ws, out = tmp_path / "ws", tmp_path / "out"
    return [
        "--tables",
        "17",
        "--preset",
        "tiny",
        "--workspace",
        str(ws),
        "--out",
        str(out),
        "--no-progress",
        *extra,
    ]


def test_a_damaged_record_stops_bench_all_before_any_cell(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(bench.runner, "execute", lambda *a, **k: pytest.fail("ran cells"))
    (tmp_path / "ws").mkdir()
    runs_path(tmp_path / "ws").write_text("{not json")
    assert main(_tab17(tmp_path)) == 2
    assert f"error: {runs_path(tmp_path / 'ws')}: not a run record" in capsys.readouterr().err


def test_reports_list_the_runs_of_their_plan(tmp_path, monkeypatch):
    """``bench.all`` records its run before writing its outputs; its report and every later ``--no-run``
    render list it."""
    kinds = {"eval expert": 6.0, "build expert": 120.0, "build moe": 30.0}
    monkeypatch.setattr(
        bench.runner,
        "execute",
        lambda *a, **k: RunSummary(builds_run=4, evals_run=3, seconds=30, kind_seconds=dict(kinds)),
    )
    report = tmp_path / "out" / "reports" / "subsets" / "tiny-tab17" / "reports"
    assert main(_tab17(tmp_path)) == 0
    [entry] = read_runs(tmp_path / "ws")
    assert (entry["builds_run"], entry["evals_run"], entry["cells_seconds"]) == (4, 3, 30.0)
    # where the time went, by cell kind, largest first, in the record and in this run's report
    assert list(entry["minutes_by_kind"].items()) == [
        ("build expert", 2.0),
        ("build moe", 0.5),
        ("eval expert", 0.1),
    ]
    assert (
        "cell time by kind: build expert 2.0 min, build moe 0.5 min, eval expert 0.1 min"
        in (report / "REPORT.md").read_text()
    )
    assert json.loads((report / "summary.json").read_text())["header"]["history"] == [entry]

    assert main(_tab17(tmp_path, "--no-run")) == 0
    assert len(read_runs(tmp_path / "ws")) == 1, "a --no-run render is not a run"
    header = json.loads((report / "summary.json").read_text())["header"]
    assert header["history"] == [entry] and header["cells"]["keys_digest"] == entry["keys_digest"]
    assert f"  - {describe(entry)}" in (report / "REPORT.md").read_text()
    assert f"<li>{html.escape(describe(entry), quote=False)}</li>" in (report / "REPORT.html").read_text()

    for _ in range(SHOWN):
        assert main(_tab17(tmp_path)) == 0
    for page in ("REPORT.md", "REPORT.html"):
        text = (report / page).read_text()
        assert (
            "(1 more not shown)" in text and text.count(": 4 builds + 3 evaluations run, 0 reused,") == SHOWN
        )
