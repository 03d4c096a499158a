"""``moegs train`` as a user runs it: seeded runs repeat, Ctrl-C and kill -9 resume to the same result, a
finished run is left alone and one of another config never reused (bad arguments: test_bad_inputs.py)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from moegs.cli import main
from moegs.experts import list_experts

SCENE = "synthetic:dnerf_like"
SMALL = ["--scene", SCENE, "--resolution-scale", "0.4", "--quiet"]


def train(out: Path, *extra: str, expert: str = "static") -> int:
    return main(["train", "--expert", expert, *SMALL, "--out", str(out), *extra])


def metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def same_result(a: Path, b: Path) -> None:
    ma, mb = metrics(a), metrics(b)
    assert ma["completed"] and mb["completed"]
    resumed = f"{b.name} resumed from step {mb.get('resumed_from')}"  # which checkpoint, if a resume differs
    assert ma["num_gaussians"] == mb["num_gaussians"] and ma["final_loss"] == mb["final_loss"], resumed
    assert ma["test"]["psnr"] == mb["test"]["psnr"]


@pytest.mark.slow
@pytest.mark.parametrize("expert", [s.name for s in list_experts() if not s.composite])
def test_seeded_runs_repeat(expert, tmp_path):
    """The seed reaches network initialisation: two runs with ``--seed 3`` are identical."""
    for name in ("a", "b"):
        assert train(tmp_path / name, "--iterations", "12", "--seed", "3", expert=expert) == 0
    same_result(tmp_path / "a", tmp_path / "b")


def test_finished_run_is_left_alone_unless_forced(tmp_path, capsys):
    out = tmp_path / "run"
    assert train(out, "--iterations", "6") == 0
    first = metrics(out)
    capsys.readouterr()
    assert train(out, "--iterations", "6") == 0
    assert "holds a finished run" in capsys.readouterr().out and metrics(out) == first
    assert train(out, "--iterations", "6", "--force") == 0
    assert "holds a finished run" not in capsys.readouterr().out
    again = metrics(out)  # trained again: the same result, another (measured) training time
    assert again["test"]["psnr"] == first["test"]["psnr"] and again["train_seconds"] != first["train_seconds"]


def test_a_scene_without_test_views_is_reported_as_not_evaluated(tmp_path, capsys, monkeypatch):
    """A run on a scene without test views says so instead of printing a NaN PSNR."""
    import moegs.data

    load = moegs.data.load_scene
    monkeypatch.setattr(moegs.data, "load_scene", lambda *a, **k: dataclasses.replace(load(*a, **k), test=[]))
    assert train(tmp_path / "run", "--iterations", "3") == 0
    printed = capsys.readouterr().out
    assert "not evaluated (the scene has no test views)" in printed and "nan" not in printed.lower()
    assert metrics(tmp_path / "run")["test"] is None


def test_a_finished_run_of_another_config_is_refused_by_train_and_marked_by_compare(tmp_path, capsys):
    """``train`` refuses to reuse a finished run whose config differs from the one it would train, naming the
    folder and the changed fields; ``compare`` reuses it (a user may train an expert on purpose with other
    settings) but marks its row and names the fields."""
    out = tmp_path / "run"
    assert train(out, "--iterations", "6") == 0
    first = metrics(out)
    capsys.readouterr()
    assert train(out, "--iterations", "7") == 2
    err = capsys.readouterr().err
    assert f"{out} holds a finished run of another static config (changed: train.iterations)" in err
    assert "--force trains it again" in err and metrics(out) == first
    # the same folder as compare's run of static at the quick preset (other iterations and resolution)
    shutil.copytree(out, tmp_path / "compare" / "static")
    argv = ["compare", "--experts", "static", "--scene", SCENE, "--out", str(tmp_path / "compare"), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    table = json.loads((tmp_path / "compare" / "table.json").read_text())
    assert table["skipped"] == ["static"] and table["rows"][0]["psnr"] == first["test"]["psnr"]
    changed = table["rows"][0]["config_changes"]
    assert changed == ["train.iterations", "train.resolution_scale"]
    assert "another config than the preset's, changed: train.iterations, train.resolution_scale" in printed
    markdown = (tmp_path / "compare" / "table.md").read_text()
    assert "| static* |" in markdown and "static*: a finished run of another config" in markdown


def _start(out: Path, iterations: int, every: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "moegs.cli", "train", "--expert", "static", *SMALL, "--out", str(out)]
    cmd += ["--iterations", str(iterations), "--checkpoint-every", str(every)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # the "recipe:" line arrives when it is printed
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, preexec_fn=default_sigint
    )


def default_sigint() -> None:
    """In the child: SIGINT as in a terminal's foreground job (a background test run inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for_checkpoint(proc: subprocess.Popen, out: Path) -> None:
    deadline = time.monotonic() + 300
    while not (out / "checkpoint.safetensors").is_file():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no checkpoint written"
        time.sleep(0.2)


