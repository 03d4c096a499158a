"""One table end to end at the ``tiny`` preset: real cells computed (training + evaluation) in worker
processes, result JSONs, LaTeX (structure + pdflatex when installed), plots, report; a warm re-run
reuses everything; a failing cell is isolated; the submitit path runs through submitit's local executor.

Table XVII (D-NeRF, real ``mutant`` scene) is used as soon as one of its experts exists in the
library; until then the same pipeline runs a table of the experts that exist (3DGS, 3DGS-MCMC).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.all import write_outputs
from bench.codedeps import task_modules
from bench.executors import LocalExecutor, SubmititExecutor
from bench.latex import check_structure
from bench.plan import Slot, SpecPlan, make_plan
from bench.presets import get_preset
from bench.registry import get_spec
from bench.results import read_result
from bench.runner import execute
from bench.spec import Claim, Row, Spec
from bench.store import META, Workspace
from bench.tasks import Task

pytestmark = pytest.mark.slow
PRESET = get_preset("tiny")


def _spec() -> Spec:
    """Table XVII if any of its rows can be computed, else the same layout with the experts that exist."""
    tab17 = get_spec("tab17")
    plan = make_plan([tab17], PRESET)
    if any(s.task is not None for s in plan.specs[0].slots):
        return tab17
    return Spec(
        id="e2e",
        title="end-to-end check with the available experts",
        dataset="dnerf",
        axis="scenes",
        rows=(Row("3DGS", "expert", {"expert": "static"}), Row("3DGS-MCMC", "expert", {"expert": "mcmc"})),
        claims=(
            Claim(
                "any",
                "3DGS-MCMC vs 3DGS (informative only)",
                "better",
                {"a": "3DGS-MCMC", "b": "3DGS", "strict": False, "margin": 100.0},
            ),
        ),
    )


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from moegs.paths import data_root

    if data_root() is None or not (data_root() / "dnerf" / "mutant").is_dir():
        pytest.skip(f"real scene dnerf/mutant not found (MOEGS_DATA={data_root()})")
    root = tmp_path_factory.mktemp("bench")
    ws, out = Workspace(root / "ws"), root / "out"
    spec = _spec()
    plan = make_plan([spec], PRESET)
    start = time.perf_counter()
    summary = execute(plan, ws, LocalExecutor(jobs=2), progress=False)
    cold = time.perf_counter() - start
    outputs = write_outputs(plan, ws, [spec.id], out / "tables", out / "reports")
    return {
        "spec": spec,
        "plan": plan,
        "ws": ws,
        "out": out,
        "summary": summary,
        "cold": cold,
        "outputs": outputs,
    }


def _ok_slots(run) -> list[Slot]:
    return [s for s in run["plan"].specs[0].slots if s.task is not None]


def test_cells_computed_from_the_real_scene(run):
    summary = run["summary"]
    assert not summary.failures, [f"{o.task.slug}: {o.error} ({o.log})" for o in summary.failures]
    assert summary.builds_run >= 2 and summary.evals_run >= 1
    # where the time went: every cell that ran, by action and kind
    assert "build expert" in summary.kind_seconds and all(v > 0 for v in summary.kind_seconds.values())
    assert {k.split()[0] for k in summary.kind_seconds} == {"build", "eval"}
    slots = _ok_slots(run)
    assert slots and all(s.scene.name == "dnerf:mutant" and s.scene.real for s in slots)
    for slot in slots:
        res = read_result(run["ws"].result_path(slot.task))
        assert res["status"] == "ok"
        assert 5.0 < res["metrics"]["psnr"] < 60.0
        assert {"fps", "memory_mb", "train_time_h", "ssim"} <= set(res["metrics"])
        assert res["metric_profile"]["name"] == "moegs"
        assert res["versions"]["torch"].startswith("2.") and res["versions"]["moegs_code_version"]
        assert res["scene"]["real"] and len(res["scene"]["input_hash"]["sha256"]) == 64
        ckpts = [a for a in res["artifacts"].values() if a["kind"] == "expert"]
        assert ckpts and all(len(h) == 64 for a in ckpts for h in a["files"].values())
        assert Path(res["log"]).is_file()
        assert res["per_view"] and all({"time", "camera"} <= set(v) for v in res["per_view"])


def test_workers_ran_only_library_code_their_keys_hash(run):
    """Every library module a worker imported is in its task's static closure (``bench.codedeps``), so
    editing any other module leaves the task's key, and its cached cell, valid."""
    ws = run["ws"]
    records = [read_result(ws.result_path(slot.task)) for slot in _ok_slots(run)]
    records += [json.loads(p.read_text()) for p in sorted(ws.root.glob(f"store/*/*/{META}"))]
    assert len(records) >= 3 and any("build_seconds" in r for r in records)
    assert any("moegs.train.loop" in r["modules_loaded"] for r in records)  # the record is the real one
    for record in records:
        task = Task.from_dict(record["task"])
        outside = set(record["modules_loaded"]) - task_modules(*task.code_dependencies())
        assert not outside, f"{task.slug} imported {sorted(outside)}, which its code version does not hash"


