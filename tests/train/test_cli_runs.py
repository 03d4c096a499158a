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