@pytest.mark.slow
def test_ctrl_c_saves_and_kill_9_resumes_to_the_same_result(tmp_path):
    iterations = "800"
    reference = tmp_path / "reference"
    assert train(reference, "--iterations", iterations) == 0

    interrupted = tmp_path / "sigint"
    proc = _start(interrupted, int(iterations), every=10_000)
    for line in proc.stdout:  # the recipe line is printed just before training starts
        if line.startswith("recipe:"):
            break
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    assert "interrupted: SIGINT after step" in err and "Traceback" not in err
    assert (interrupted / "checkpoint.safetensors").is_file() and not (interrupted / "metrics.json").exists()
    assert train(interrupted, "--iterations", iterations) == 0  # the same command resumes
    same_result(reference, interrupted)

    killed = tmp_path / "kill9"
    proc = _start(killed, int(iterations), every=50)
    _wait_for_checkpoint(proc, killed)
    proc.kill()
    proc.communicate(timeout=60)
    assert not (killed / "metrics.json").exists()
    assert train(killed, "--iterations", iterations, "--checkpoint-every", "50") == 0
    same_result(reference, killed)


def test_route_needs_two_known_experts_before_training(tmp_path, capsys):
    assert main(["route", "--experts", "static", "--scene", SCENE, "--out", str(tmp_path)]) == 2
    assert "at least two different experts" in capsys.readouterr().err
    assert main(["route", "--experts", "static,nosuch", "--scene", SCENE, "--out", str(tmp_path)]) == 2
    assert "unknown expert 'nosuch'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing was trained


ROUTE_EXPERTS = ("static", "mcmc")


@pytest.fixture(scope="module")
def route_experts(tmp_path_factory) -> Path:
    """Two short finished expert runs that ``moegs route`` reuses as its stage 1."""
    base = tmp_path_factory.mktemp("route_experts")
    for name in ROUTE_EXPERTS:
        argv = ["train", "--expert", name, "--scene", SCENE, "--iterations", "30", "--quiet"]
        assert main([*argv, "--out", str(base / name)]) == 0
    return base


def _route_folder(experts: Path, out: Path) -> Path:
    import shutil

    for name in ROUTE_EXPERTS:
        shutil.copytree(experts / name, out / name)
    return out


def _route_cmd(out: Path, every: int) -> list[str]:
    cmd = [sys.executable, "-m", "moegs.cli", "route", "--experts", ",".join(ROUTE_EXPERTS), "--scene", SCENE]
    return cmd + [
        "--out",
        str(out),
        "--iterations",
        "120",
        "--checkpoint-every",
        str(every),
        "--gate-views",
        "0",
    ]


def _router_metrics(out: Path) -> dict:
    return json.loads((out / "router_vapr" / "metrics.json").read_text())


