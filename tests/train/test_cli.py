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
    assert "  synthetic    generated on demand\n" in done.stdout and "  n3v          " in done.stdout


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


@pytest.mark.parametrize("scene", ["dnerf:mutant", "synthetic:dnerf_like"])
@pytest.mark.parametrize("overrides", [{}, {"train.resolution_scale": 0.4}])
def test_a_run_reloads_its_scene_as_its_training_loaded_it(scene, overrides):
    """``eval`` / ``render`` / ``export`` read the run's ``config.json``: the loader arguments must be the
    recipe's (``Recipe.load_kwargs``), or the scores are of other images than the run's own test views."""
    from moegs.cli import _load_kwargs
    from moegs.recipes import config_for

    recipe = config_for("static", scene, "quick", overrides=overrides)
    meta = {"scene": scene, "train": {"resolution_scale": recipe.config.train.resolution_scale}}
    assert _load_kwargs({**meta, "recipe": recipe.provenance()}) == recipe.load_kwargs


def test_export_writes_the_gaussians_at_the_time_asked(tmp_path, monkeypatch):
    """``moegs export RUN --time t`` exports ``frame(t)`` (a deforming expert's Gaussians move with t)."""
    import moegs.cli
    import moegs.io

    asked, written = [], []

    class Expert:
        def frame(self, t):
            asked.append(t)
            return f"frame at {t}"

    monkeypatch.setattr(moegs.cli, "_load_run", lambda run: (tmp_path, None, None, Expert()))
    monkeypatch.setattr(moegs.io, "export_ply", lambda frame, path: written.append((frame, path)) or path)
    assert main(["export", str(tmp_path), "--time", "0.25"]) == 0
    assert asked == [0.25] and written == [("frame at 0.25", tmp_path / "point_cloud_t0.250.ply")]


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
    evaluated = json.loads((run / "eval-clean.json").read_text())
    # the same views at the resolution the run trained at (the user's 0.4 of the stand-in): the same PSNR
    assert [v["key"] for v in evaluated["per_view"]] == [v["key"] for v in metrics["test"]["per_view"]]
    assert evaluated["psnr"] == pytest.approx(metrics["test"]["psnr"], abs=1e-6)
    assert main(["render", str(run)]) == 0
    renders = run / "renders"
    assert (renders / "video.mp4").stat().st_size > 0 and (renders / "00000.png").is_file()
    assert len((renders / "psnr.csv").read_text().splitlines()) == 1 + metrics["test"]["num_views"]
    assert main(["export", str(run), "--time", "0.5", "--out", str(tmp_path / "g.ply")]) == 0
    assert (tmp_path / "g.ply").stat().st_size > 0
    capsys.readouterr()
    assert main(["eval", str(tmp_path)]) == 2
    assert "is not a training run (no config.json)" in capsys.readouterr().err
