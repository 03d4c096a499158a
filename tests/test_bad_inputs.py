# ruff: noqa: E501  (one case per line: the tables read as tables)
"""Every bad input ends in one clear message naming the argument, file or field and what was expected.

One table per boundary: command-line arguments (rejected before any work), commands on broken runs,
dataset loaders (D-NeRF, Panoptic, HyperNeRF JSON), checkpoint files, the bench's cache, and the
rasterizer's inputs. Each case asserts the message itself, not only that something failed.
"""

from __future__ import annotations

import importlib
import json
import math
import re
from pathlib import Path

import helpers.data_layouts as fx
import pytest
import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.cli import main
from moegs.gaussians import GaussianFrame
from moegs.render import rasterize

SCENE = "synthetic:dnerf_like"
EXPERTS = "deformable, ed3dgs, ex4dgs, fourdgs, grid4d, mcmc, mode, static, stg"


def _one_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in text, text
    return lines[0]


# -- 1. command-line arguments: argparse rejects them before any work (exit 2) --------------------------
TRAIN = ["train", "--expert", "static", "--scene", SCENE]
ROUTE = ["route", "--experts", "static,mcmc", "--scene", SCENE]
COMPARE = ["compare", "--scene", SCENE]
# fmt: off
ARGUMENTS = [
    (["train", "--expert", "static", "--scene", "foo"], "argument --scene: scene name must be '<dataset>:<scene>', got 'foo'"),
    (["train", "--expert", "static", "--scene", "nosuch:x"], "argument --scene: unknown dataset 'nosuch' in 'nosuch:x'"),
    (["train", "--expert", "static", "--scene", "dnerf:"], "argument --scene: scene name 'dnerf:' has no scene after ':'"),
    ([*TRAIN, "--seed", "-1"], "argument --seed: expected an integer seed in [0, 2**63), got '-1'"),
    ([*TRAIN, "--seed", "1e20"], "argument --seed: expected an integer seed in [0, 2**63), got '1e20'"),
    ([*TRAIN, "--seed", str(2**64)], f"argument --seed: expected an integer seed in [0, 2**63), got '{2**64}'"),
    ([*TRAIN, "--iterations", "0"], "argument --iterations: expected a positive integer, got '0'"),
    ([*TRAIN, "--iterations", "-5"], "argument --iterations: expected a positive integer, got '-5'"),
    ([*TRAIN, "--iterations", "ten"], "argument --iterations: expected a positive integer, got 'ten'"),
    ([*TRAIN, "--resolution-scale", "0"], "argument --resolution-scale: expected a scale in (0, 1], got '0'"),
    ([*TRAIN, "--resolution-scale", "1.5"], "argument --resolution-scale: expected a scale in (0, 1], got '1.5'"),
    ([*TRAIN, "--resolution-scale", "nan"], "argument --resolution-scale: expected a scale in (0, 1], got 'nan'"),
    ([*TRAIN, "--checkpoint-every", "0"], "argument --checkpoint-every: expected a positive integer, got '0'"),
    ([*TRAIN, "--preset", "big"], "argument --preset: invalid choice: 'big'"),
    (["train", "--scene", SCENE], "the following arguments are required: --expert"),
    (["route", "--scene", SCENE], "one of the arguments --experts --runs is required"),
    ([*ROUTE, "--runs", "a", "b"], "argument --runs: not allowed with argument --experts"),
    ([*ROUTE, "--expert-iterations", "0"], "argument --expert-iterations: expected a positive integer, got '0'"),
    ([*ROUTE, "--router", "nosuch"], "argument --router: invalid choice: 'nosuch'"),
    ([*ROUTE, "--iterations", "0"], "argument --iterations: expected a positive integer, got '0'"),
    ([*ROUTE, "--gate-views", "-1"], "argument --gate-views: expected an integer >= 0, got '-1'"),
    ([*ROUTE, "--convention", "x"], "argument --convention: invalid choice: 'x'"),
    ([*ROUTE, "--preset", "x"], "argument --preset: invalid choice: 'x'"),
    ([*ROUTE, "--seed", "-3"], "argument --seed: expected an integer seed in [0, 2**63), got '-3'"),
    (["route", "--experts", "static,mcmc", "--scene", "mutant"], "argument --scene: scene name must be '<dataset>:<scene>', got 'mutant'"),
    ([*ROUTE, "--checkpoint-every", "0"], "argument --checkpoint-every: expected a positive integer, got '0'"),
    (["render", "run", "--fps", "0"], "argument --fps: expected a positive integer, got '0'"),
    (["render", "run", "--fps", "-2"], "argument --fps: expected a positive integer, got '-2'"),
    (["render", "run", "--fps", "x"], "argument --fps: expected a positive integer, got 'x'"),
    (["render", "run", "--frames", "0"], "argument --frames: expected a positive integer, got '0'"),
    (["render", "run", "--path", "zigzag"], "argument --path: invalid choice: 'zigzag'"),
    (["export", "run", "--time", "7.5"], "argument --time: expected a time in [0, 1], got '7.5'"),
    (["export", "run", "--time", "nan"], "argument --time: expected a time in [0, 1], got 'nan'"),
    (["export", "run", "--time", "-0.1"], "argument --time: expected a time in [0, 1], got '-0.1'"),
    (["export", "run", "--time", "abc"], "argument --time: expected a time in [0, 1], got 'abc'"),
    ([*COMPARE, "--frames", "3"], "argument --frames: expected START:STOP with 0 <= START < STOP, got '3'"),
    ([*COMPARE, "--frames", "5:2"], "argument --frames: expected START:STOP with 0 <= START < STOP, got '5:2'"),
    ([*COMPARE, "--frames", "a:b"], "argument --frames: expected START:STOP with 0 <= START < STOP, got 'a:b'"),
    ([*COMPARE, "--preset", "x"], "argument --preset: invalid choice: 'x'"),
    (["eval", "run", "--profile", "x"], "argument --profile: invalid choice: 'x'"),
    (["recipe", "--expert", "static", "--scene", SCENE, "--preset", "x"], "argument --preset: invalid choice: 'x'"),
    (["recipe", "--expert", "static", "--scene", "x"], "argument --scene: scene name must be '<dataset>:<scene>', got 'x'"),
    (["nosuch"], "argument command: invalid choice: 'nosuch'"),
]
# fmt: on


