"""``moegs`` command line: a light ``list`` and an end-to-end smoke run on a generated scene."""

import json
import re
import subprocess
import sys

import av
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
    assert "  synthetic    dnerf_like, n3v_like (generated on demand)\n" in done.stdout
    assert "  n3v          " in done.stdout


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
    import torch

    import moegs.cli
    import moegs.io
    from moegs.gaussians import GaussianFrame

    asked, written = [], []

    class Expert:
        def frame(self, t):
            asked.append(t)
            one = torch.ones(1, 3)
            return GaussianFrame(t * one, torch.ones(1, 4), -one, torch.ones(1), colors=one)

    monkeypatch.setattr(moegs.cli, "_load_run", lambda run: (tmp_path, None, None, Expert()))
    monkeypatch.setattr(moegs.io, "export_ply", lambda frame, path: written.append((frame, path)) or path)
    assert main(["export", str(tmp_path), "--time", "0.25"]) == 0
    [(frame, path)] = written
    assert asked == [0.25] and path == tmp_path / "point_cloud_t0.250.ply"
    assert frame.means.tolist() == [[0.25] * 3] and frame.scales.tolist() == [[1.0] * 3]  # |scales|: logs


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
    """A tiny run at an odd image size (37x37): train prints PSNR, SSIM, LPIPS and its files and keeps its
    loss curve; render writes yuv420p videos (padded to 38x38) along each path with time advancing, and a
    ground truth | render | error strip per test view."""
    import imageio.v3 as iio

    import moegs.cli
    from moegs.io.video import decode_video

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
                "0.37",
                "--out",
                str(run),
                "--quiet",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["completed"] and metrics["step"] == 4 and metrics["stand_in"]
    assert re.search(
        r"^test \(5 views\): PSNR \d+\.\d\d  SSIM \d\.\d{4}  LPIPS (\d\.\d{4}|n/a \(.+\))$", printed, re.M
    )
    assert f"wrote {run}:\n  config.json " in printed
    for name in ("checkpoint.safetensors", "metrics.json", "loss.json", "loss.png"):
        assert re.search(rf"^  {re.escape(name)} +\S", printed, re.M), name
    loss = json.loads((run / "loss.json").read_text())["curves"]["static"]
    assert loss["first_step"] == 1 and len(loss["loss"]) == 4 and loss["loss"][-1] == metrics["final_loss"]
    assert iio.imread(run / "loss.png").ndim == 3
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["seed"] == 1 and config["train"]["resolution_scale"] == 0.37
    assert config["recipe"]["base"] == "paper" and config["recipe"]["preset"] == "quick"
    assert config["recipe"]["overrides"]["train.iterations"] == 4

    assert main(["eval", str(run), "--profile", "clean"]) == 0
    evaluated = json.loads((run / "eval-clean.json").read_text())
    # the same views at the resolution the run trained at (the user's 0.37 of the stand-in): the same PSNR
    assert [v["key"] for v in evaluated["per_view"]] == [v["key"] for v in metrics["test"]["per_view"]]
    assert evaluated["psnr"] == pytest.approx(metrics["test"]["psnr"], abs=1e-6)

    times = []
    render = moegs.cli._render_image
    monkeypatch.setattr(moegs.cli, "_render_image", lambda e, c, *a: times.append(c.time) or render(e, c, *a))
    capsys.readouterr()
    assert main(["render", str(run), "--frames", "6"]) == 0  # auto: the D-NeRF-like rig surrounds the scene
    renders = run / "renders"
    printed = capsys.readouterr().out
    assert f"wrote {renders}:\n  video.mp4 " in printed
    assert "6 frames along the orbit path, time 0.000 -> 1.000, 38x38 H.264 yuv420p, 30 fps\n" in printed
    assert re.search(
        r"^  test/00000\.\.00004\.png +ground truth \| render \| error of each test view", printed, re.M
    )
    assert times == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    with av.open(str(renders / "video.mp4")) as container:
        stream = container.streams.video[0]
        assert (stream.codec_context.name, stream.codec_context.pix_fmt) == ("h264", "yuv420p")
    assert decode_video(renders / "video.mp4").shape == (6, 38, 38, 3)
    strip = iio.imread(renders / "test" / "00000.png")
    assert strip.shape == (37, 3 * 37, 3)
    rows = (renders / "psnr.csv").read_text().splitlines()
    assert len(rows) == 1 + metrics["test"]["num_views"]
    assert float(rows[1].split(",")[-1]) == pytest.approx(metrics["test"]["per_view"][0]["psnr"], abs=1e-3)
    times.clear()
    assert main(["render", str(run), "--path", "spiral", "--frames", "3"]) == 0
    assert decode_video(renders / "video.mp4").shape[0] == 3 and times == [0.0, 0.5, 1.0]
    times.clear()
    assert main(["render", str(run), "--path", "test", "--out", str(tmp_path / "r")]) == 0
    assert times == [] and "5 frames along the test path" in capsys.readouterr().out  # the strips' renders
    assert decode_video(tmp_path / "r" / "video.mp4").shape[0] == metrics["test"]["num_views"]

    assert main(["export", str(run), "--time", "0.5", "--out", str(tmp_path / "g.ply")]) == 0
    assert (tmp_path / "g.ply").stat().st_size > 0
    capsys.readouterr()
    assert main(["eval", str(tmp_path)]) == 2
    assert "is not a training run (no config.json)" in capsys.readouterr().err