@pytest.mark.slow
def test_route_ctrl_c_and_kill_9_resume_to_the_same_result(route_experts, tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    reference = _route_folder(route_experts, tmp_path / "reference")
    done = subprocess.run(_route_cmd(reference, 50), capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    expected = _router_metrics(reference)["test"]

    for how in ("ctrl-c", "kill-9"):
        out = _route_folder(route_experts, tmp_path / how)
        ckpt = out / "router_vapr" / "router.safetensors"
        proc = subprocess.Popen(
            _route_cmd(out, 10),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            preexec_fn=default_sigint,
        )
        deadline = time.monotonic() + 300
        while not ckpt.is_file():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no router checkpoint written"
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT if how == "ctrl-c" else signal.SIGKILL)
        _, err = proc.communicate(timeout=300)
        if how == "ctrl-c":
            assert proc.returncode == 130, err
            assert "moegs route: interrupted: SIGINT after step" in err and "Traceback" not in err
        assert not (out / "router_vapr" / "metrics.json").exists()
        again = subprocess.run(_route_cmd(out, 10), capture_output=True, text=True, env=env, timeout=600)
        assert again.returncode == 0, again.stderr[-2000:]
        assert _router_metrics(out)["test"]["psnr"] == expected["psnr"], how

    finished = _router_metrics(reference)
    rerun = subprocess.run(_route_cmd(reference, 50), capture_output=True, text=True, env=env, timeout=600)
    assert rerun.returncode == 0 and "holds a finished router run" in rerun.stdout
    assert _router_metrics(reference) == finished  # left alone


@pytest.mark.slow
def test_route_runs_trains_only_the_router(route_experts, tmp_path, capsys):
    """``moegs route --runs`` routes finished runs as they are: nothing in their folders is written, no
    expert trains in ``--out``; the router folder records its runs and refuses a router over others."""
    import hashlib

    def snapshot() -> dict:
        return {
            str(p): (p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
            for p in sorted(route_experts.rglob("*"))
            if p.is_file()
        }

    runs = [str(route_experts / name) for name in ROUTE_EXPERTS]
    before = snapshot()
    out = tmp_path / "moe"
    argv = ["route", "--runs", *runs, "--out", str(out), "--iterations", "10", "--gate-views", "1", "--quiet"]
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    for name, run in zip(ROUTE_EXPERTS, runs, strict=True):
        assert f"expert {name}: reusing the trained run {run} ({name}, 30 iterations, test PSNR " in printed
    assert snapshot() == before  # no expert was trained, resumed or rewritten
    assert [p.name for p in out.iterdir()] == ["router_vapr"]
    router = out / "router_vapr"
    assert json.loads((router / "metrics.json").read_text())["experts"] == list(ROUTE_EXPERTS)
    recorded = json.loads((router / "runs.json").read_text())["runs"]
    assert [(router / r).resolve() for r in recorded] == [Path(r).resolve() for r in runs]
    assert (router / "gates" / "gate_1_mcmc_000.png").is_file()

    assert main(argv) == 0  # the same command finds its finished router
    assert "holds a finished router run" in capsys.readouterr().out
    swapped = ["route", "--runs", *runs[::-1], "--out", str(out), "--iterations", "10", "--quiet"]
    assert main(swapped) == 2
    err = capsys.readouterr().err
    assert f"moegs route: {router} holds a router over other expert runs (" in err and "--force" in err
    assert snapshot() == before


def _fake_run(folder: Path, **changes) -> str:
    """A run folder with what ``--runs`` reads before loading anything (``config.json``, ``metrics.json``):
    a finished static run of the quick preset on the stand-in, with ``changes``."""
    values = {"expert": "static", "scene": SCENE, "preset": "quick", "background": "white", "completed": True}
    values |= changes
    overrides = {"train.resolution_scale": values["scale"]} if "scale" in values else {}
    config = {
        "expert": values["expert"],
        "scene": values["scene"],
        "train": {"resolution_scale": values.get("scale", 0.125)},
        "recipe": {"preset": values["preset"], "background": values["background"], "overrides": overrides},
    }
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "metrics.json").write_text(
        json.dumps({"completed": values["completed"], "test": {"psnr": 20.0}})
    )
    return str(folder)


RUNS_REFUSED = {  # the second run's changes, extra arguments, expected message ({a}, {b}: the runs)
    "another background": (
        {"background": "black"},
        [],
        "the runs trained on different backgrounds ({a}: white, {b}: black); a router blends images "
        "composited on one background",
    ),
    "another preset": (
        {"preset": "paper"},
        [],
        "the runs trained on different presets ({a}: quick, {b}: paper); route runs of one preset",
    ),
    "another scene": (
        {"scene": "synthetic:n3v_like"},
        [],
        f"the runs trained on different scenes ({{a}}: {SCENE}, {{b}}: synthetic:n3v_like); "
        "route runs of one scene",
    ),
    "another image size": (
        {"scale": 0.5},
        [],
        "the runs trained on different image scales ({a}: None, {b}: 0.5); "
        "a router blends images of one size",
    ),
    "unfinished": ({"completed": False}, [], "{b} holds no finished run (metrics.json of a completed"),
    "unknown expert": ({"expert": "nosuch"}, [], "unknown expert 'nosuch'"),
    "another --scene": (
        {},
        ["--scene", "synthetic:n3v_like"],
        f"--scene synthetic:n3v_like but the runs trained on {SCENE}; leave --scene out with --runs",
    ),
    "another --preset": (
        {},
        ["--preset", "paper"],
        "--preset paper but the runs trained at quick; leave --preset out with --runs",
    ),
    "--expert-iterations": (
        {},
        ["--expert-iterations", "5"],
        "--expert-iterations trains experts (--experts); --runs routes trained runs as they are",
    ),
}


@pytest.mark.parametrize("case", sorted(RUNS_REFUSED))
def test_route_runs_that_cannot_be_routed_are_refused_in_one_line(case, tmp_path, capsys):
    changes, extra, message = RUNS_REFUSED[case]
    a, b = _fake_run(tmp_path / "a"), _fake_run(tmp_path / "b", **changes)
    out = tmp_path / "out"
    assert main(["route", "--runs", a, b, *extra, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"moegs route: {message.format(a=a, b=b)}"), err
    assert not out.exists()


def test_route_runs_needs_two_different_run_folders(tmp_path, capsys):
    a = _fake_run(tmp_path / "a")
    (tmp_path / "empty").mkdir()
    cases = {
        (a,): "--runs needs at least two different run folders to route between",
        (a, a): f"--runs names {str(a)!r} more than once (a duplicate); give each once",
        (a, str(tmp_path / "empty")): f"{tmp_path / 'empty'} is not a training run (no config.json)",
    }
    for runs, message in cases.items():
        assert main(["route", "--runs", *runs, "--out", str(tmp_path / "out"), "--quiet"]) == 2
        assert capsys.readouterr().err.startswith(f"moegs route: {message}")
    assert not (tmp_path / "out").exists()


def test_finished_run_is_a_completed_and_evaluated_run(tmp_path):
    """The one check ``moegs train``, ``compare`` and ``route`` use before training into a folder."""
    import json

    from moegs.train.entry import finished_run

    metrics = tmp_path / "metrics.json"
    assert finished_run(tmp_path) is None  # nothing there yet
    for partial in ({"completed": False, "test": {"psnr": 20.0}}, {"completed": True, "test": None}):
        metrics.write_text(json.dumps(partial))
        assert finished_run(tmp_path) is None  # interrupted, or stopped before its evaluation
    metrics.write_text(json.dumps({"completed": True, "test": {"psnr": 20.0}}))
    assert finished_run(tmp_path)["test"]["psnr"] == 20.0
    metrics.write_text("{cut")
    with pytest.raises(ValueError, match=re.escape(f"{metrics} is not valid JSON") + ".*; remove it"):
        finished_run(tmp_path)


def test_changed_fields_are_described_six_at_most():
    from moegs.train.reuse import describe_changes

    assert describe_changes(["train.iterations"]) == "train.iterations"
    assert describe_changes(list("abcdef")) == "a, b, c, d, e, f"
    assert describe_changes(list("abcdefgh")) == "a, b, c, d, e, f and 2 more"
