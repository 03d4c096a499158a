"""``moegs`` command line: a light ``list`` and an end-to-end smoke run on a generated scene."""

import json
import subprocess
import sys

import pytest

from moegs.cli import main

SCENE = "synthetic:dnerf_like"  # generated on demand (~3 s), needs no staged data


def test_list_imports_no_torch_expert_renderer_or_loader():
    code = (
        "import sys; from moegs.cli import main; main(['list']); "
        "heavy = [m for m in sys.modules if m.startswith(('torch', 'moegs.render', 'moegs.experts.', "
        "'moegs.train', 'moegs.data.', 'moegs.metrics'))]; assert not heavy, heavy"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "static" in done.stdout and "mcmc" in done.stdout and "dnerf" in done.stdout


def test_list_says_where_it_looked_for_data(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path / "missing"))
    assert main(["list"]) == 0
    assert f"data root: {tmp_path / 'missing'} (MOEGS_DATA) does not exist" in capsys.readouterr().out
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    assert main(["list"]) == 0
    assert f"data root: {tmp_path}\n" in capsys.readouterr().out
    monkeypatch.setattr("moegs.paths.data_root", lambda: None)
    assert main(["list"]) == 0
    assert "data root: none (set MOEGS_DATA;" in capsys.readouterr().out


def test_unknown_expert_lists_valid_names(capsys):
    assert main(["train", "--expert", "nope", "--scene", SCENE]) == 2
    err = capsys.readouterr().err
    assert "unknown expert 'nope'; registered experts:" in err and "mcmc" in err and "static" in err


def test_recipe_shows_how_a_config_is_made(capsys):
    assert main(["recipe", "--expert", "grid4d", "--scene", "dnerf:lego"]) == 0
    out = capsys.readouterr().out
    assert "dnerf preset 'paper-dnerf'" in out and "grid_lr_scale=250.0" in out and "background: black" in out
    assert (
        main(
            [
                "recipe",
                "--expert",
                "ed3dgs",
                "--scene",
                "synthetic:n3v_like",
                "--dataset",
                "technicolor",
                "--json",
            ]
        )
        == 0
    )
    record = json.loads(capsys.readouterr().out)
    assert record["recipe"]["base"] == "paper-technicolor" and record["config"]["min_embeddings"] == 5


@pytest.mark.slow
def test_train_eval_render_export(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MOEGS_CACHE", str(tmp_path / "cache"))
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "--expert",
                "static",
                "--scene",
                SCENE,
                "--iterations",
                "4",
                "--resolution-scale",
                "0.4",
                "--out",
                str(run),
                "--quiet",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["completed"] and metrics["step"] == 4 and metrics["stand_in"]
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["seed"] == 1 and config["train"]["resolution_scale"] == 0.4
    assert config["recipe"]["base"] == "paper" and config["recipe"]["preset"] == "quick"
    assert config["recipe"]["overrides"]["train.iterations"] == 4

    assert main(["eval", str(run), "--profile", "clean"]) == 0
    assert json.loads((run / "eval-clean.json").read_text())["psnr"] == pytest.approx(
        metrics["test"]["psnr"], abs=1.0
    )
    assert main(["render", str(run)]) == 0
    renders = run / "renders"
    assert (renders / "video.mp4").stat().st_size > 0 and (renders / "00000.png").is_file()
    assert len((renders / "psnr.csv").read_text().splitlines()) == 1 + metrics["test"]["num_views"]
    assert main(["export", str(run), "--time", "0.5", "--out", str(tmp_path / "g.ply")]) == 0
    assert (tmp_path / "g.ply").stat().st_size > 0
    capsys.readouterr()
    assert main(["eval", str(tmp_path)]) == 2
    assert "is not a training run (no config.json)" in capsys.readouterr().err