@pytest.mark.parametrize(("argv", "message"), ARGUMENTS, ids=[" ".join(a) for a, _ in ARGUMENTS])
def test_bad_arguments_are_rejected_before_any_work(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err, err


# -- 2. commands on bad names and broken runs: one line, exit 2 -----------------------------------------
@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished two-step static run on the small D-NeRF-like stand-in."""
    out = tmp_path_factory.mktemp("run") / "static"
    argv = [*TRAIN, "--resolution-scale", "0.4", "--quiet"]
    assert main([*argv, "--iterations", "2", "--out", str(out)]) == 0
    return out


def _copy_run(run: Path, tmp_path: Path) -> Path:
    import shutil

    return Path(shutil.copytree(run, tmp_path / "run"))


def _swap_checkpoint(run: Path) -> None:
    """Replace the run's checkpoint by one of another expert (mcmc) trained for one step."""
    assert main(["train", "--expert", "mcmc", "--scene", SCENE, "--resolution-scale", "0.4", "--quiet",
                 "--iterations", "1", "--out", str(run.parent / "other")]) == 0  # fmt: skip
    (run / "checkpoint.safetensors").write_bytes(
        (run.parent / "other" / "checkpoint.safetensors").read_bytes()
    )


def _flip_a_bit(run: Path) -> None:
    """A bit of the checkpoint's last tensor flipped after it was written (disk or copy damage)."""
    path = run / "checkpoint.safetensors"
    raw = bytearray(path.read_bytes())
    raw[-5] ^= 0x10
    path.write_bytes(bytes(raw))


def _other_scene(run: Path) -> None:
    """The checkpoint rewritten (with a valid digest) as if trained on another scene."""
    from moegs.io import load_checkpoint, save_checkpoint

    path = run / "checkpoint.safetensors"
    state = load_checkpoint(path)
    state["scene"]["name"] = "synthetic:n3v_like"
    save_checkpoint(path, state)


def _edit_config(run: Path, change) -> None:
    path = run / "config.json"
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _crafted_type(run: Path) -> None:
    from safetensors import safe_open
    from safetensors.torch import save_file

    path = run / "checkpoint.safetensors"
    with safe_open(str(path), "pt") as f:
        meta, tensors = f.metadata(), {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
    tree = json.loads(meta["moegs"])
    tree["expert"]["config"]["strategy"]["_type"] = "subprocess:Popen"
    save_file(tensors, str(path), metadata={"moegs": json.dumps(tree)})


def _small_images(run: Path) -> None:
    """The run's config says it trained at scale 0.2 (20x20 images: too small for LPIPS)."""

    def change(data: dict) -> None:
        data["train"]["resolution_scale"] = 0.2
        data["recipe"]["overrides"]["train.resolution_scale"] = 0.2

    _edit_config(run, change)


BROKEN_RUNS = {  # name: (damage(run), argv after the command, expected message; {run} = the run folder)
    "no config.json": (lambda r: (r / "config.json").unlink(), "eval", "{run} is not a training run (no config.json); train one with `moegs train`"),
    "config.json not JSON": (lambda r: (r / "config.json").write_text("{oops"), "eval", "{run}/config.json: not valid JSON (Expecting property name enclosed in double quotes: line 1 column 2 (char 1))"),
    "config.json a list": (lambda r: (r / "config.json").write_text("[1]"), "eval", "{run}/config.json: expected a JSON object, got list"),
    "config.json no expert": (lambda r: _edit_config(r, lambda d: d.pop("expert")), "eval", "{run}/config.json: field 'expert' must be a str, got None"),
    "config.json scene a number": (lambda r: _edit_config(r, lambda d: d.update(scene=3)), "eval", "{run}/config.json: field 'scene' must be a str, got 3"),
    "config.json unknown scene": (lambda r: _edit_config(r, lambda d: d.update(scene="nosuch:x")), "eval", "unknown dataset 'nosuch' in 'nosuch:x'; valid datasets: ['dnerf', 'panoptic', 'n3v', 'technicolor', 'hypernerf', 'synthetic']"),
    "no checkpoint": (lambda r: (r / "checkpoint.safetensors").unlink(), "eval", "checkpoint {run}/checkpoint.safetensors does not exist"),
    "truncated checkpoint": (lambda r: (r / "checkpoint.safetensors").write_bytes((r / "checkpoint.safetensors").read_bytes()[:100]), "eval", "{run}/checkpoint.safetensors: not a readable safetensors file ("),
    "empty checkpoint": (lambda r: (r / "checkpoint.safetensors").write_bytes(b""), "eval", "{run}/checkpoint.safetensors: not a readable safetensors file ("),
    "checkpoint with a flipped bit": (_flip_a_bit, "eval", "{run}/checkpoint.safetensors: its content does not match the digest written with it (changed or damaged after it was written); train again, or delete the file to start that run over"),
    "checkpoint of another scene": (_other_scene, "eval", "{run}/checkpoint.safetensors was trained on another scene (name 'synthetic:n3v_like'), not this one (name 'synthetic:dnerf_like')"),
    "checkpoint of another expert": (_swap_checkpoint, "eval", "{run}/checkpoint.safetensors holds a 'mcmc' checkpoint, but its run says 'static'"),
    "crafted config type": (_crafted_type, "eval", "config _type 'subprocess:Popen' is not Strategy or a moegs subclass of it"),
    "render: truncated checkpoint": (lambda r: (r / "checkpoint.safetensors").write_bytes(b"\x00" * 9), "render", "{run}/checkpoint.safetensors: not a readable safetensors file ("),
    "export: no config.json": (lambda r: (r / "config.json").unlink(), "export", "{run} is not a training run (no config.json); train one with `moegs train`"),
    "images too small to score": (_small_images, "eval", "{run} was trained on images too small to score: --resolution-scale 0.2 makes synthetic:dnerf_like's images 20x20 pixels ("),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BROKEN_RUNS))
def test_broken_runs_fail_with_one_line_naming_the_file(case, finished_run, tmp_path, capsys):
    damage, command, message = BROKEN_RUNS[case]
    run = _copy_run(finished_run, tmp_path)
    damage(run)
    capsys.readouterr()
    assert main([command, str(run)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"moegs {command}: {message.format(run=run)}"), line


COMMANDS = [
    (["train", "--expert", "nosuch", "--scene", SCENE], f"moegs train: unknown expert 'nosuch'; registered experts: {EXPERTS}"),
    ([*TRAIN, "--set", "oops"], "moegs train: --set expects FIELD=VALUE (e.g. train.iterations=100), got 'oops'"),
    ([*TRAIN, "--set", "nosuch=1"], "moegs train: StaticConfig has no field 'nosuch' (in 'nosuch')"),
    ([*TRAIN, "--set", "train.nosuch=1"], "moegs train: TrainConfig has no field 'nosuch' (in 'train.nosuch'); fields: ['backend', "),
    ([*TRAIN, "--set", "train=1"], "moegs train: 'train' is a group of fields; set one of them, e.g. train.iterations=..."),
    ([*TRAIN, "--set", "train.batch_size=true"], "moegs train: --set train.batch_size=true: train.batch_size expects an int, got true"),
    ([*TRAIN, "--set", "train.iterations=-5"], "moegs train: --set train.iterations=-5: train.iterations expects a positive int, got -5"),
    ([*TRAIN, "--iterations", "3", "--set", "train.iterations=abc"], "moegs train: --set train.iterations=abc: train.iterations expects an int, got abc"),
    ([*TRAIN, "--set", "train.lambda_dssim=inf"], "moegs train: --set train.lambda_dssim=inf: train.lambda_dssim expects a finite number, got inf"),
    ([*TRAIN, "--set", "train.lambda_dssim=2"], "moegs train: --set train.lambda_dssim=2: TrainConfig.lambda_dssim must be in [0, 1], got 2.0"),
    ([*TRAIN, "--set", "train.resolution_scale=0"], "moegs train: --set train.resolution_scale=0: train.resolution_scale expects a scale in (0, 1], got 0"),
    ([*TRAIN, "--set", "strategy.densify_every=0"], "moegs train: --set strategy.densify_every=0: strategy.densify_every expects a positive int, got 0"),
    ([*TRAIN, "--set", "train.seed=1", "train.seed=2"], "moegs train: --set train.seed is given twice (1 and 2); give it once"),
    ([*TRAIN, "--seed", "1", "--set", "train.seed=5"], "moegs train: --seed 1 and --set train.seed=5 disagree; give one of them"),
    ([*TRAIN, "--iterations", "3", "--set", "train.iterations=4"], "moegs train: --iterations 3 and --set train.iterations=4 disagree; give one of them"),
    ([*TRAIN, "--resolution-scale", "0.5", "--set", "train.resolution_scale=0.4"], "moegs train: --resolution-scale 0.5 and --set train.resolution_scale=0.4 disagree; give one of them"),
    ([*TRAIN, "--checkpoint-every", "2", "--set", "train.checkpoint_every=3"], "moegs train: --checkpoint-every 2 and --set train.checkpoint_every=3 disagree; give one of them"),
    ([*TRAIN, "--resolution-scale", "0.1"], "moegs train: --resolution-scale 0.1 makes synthetic:dnerf_like's images 10x10 pixels ("),
    ([*TRAIN, "--set", "train.resolution_scale=0.2"], "moegs train: --set train.resolution_scale=0.2 makes synthetic:dnerf_like's images 20x20 pixels ("),
    ([*TRAIN, "--resolution-scale", "0.001"], "moegs train: --resolution-scale 0.001 makes the images 0x0 pixels; SSIM and LPIPS need at least 31x31 (SSIM's window: 11 px, LPIPS-Alex: 31): use a larger scale"),
    (["route", "--experts", "static", "--scene", SCENE], "moegs route: --experts needs at least two different experts to route between, got ['static']"),
    (["route", "--experts", "static,static", "--scene", SCENE], "moegs route: --experts names 'static' more than once (a duplicate); give each once"),
    (["route", "--experts", "static,mcmc,static", "--scene", SCENE], "moegs route: --experts names 'static' more than once (a duplicate); give each once"),
    (["compare", "--experts", "static,mcmc,static", "--scene", SCENE], "moegs compare: --experts names 'static' more than once (a duplicate); give each once"),
    (["route", "--experts", "static,nosuch", "--scene", SCENE], f"moegs route: unknown expert 'nosuch'; registered experts: {EXPERTS}"),
    (["route", "--experts", "static,mcmc"], "moegs route: --experts needs --scene (the runs of --runs name theirs)"),
    (["compare", "--experts", ",", "--scene", SCENE], "moegs compare: --experts: expected comma-separated registry names or 'all', got none"),
    (["compare", "--experts", "nope", "--scene", SCENE], f"moegs compare: unknown expert 'nope'; registered experts: {EXPERTS}"),
    (["recipe", "--expert", "nosuch", "--scene", SCENE], f"moegs recipe: unknown expert 'nosuch'; registered experts: {EXPERTS}"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "message"), COMMANDS, ids=[" ".join(a[:3]) + " " + a[-1] for a, _ in COMMANDS]
)
def test_bad_names_fail_with_one_line(argv, message, tmp_path, capsys):
    assert main([*argv, *(["--out", str(tmp_path / "out")] if argv[0] != "recipe" else [])]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(message), line
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.safetensors"))


SMALL = [  # (argv, the end of its line: the smallest scale that works, named by the argument that set it)
    ([*TRAIN, "--resolution-scale", "0.1"], "; SSIM and LPIPS need at least 31x31 (SSIM's window: 11 px, LPIPS-Alex: 31): use --resolution-scale 0.31 or more"),
    ([*TRAIN, "--set", "train.resolution_scale=0.2"], ": use --set train.resolution_scale=0.31 or more"),
]  # fmt: skip


@pytest.mark.parametrize(("argv", "end"), SMALL, ids=[a[-1] for a, _ in SMALL])
def test_images_too_small_for_the_metrics_name_the_smallest_scale(argv, end, tmp_path, capsys):
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert _one_line(capsys.readouterr().err).endswith(end)
    assert not (tmp_path / "out").exists()  # refused before anything was written


HOLD = "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDONLY); fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)"


@pytest.mark.parametrize("command", ["train", "route", "compare"])
def test_a_second_writer_of_a_run_folder_gets_one_line(command, tmp_path, capsys):
    """While another process holds the folder (a ``moegs train`` on it: ``moegs.guards.folder_lock``), a second
    command on the same ``--out`` exits 2 with one line and writes nothing."""
    import subprocess
    import sys

    out = tmp_path / "out"
    out.mkdir()
    argv = {
        "train": [*TRAIN, "--iterations", "1"],
        "route": ROUTE,
        "compare": [*COMPARE, "--experts", "static"],
    }
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert main([*argv[command], "--out", str(out), "--quiet"]) == 2
    finally:
        holder.kill()
        holder.wait()
    held = f"{out} is in use by another moegs command (it holds the folder's lock); wait for it to end"
    assert _one_line(capsys.readouterr().err) == f"moegs {command}: {held} or choose another --out"
    assert not any(out.iterdir())


def test_eval_of_an_unfinished_run_says_so(tmp_path, capsys):
    """A run stopped at step 2 of 4 (as if killed): ``moegs eval`` scores its checkpoint and says that the run
    is unfinished, at which step, and how to finish it."""
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import train_recipe

    overrides = {"train.iterations": 4, "train.resolution_scale": 0.4, "train.checkpoint_every": 2}
    recipe = config_for("static", SCENE, "quick", overrides=overrides)
    run = tmp_path / "run"
    train_recipe(recipe, load_scene(SCENE, **recipe.load_kwargs), run, stop_after=2, progress=False)
    capsys.readouterr()
    assert main(["eval", str(run)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("static on synthetic:dnerf_like (5 test views, profile moegs): PSNR ")
    assert lines[1] == (
        "unfinished run: its checkpoint is at step 2 of 4 (no completed metrics.json); the scores above are "
        f"that checkpoint's, and the `moegs train` that wrote {run} finishes it"
    )
    assert json.loads((run / "eval-moegs.json").read_text())["unfinished"] == lines[1]


def test_eval_of_a_finished_run_says_nothing_more(finished_run, tmp_path, capsys):
    run = _copy_run(finished_run, tmp_path)
    capsys.readouterr()
    assert main(["eval", str(run)]) == 0
    assert len(capsys.readouterr().out.strip().splitlines()) == 1
    assert json.loads((run / "eval-moegs.json").read_text())["unfinished"] is None


def test_debug_shows_the_traceback():
    with pytest.raises(ValueError, match="at least two different experts"):
        main(["--debug", "route", "--experts", "static", "--scene", SCENE])


# -- 3. dataset loaders: JSON fields are type-checked, errors name file and field ---------------------
def _edited(tmp_path: Path, write, name: str, change) -> tuple[Path, Path]:
    """A fixture scene written by ``write(root)`` whose JSON file ``name`` is passed through ``change``."""
    root = tmp_path / "scene"
    write(root)
    path = root / name
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    return root, path


def _error_text(call, error) -> str:
    """The message of the ``error`` that ``call()`` raises (a KeyError's own text, unquoted)."""
    with pytest.raises(error) as err:
        call()
    return err.value.args[0] if isinstance(err.value, KeyError) else str(err.value)


def _dnerf(tmp_path: Path, change) -> tuple[Path, Path]:
    return _edited(tmp_path, fx.write_dnerf, "transforms_train.json", change)


def _set(field, value):
    return lambda d: d.__setitem__(field, value)


def _frame_field(field, value):
    return lambda d: d["frames"][1].__setitem__(field, value)


DNERF = {
    "angle a string": (_set("camera_angle_x", "wide"), TypeError, "{path}: 'camera_angle_x' must be a finite number, got 'wide'"),
    "angle zero": (_set("camera_angle_x", 0), ValueError, "{path}: 'camera_angle_x' must be a field of view in (0, pi) radians, got 0.0"),
    "angle negative": (_set("camera_angle_x", -0.5), ValueError, "{path}: 'camera_angle_x' must be a field of view in (0, pi) radians, got -0.5"),
    "angle too wide": (_set("camera_angle_x", 4.0), ValueError, "{path}: 'camera_angle_x' must be a field of view in (0, pi) radians, got 4.0"),
    "angle null": (_set("camera_angle_x", None), TypeError, "{path}: 'camera_angle_x' must be a finite number, got None"),
    "angle a bool": (_set("camera_angle_x", True), TypeError, "{path}: 'camera_angle_x' must be a finite number, got True"),
    "angle NaN": (_set("camera_angle_x", math.nan), TypeError, "{path}: 'camera_angle_x' must be a finite number, got nan"),
    "angle missing": (lambda d: d.pop("camera_angle_x"), KeyError, "{path}: missing key 'camera_angle_x' (found ['frames'])"),
    "frames missing": (lambda d: d.pop("frames"), KeyError, "{path}: missing key 'frames' (found ['camera_angle_x'])"),
    "frames empty": (_set("frames", []), ValueError, "{path}: 'frames' is empty"),
    "frames an object": (_set("frames", {}), TypeError, "{path}: 'frames' must be a list, got dict"),
    "frame not an object": (lambda d: d["frames"].__setitem__(0, 3), KeyError, "{path}: missing key 'file_path' in frames[0] (found int)"),
    "file_path a number": (_frame_field("file_path", 3), TypeError, "{path}: frames[1].file_path must be a string, got 3"),
    "matrix 3x3": (_frame_field("transform_matrix", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]), ValueError, "{path}: frames[1].transform_matrix must be 4x4, got [3, 3]"),
    "matrix of strings": (_frame_field("transform_matrix", [["a"] * 4] * 4), TypeError, "{path}: frames[1].transform_matrix must be a 4x4 array of numbers"),
    "matrix ragged": (_frame_field("transform_matrix", [[1, 0, 0, 0], [0, 1]]), TypeError, "{path}: frames[1].transform_matrix must be a 4x4 array of numbers"),
    "matrix with NaN": (_frame_field("transform_matrix", [[math.nan] * 4] * 4), ValueError, "{path}: frames[1].transform_matrix has NaN or Inf"),
    "matrix singular": (_frame_field("transform_matrix", [[0.0] * 4] * 3 + [[0, 0, 0, 1]]), ValueError, "{path}: frames[1].transform_matrix: its rotation is singular"),
    "matrix scaled": (_frame_field("transform_matrix", [[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), ValueError, "{path}: frames[1].transform_matrix: its rotation is not orthonormal (largest entry of |R^T R - I|: 3; tolerance 0.001)"),
    "matrix mirrored": (_frame_field("transform_matrix", [[-1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), ValueError, "{path}: frames[1].transform_matrix: its rotation is a reflection (determinant -1), not a rotation: the camera would see the scene mirrored"),
    "image read twice": (lambda d: d["frames"][1].__setitem__("file_path", d["frames"][0]["file_path"]), ValueError, "{path}: frames[1] reads {root}/train/r_000.png, which transforms_train.json frames[0] reads too; each view needs its own image"),
    "time a string": (_frame_field("time", "0.5"), TypeError, "{path}: frames[1].time must be a finite number, got '0.5'"),
    "time above 1": (_frame_field("time", 1.5), ValueError, "{path}: frames[1].time = 1.5 is outside [0, 1]"),
    "time negative": (_frame_field("time", -0.1), ValueError, "{path}: frames[1].time = -0.1 is outside [0, 1]"),
    "time missing": (lambda d: d["frames"][1].pop("time"), KeyError, "{path}: missing key 'time' in frames[1] (found ['file_path', 'rotation', 'transform_matrix'])"),
}  # fmt: skip


def test_dnerf_file_errors_name_the_file(tmp_path):
    from moegs.data.dnerf import load_dnerf

    root, path = _dnerf(tmp_path, lambda d: None)
    path.write_text("{broken")
    with pytest.raises(ValueError) as err:
        load_dnerf(root)
    assert str(err.value).startswith(
        f"D-NeRF train split (expected transforms_train.json in {root}): {path} is not valid JSON"
    )
    (root / "transforms_train.json").unlink()
    with pytest.raises(FileNotFoundError, match=re.escape(f"D-NeRF scene: expected {path}")):
        load_dnerf(root)


def _zero_focal(d):
    d["k"][1][0] = [[0.0, 0.0, 16.0], [0.0, 21.0, 9.0], [0.0, 0.0, 1.0]]


def _bad_k_shape(d):
    d["k"][0][0] = [[1.0, 0.0], [0.0, 1.0]]


PANOPTIC = {
    "missing w2c": (lambda d: d.pop("w2c"), KeyError, "{path}: missing key 'w2c' (found ['cam_id', 'fn', 'h', 'k', 'w'])"),
    "k time steps": (lambda d: d["k"].pop(), ValueError, "{path}: 'k' has 1 time steps but 'fn' has 2"),
    "cameras per step": (lambda d: d["fn"][0].pop(), ValueError, "{path}: time step 0 has 4 k, 4 w2c, 3 fn, 4 cam_id entries"),
    "zero focal": (_zero_focal, ValueError, "{path}: time step 1, camera 1: Camera 'cam01/000001' needs positive focal lengths, got fx=0.0, fy=21.0"),
    "K of wrong shape": (_bad_k_shape, ValueError, "{path}: time step 0, camera 1: Camera.K must have shape [3, 3], got [2, 2]"),
}  # fmt: skip


def _camera_field(field: str, value):
    """Sets ``field`` of a HyperNeRF camera file, or removes it when ``value`` is ``KeyError``."""
    return (lambda d: d.pop(field)) if value is KeyError else _set(field, value)


HYPERNERF = {
    "focal a string": (_camera_field("focal_length", "long"), TypeError, "{path}: 'focal_length' must be a finite number, got 'long'"),
    "focal zero": (_camera_field("focal_length", 0.0), ValueError, "{path}: Camera '0_00000' needs positive focal lengths, got fx=0.0, fy=0.0"),
    "focal missing": (_camera_field("focal_length", KeyError), KeyError, "{path}: missing key 'focal_length' (found ['image_size', 'orientation', 'pixel_aspect_ratio', 'position', 'principal_point', 'radial_distortion', 'skew', 'tangential_distortion'])"),
    "orientation 2x2": (_camera_field("orientation", [[1, 0], [0, 1]]), ValueError, "{path}: 'orientation' must be 3x3, got [2, 2]"),
    "position text": (_camera_field("position", "origin"), TypeError, "{path}: 'position' must be a 3 array of numbers"),
    "image_size of 3": (_camera_field("image_size", [64, 40, 3]), ValueError, "{path}: 'image_size' must be 2, got [3]"),
    "aspect ratio text": (_camera_field("pixel_aspect_ratio", "square"), TypeError, "{path}: 'pixel_aspect_ratio' must be a finite number, got 'square'"),
    "distortion text": (_camera_field("radial_distortion", "none"), TypeError, "{path}: 'radial_distortion' must be a list of numbers, got 'none'"),
    "skew null": (_camera_field("skew", None), TypeError, "{path}: 'skew' must be a finite number, got None"),
}  # fmt: skip


LOADER_FILES = {  # dataset: (module:loader in moegs.data, writes the fixture scene, the JSON file a case edits, the cases)
    "dnerf": ("dnerf:load_dnerf", fx.write_dnerf, "transforms_train.json", DNERF),
    "panoptic": (
        "panoptic:load_panoptic",
        lambda root: fx.write_panoptic(root, frames=2),
        "train_meta.json",
        PANOPTIC,
    ),
    "hypernerf": ("hypernerf:load_hypernerf", fx.write_hypernerf, "camera/0_00000.json", HYPERNERF),
}
LOADER_CASES = [(dataset, case) for dataset, files in LOADER_FILES.items() for case in sorted(files[3])]


@pytest.mark.parametrize(("dataset", "case"), LOADER_CASES, ids=[f"{d}: {c}" for d, c in LOADER_CASES])
def test_loader_json_fields_are_checked(dataset, case, tmp_path):
    loader, write, name, cases = LOADER_FILES[dataset]
    module, function = loader.split(":")
    load = getattr(importlib.import_module(f"moegs.data.{module}"), function)
    change, error, message = cases[case]
    root, path = _edited(tmp_path, write, name, change)
    text = _error_text(lambda: load(root), error)
    assert text == message.format(path=path, root=root), text


# -- 4. checkpoint files ----------------------------------------------------------------------------
def _checkpoint(tmp_path: Path) -> Path:
    from moegs.io import save_checkpoint

    return save_checkpoint(tmp_path / "c.safetensors", {"format": 1, "w": torch.ones(3)})


CHECKPOINTS = {
    "missing": (lambda p: p.unlink(), FileNotFoundError, "checkpoint {path} does not exist"),
    "empty": (lambda p: p.write_bytes(b""), "IntegrityError", "{path}: not a readable safetensors file ("),
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[:-5]), "IntegrityError", "{path}: not a readable safetensors file ("),
    "a bit flipped": (lambda p: p.write_bytes(p.read_bytes()[:-1] + bytes([p.read_bytes()[-1] ^ 1])), "IntegrityError", "{path}: its content does not match the digest written with it (changed or damaged after it was written); train again, or delete the file to start that run over"),
    "random bytes": (lambda p: p.write_bytes(bytes(range(256)) * 4), "IntegrityError", "{path}: not a readable safetensors file ("),
    "text file": (lambda p: p.write_text("hello"), "IntegrityError", "{path}: not a readable safetensors file ("),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CHECKPOINTS))
def test_damaged_checkpoints_name_the_file(case, tmp_path):
    from moegs.errors import IntegrityError
    from moegs.io import load_checkpoint

    damage, error, message = CHECKPOINTS[case]
    path = _checkpoint(tmp_path)
    damage(path)
    with pytest.raises(IntegrityError if error == "IntegrityError" else error) as err:
        load_checkpoint(path)
    assert str(err.value).startswith(message.format(path=path)), str(err.value)


def test_foreign_safetensors_and_bad_metadata_are_named(tmp_path):
    from safetensors.torch import save_file

    from moegs.errors import IntegrityError
    from moegs.io import load_checkpoint

    path = tmp_path / "foreign.safetensors"
    save_file({"w": torch.ones(2)}, str(path))
    with pytest.raises(IntegrityError) as err:
        load_checkpoint(path)
    assert str(err.value) == f"{path}: a safetensors file but not a moegs checkpoint (no 'moegs' metadata)"
    save_file({"w": torch.ones(2)}, str(path), metadata={"moegs": "{not json"})
    with pytest.raises(IntegrityError) as err:
        load_checkpoint(path)
    assert str(err.value).startswith(f"{path}: damaged checkpoint metadata (Expecting property name")


def test_checkpoint_format_is_checked(tmp_path):
    from moegs.io import save_checkpoint
    from moegs.train.checkpoint import read_checkpoint

    path = save_checkpoint(tmp_path / "c.safetensors", {"format": 999})
    with pytest.raises(ValueError) as err:
        read_checkpoint(path)
    assert str(err.value).startswith(f"{path}: checkpoint format 999, this moegs reads ")


# -- 5. the bench's cache ---------------------------------------------------------------------------
def _bench_task():
    from bench.tasks import Task

    return Task(
        action="eval",
        kind="expert",
        params={"expert": "static"},
        scene="dnerf:mutant",
        scene_kwargs={},
        preset="tiny",
        seed=0,
    )


def _result(task) -> dict:
    from bench.results import SCHEMA

    return {"schema": SCHEMA, "status": "ok", "key": task.key, "task": task.to_dict(),
            "metrics": {"psnr": 30.0}, "versions": {}, "timings": {}}  # fmt: skip


def _rewrite(change):
    def damage(path: Path) -> None:
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data))

    return damage


RESULTS = {
    "not JSON": (lambda p: p.write_text("{not json"), "{path}: not valid JSON (Expecting property name"),
    "a list": (lambda p: p.write_text("[1, 2]"), "{path}: expected a JSON object, got list"),
    "no hash": (_rewrite(lambda d: d.pop("content_sha256")), "{path}: missing field(s) ['content_sha256']"),
    "edited number": (_rewrite(lambda d: d["metrics"].update(psnr=99.0)), "{path}: content does not match its content_sha256 (edited or damaged)"),
    "edited status": (_rewrite(lambda d: d.update(status="ok ")), "{path}: status must be 'ok' or 'failed', got 'ok '"),
    "other schema": (_rewrite(lambda d: d.update(schema="x")), "{path}: schema 'x', expected 'moegs.bench.result/1'"),
    "metrics a list": (_rewrite(lambda d: d.update(metrics=[1])), "{path}: 'metrics' must be an object"),
    "other key": (_rewrite(lambda d: d.update(key="abc")), "{path}: key 'abc' does not match the file name"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(RESULTS))
def test_bench_results_from_disk_are_checked(case, tmp_path):
    from bench.results import ResultError, load_valid, write_result
    from bench.store import Workspace

    task = _bench_task()
    path = Workspace(tmp_path).result_path(task)
    write_result(path, _result(task))
    RESULTS[case][0](path)
    with pytest.raises(ResultError) as err:
        load_valid(path, task)
    assert str(err.value).startswith(RESULTS[case][1].format(path=path)), str(err.value)


def _artefact(tmp_path: Path):
    from bench.store import Workspace

    ws, task = Workspace(tmp_path), _bench_task()
    task = type(task)(**{**task.to_dict(), "action": "build"})
    ws.ensure(task, lambda out: (out / "checkpoint.bin").write_bytes(b"weights") and {})
    return ws, task, ws.artifact_dir(task)


ARTEFACTS = {
    "flipped byte": (lambda d: (d / "checkpoint.bin").write_bytes(b"weightS"), "{dir}/checkpoint.bin: sha256 "),
    "deleted file": (lambda d: (d / "checkpoint.bin").unlink(), "{dir}/checkpoint.bin: missing (recorded in {dir}/artifact.json)"),
    "no hashes": (_rewrite(lambda m: m.pop("files")), "artefact {dir}: artifact.json records no file hashes"),
    "unreadable meta": (lambda d: (d / "artifact.json").write_text("{"), "artefact {dir}: unreadable artifact.json ("),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(ARTEFACTS))
def test_bench_artefacts_are_verified(case, tmp_path):
    from bench.store import ArtifactError, Workspace

    _, task, folder = _artefact(tmp_path)
    damage, message = ARTEFACTS[case]
    damage(folder / "artifact.json" if case == "no hashes" else folder)
    with pytest.raises(ArtifactError) as err:
        Workspace(tmp_path).verify(task)
    assert str(err.value).startswith(message.format(dir=folder)), str(err.value)


# -- 6. rasterizer inputs ---------------------------------------------------------------------------
def _frame(n: int = 4, **change) -> GaussianFrame:
    fields = {
        "means": torch.zeros(n, 3),
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        "scales": torch.full((n, 3), 0.1),
        "opacities": torch.full((n,), 0.5),
        "colors": torch.rand(n, 3),
    }
    return GaussianFrame(**{**fields, **change})


def _camera(**change) -> Camera:
    fields = {
        "K": intrinsics(20.0, 20.0, 8.0, 8.0),
        "world_to_camera": look_at(torch.tensor([0.0, -3.0, 0.0]), torch.zeros(3)),
        "width": 16,
        "height": 16,
    }
    return Camera(**{**fields, **change})


def _half_frame() -> GaussianFrame:
    f = _frame()
    return GaussianFrame(f.means.half(), f.quats.half(), f.scales.half(), f.opacities.half(), f.colors.half())


def _with(**change):
    return lambda: rasterize(_frame(**change), _camera())


RASTERIZE = {
    "opacity above 1": (_with(opacities=torch.full((4,), 1.5)), ValueError, "frame: opacities must be in [0, 1]"),
    "opacity negative": (_with(opacities=torch.full((4,), -0.1)), ValueError, "frame: opacities must be in [0, 1]"),
    "zero quaternion": (_with(quats=torch.zeros(4, 4)), ValueError, "frame: quats must have a non-zero norm"),
    "float16": (lambda: rasterize(_half_frame(), _camera()), ValueError, "frame.means must be float32 or float64, got torch.float16"),
    "int64 means": (_with(means=torch.zeros(4, 3, dtype=torch.int64)), ValueError, "frame.means must be float32 or float64, got torch.int64"),
    "mixed dtypes": (_with(colors=torch.rand(4, 3, dtype=torch.float64)), ValueError, "frame.colors is torch.float64 but means are torch.float32; use one dtype"),
    "NaN means": (_with(means=torch.full((4, 3), math.nan)), FloatingPointError, "frame.means contains NaN or Inf"),
    "Inf scales": (_with(scales=torch.full((4, 3), math.inf)), FloatingPointError, "frame.scales contains NaN or Inf"),
    "background shape": (lambda: rasterize(_frame(), _camera(), background=torch.zeros(4)), ValueError, "background must have shape [3], got [4]"),
    "background NaN": (lambda: rasterize(_frame(), _camera(), background=torch.full((3,), math.nan)), FloatingPointError, "background contains NaN or Inf"),
    "background a list": (lambda: rasterize(_frame(), _camera(), background=[1, 1, 1]), TypeError, "background must be a tensor of shape [3], got list"),
    "not a frame": (lambda: rasterize("frame", _camera()), TypeError, "frame must be a GaussianFrame, got str"),
    "not a camera": (lambda: rasterize(_frame(), "camera"), TypeError, "camera must be a moegs.Camera, got str"),
    "sh degree of a colour frame": (lambda: rasterize(_frame(), _camera(), sh_degree=1), ValueError, "sh_degree=1 was given but the frame has `colors`, not `sh`"),
    "unknown backend": (lambda: rasterize(_frame(), _camera(), backend="vulkan"), ValueError, "unknown backend 'vulkan'"),
}  # fmt: skip

FRAMES = {
    "means [N, 2]": (dict(means=torch.zeros(4, 2)), "GaussianFrame.means must have shape [4, 3], got [4, 2]"),
    "quats [N, 3]": (dict(quats=torch.zeros(4, 3)), "GaussianFrame.quats must have shape [4, 4], got [4, 3]"),
    "scales [N]": (dict(scales=torch.zeros(4)), "GaussianFrame.scales must have shape [4, 3], got [4]"),
    "opacities [N, 1]": (dict(opacities=torch.zeros(4, 1)), "GaussianFrame.opacities must have shape [4], got [4, 1]"),
    "colors and sh": (dict(sh=torch.zeros(4, 1, 3)), "GaussianFrame needs exactly one of `colors` [N, D] or `sh` [N, B, C]"),
    "neither colors nor sh": (dict(colors=None), "GaussianFrame needs exactly one of `colors` [N, D] or `sh` [N, B, C]"),
    "sh with 5 bases": (dict(colors=None, sh=torch.zeros(4, 5, 3)), "GaussianFrame.sh has 5 bases; expected 1, 4, 9 or 16 (degree 0-3)"),
    "colors of other N": (dict(colors=torch.zeros(3, 3)), "GaussianFrame.colors must have shape [4, D], got [3, 3]"),
}  # fmt: skip

CAMERAS = {
    "zero focal": (dict(K=intrinsics(0.0, 20.0, 8.0, 8.0)), "Camera '' needs positive focal lengths, got fx=0.0, fy=20.0"),
    "negative focal": (dict(K=intrinsics(20.0, -20.0, 8.0, 8.0)), "Camera '' needs positive focal lengths, got fx=20.0, fy=-20.0"),
    "singular rotation": (dict(world_to_camera=torch.diag(torch.tensor([1.0, 0.0, 1.0, 1.0]))), "Camera '': its world_to_camera rotation is singular"),
    "sheared rotation": (dict(world_to_camera=torch.tensor([[1.0, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])), "Camera '': its world_to_camera rotation is not orthonormal (largest entry of |R^T R - I|: 0.5; tolerance 0.001)"),
    "K 2x2": (dict(K=torch.eye(2)), "Camera.K must have shape [3, 3], got [2, 2]"),
    "w2c 3x4": (dict(world_to_camera=torch.zeros(3, 4)), "Camera.world_to_camera must have shape [4, 4], got [3, 4]"),
    "zero width": (dict(width=0), "Camera size must be positive, got 0x16"),
    "near beyond far": (dict(near=5.0, far=1.0), "Camera needs 0 < near < far, got near=5.0, far=1.0"),
    "NaN in K": (dict(K=torch.full((3, 3), math.nan)), "Camera '' has non-finite intrinsics or extrinsics"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(RASTERIZE))
def test_rasterize_checks_its_inputs(case):
    call, error, message = RASTERIZE[case]
    with pytest.raises(error) as err:
        call()
    assert str(err.value).startswith(message), str(err.value)


@pytest.mark.parametrize("case", sorted(FRAMES))
def test_gaussian_frame_checks_shapes(case):
    with pytest.raises(ValueError) as err:
        _frame(**FRAMES[case][0])
    assert str(err.value) == FRAMES[case][1]


@pytest.mark.parametrize("case", sorted(CAMERAS))
def test_camera_checks_geometry(case):
    with pytest.raises(ValueError) as err:
        _camera(**CAMERAS[case][0])
    assert str(err.value) == CAMERAS[case][1]


def test_the_table_has_at_least_100_cases():
    tables = [
        ARGUMENTS,
        BROKEN_RUNS,
        COMMANDS,
        SMALL,
        DNERF,
        PANOPTIC,
        HYPERNERF,
        CHECKPOINTS,
        RESULTS,
        ARTEFACTS,
    ]
    tables += [RASTERIZE, FRAMES, CAMERAS]
    assert sum(map(len, tables)) >= 100