def test_latex(run):
    spec, out = run["spec"], run["out"]
    path = out / "tables" / f"{spec.id}.tex"
    text = path.read_text()
    assert check_structure(text) == []
    assert r"\providecommand{\rankfirst}" in text and r"\toprule" in text and "Reduced scale" in text
    res = read_result(run["ws"].result_path(_ok_slots(run)[0].task))
    assert f"{res['metrics']['psnr']:.2f}" in text, "our number appears in the table"
    assert f"\\dynregion{{{res['metrics']['psnr_dynamic']:.2f}}}" in text, "with its dynamic-region PSNR"
    if spec.id == "tab17":
        assert r"\paperdelta{42.03}" in text or r"\paperdelta{43.95}" in text, "mutant: paper value and delta"
    if shutil.which("pdflatex"):
        for name in (path.name, "all.tex"):
            proc = subprocess.run(
                ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", name],
                cwd=path.parent,
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert proc.returncode == 0, proc.stdout[-2000:]


def test_plots_and_report(run):
    out, spec = run["out"], run["spec"]
    pngs = list((out / "reports" / "figures").glob(f"{spec.id}*.png"))
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    md = (out / "reports" / "REPORT.md").read_text()
    assert f"## {spec.id}" in md and "reduced scale" in md
    assert f"**LaTeX:** `../tables/{spec.id}.tex`" in md  # relative links: the report can move
    assert f"](figures/{spec.id}" in md
    html = (out / "reports" / "REPORT.html").read_text()
    assert f'<img src="figures/{spec.id}' in html and f"## {spec.id}" not in html  # rendered, linked
    summary = json.loads((out / "reports" / "summary.json").read_text())
    rep = next(s for s in summary["specs"] if s["id"] == spec.id)
    assert (
        rep["status"].startswith("reproduced at tiny preset") and "real data (dnerf:mutant)" in rep["status"]
    )
    assert rep["latex"] == f"../tables/{spec.id}.tex"  # no absolute paths of this machine
    # our numbers, machine-readable: every computed row on the real scene, beside the paper's value
    psnr = {v["row"]: v for v in rep["values"] if v["column"] == "Mutant" and v["metric"] == "PSNR"}
    assert set(psnr) == {row for row, status in rep["rows"].items() if status == "ok"} != set()
    assert all(5.0 < v["ours"] < 60.0 and v["paper"] > 30.0 for v in psnr.values())
    # motion evidence: every expert scored on the full image and on D-NeRF's object / background regions
    assert summary["experts"], "one row per expert and scene"
    for row in summary["experts"]:
        assert row["scene"] == "dnerf:mutant" and row["expert"] in ("deformable", "grid4d", "static", "mcmc")
        for metric in ("psnr", "ssim", "lpips"):
            assert set(row[metric]) == {"full", "dynamic", "static"}
        assert all(5.0 < row["psnr"][r] < 60.0 for r in ("full", "dynamic", "static"))
        assert row["motion_r2"] is None  # D-NeRF's test views never repeat a camera: no temporal R²
        assert row["psnr_regimes"] == {}  # motion regimes are a stand-in's ground truth
    if spec.id == "tab17":  # MoE-GS N=2: the routing signal of its gate maps
        (routing,) = summary["routing"]
        assert routing["table"] == "tab17" and routing["experts"] == ["deformable", "grid4d"]
        assert 0.0 <= routing["coherence"] <= 1.0
        assert len(routing["dynamic_share"]) == len(routing["static_share"]) == 2
    assert "noise" in summary and "## Motion, routing and noise" in md
    # what the cells cost: every build once (the experts, and the router of MoE-GS), every evaluation
    compute = summary["compute"]
    made = {(r["kind"], r["what"]) for r in compute["builds"]}
    experts = {row["expert"] for row in summary["experts"]}
    assert {("expert", e) for e in experts} <= made
    if spec.id == "tab17":
        assert ("moe", "vapr router: deformable+grid4d") in made
    assert sum(r["count"] for r in compute["evaluations"]) == len({s.task.key for s in _ok_slots(run)})
    parts = [r["minutes"] for r in compute["builds"] + compute["evaluations"]]
    assert all(m > 0 for m in parts) and compute["minutes"] == pytest.approx(sum(parts))
    assert "## What the cells cost" in md
    # the plan's identity: what tests/bench/test_committed_outputs.py checks the committed outputs with
    cells = summary["header"]["cells"]
    assert cells == run["plan"].identity() == make_plan([spec], PRESET).identity()
    assert cells["specs"] == [spec.id] and cells["scenes"] == ["dnerf:mutant"]
    assert f"keys digest `{cells['keys_digest']}`" in md


def test_warm_rerun_reuses_everything(run):
    again = execute(run["plan"], run["ws"], LocalExecutor(jobs=2), progress=False)
    assert again.builds_run == 0 and again.evals_run == 0 and again.evals_reused >= 1


def test_failing_cell_is_isolated(run):
    good = _ok_slots(run)[0]
    bad_task = Task(
        "eval",
        good.task.kind,
        dict(good.task.params),
        good.task.scene,
        {**good.task.scene_kwargs, "no_such_loader_argument": 1},
        PRESET.name,
        0,
    )
    sp = SpecPlan(
        run["spec"], [good.scene], [0], [good, Slot(good.row, good.scene, 0, None, bad_task, "planned")]
    )
    summary = execute(type(run["plan"])(PRESET, [sp]), run["ws"], LocalExecutor(jobs=2), progress=False)
    assert summary.evals_reused == 1, "the good cell is untouched"
    assert len(summary.failures) == 1 and summary.failures[0].log.is_file()
    res = read_result(run["ws"].result_path(bad_task))
    assert res["status"] == "failed" and "dependency" in res["error"]


@pytest.mark.parametrize("pack", [1, 2])
def test_submitit_local_executor(run, tmp_path, pack):
    """The Slurm path through submitit's local executor: re-evaluate cells in a copied workspace (with
    ``pack=2``, two cells in one job); each result records the device it ran on."""
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(run["ws"].root / "store", ws.root / "store")
    slots = _ok_slots(run)[:pack]
    sp = SpecPlan(run["spec"], [], [0], slots)
    summary = execute(
        type(run["plan"])(PRESET, [sp]),
        ws,
        SubmititExecutor(cluster="local", poll_seconds=0.5, pack=pack),
        progress=False,
    )
    assert not summary.failures, [o.error for o in summary.failures]
    assert summary.evals_run == pack and summary.builds_run == 0
    assert len([p for p in (ws.root / "submitit").iterdir() if p.name.isdigit()]) == 1  # one job
    for slot in slots:
        result = read_result(ws.result_path(slot.task))
        assert result["status"] == "ok" and result["device"] == {"kind": "cpu", "name": "cpu", "gpu": None}


def test_cli_one_table(run):
    """``python -m bench.all --tables 17 --no-run`` rebuilds the table from the existing results."""
    out = run["out"] / "cli"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench.all",
            "--tables",
            "17",
            "--preset",
            "tiny",
            "--no-run",
            "--workspace",
            str(run["ws"].root),
            "--out",
            str(out),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    subset = out / "reports" / "subsets" / "tiny-tab17"  # a subset run leaves the full report alone
    assert (subset / "tables" / "tab17.tex").is_file() and (subset / "reports" / "REPORT.md").is_file()
    assert not (out / "reports" / "REPORT.md").exists() and not (out / "tables").exists()


def test_cli_reports_failed_cells(run, monkeypatch, capsys):
    """``bench.all`` exits 1 with the failures listed (and still writes its outputs) when cells failed."""
    import bench.runner
    from bench.all import main
    from bench.executors import Outcome
    from bench.runner import RunSummary

    failed = Outcome(_ok_slots(run)[0].task, False, run["ws"].root / "x.log", 1.0, "boom")
    monkeypatch.setattr(bench.runner, "execute", lambda *a, **k: RunSummary(failures=[failed]))
    out = run["out"] / "failed"
    args = ["--tables", "17", "--preset", "tiny", "--workspace", str(run["ws"].root), "--out", str(out)]
    assert main([*args, "--no-progress"]) == 1
    assert "1 task(s) failed" in capsys.readouterr().err
    assert (out / "reports" / "subsets" / "tiny-tab17" / "reports" / "REPORT.md").is_file()


QUALITY = ("psnr", "ssim", "lpips")


@pytest.mark.parametrize("how", ["ctrl-c", "kill-9"])
def test_interrupted_run_resumes_to_the_same_results(run, tmp_path, how):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) or kill -9 in the middle of training;
    the same command then finishes, and every cell equals the uninterrupted run's."""
    ws = tmp_path / "ws"
    cmd = [sys.executable, "-m", "bench.all", "--tables", "17", "--preset", "tiny", "--jobs", "2"]
    cmd += ["--workspace", str(ws), "--out", str(tmp_path / "out"), "--no-progress"]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        # a terminal's foreground job: SIGINT is not ignored, even if this test runs in a background job
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 600
    while not any((ws / "store").glob("expert/*.partial")):  # an expert is training
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no training started"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT if how == "ctrl-c" else signal.SIGKILL)
    _, err = proc.communicate(timeout=300)
    if how == "ctrl-c":
        assert proc.returncode == 130, err[-2000:]
        assert "[bench] interrupted: finished cells and training checkpoints are kept" in err
        assert "Traceback" not in err
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    assert again.returncode == 0, again.stderr[-2000:]
    for slot in _ok_slots(run):
        ours = read_result(Workspace(ws).result_path(slot.task))["metrics"]
        reference = read_result(run["ws"].result_path(slot.task))["metrics"]
        for name in reference:
            if name.split("_")[0].split("/")[0] in QUALITY:
                assert ours[name] == reference[name], (slot.task.slug, name)
