# ruff: noqa: E501  (one case per line: the tables read as tables)
"""``--set`` values are parsed by their config field's type (``moegs.overrides``), and the checks of
``moegs.guards`` (image sizes the metrics can score, one writer per run folder, duplicates) name what is
wrong. The command-line cases are in tests/test_bad_inputs.py."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

from moegs.experts import list_experts
from moegs.overrides import typed_overrides, with_flags
from moegs.recipes import config_for

SCENE = "synthetic:dnerf_like"


def _config(expert: str):
    return config_for(expert, SCENE, "quick").config


def _leaves(config, prefix=""):
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            yield from _leaves(value, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", value



@pytest.mark.parametrize(
    "expert",
    [s.name for s in list_experts()],
)
def test_every_default_value_reads_back_as_itself(expert):
    """Each field of each expert's quick config, written as JSON, parses back to its value and type: the
    checks refuse nothing a recipe holds."""
    config = _config(expert)
    for field, value in _leaves(config):
        text = json.dumps(list(value) if isinstance(value, tuple) else value)
        parsed = typed_overrides(config, {field: text})[field]
        assert parsed == value and type(parsed) is type(value), (field, text, parsed)


PARSED = [  # (expert, field, text, value)
    ("static", "train.iterations", "1e3", 1000),
    ("static", "train.iterations", "10_000", 10000),
    ("static", "train.lambda_dssim", "1", 1.0),
    ("static", "train.max_eval_views", "null", None),
    ("static", "train.max_eval_views", "3", 3),
    ("static", "train.resolution_scale", "0.5", 0.5),
    ("static", "train.backend", "torch", "torch"),
    ("static", "train.backend", '"torch"', "torch"),
    ("static", "strategy.reset_at_densify_from_if_white", "false", False),
    ("grid4d", "spatial_perturb", "[0.1, 0.2, 0.3]", (0.1, 0.2, 0.3)),
    ("grid4d", "spatial_perturb", "0.1,0.2,0.3", (0.1, 0.2, 0.3)),
    ("fourdgs", "multires", "[1, 2, 4]", (1, 2, 4)),
    ("ed3dgs", "deform", "means,quats", ("means", "quats")),
    ("ex4dgs", "random_background", "true", True),
    ("ex4dgs", "random_background", "null", None),
]


@pytest.mark.parametrize(("expert", "field", "text", "value"), PARSED)
def test_set_values_are_parsed_by_their_field_type(expert, field, text, value):
    parsed = typed_overrides(_config(expert), {field: text})[field]
    assert parsed == value and type(parsed) is type(value)


REFUSED = [  # (expert, field, text, message)
    ("static", "train.batch_size", "true", "--set train.batch_size=true: train.batch_size expects an int, got true"),
    ("static", "train.iterations", "abc", "--set train.iterations=abc: train.iterations expects an int, got abc"),
    ("static", "train.iterations", "2.5", "--set train.iterations=2.5: train.iterations expects an int, got 2.5"),
    ("static", "train.iterations", "0", "--set train.iterations=0: train.iterations expects a positive int, got 0"),
    ("static", "train.lambda_dssim", "nan", "--set train.lambda_dssim=nan: train.lambda_dssim expects a finite number, got nan"),
    ("static", "train.max_eval_views", "all", "--set train.max_eval_views=all: train.max_eval_views expects an int or null, got all"),
    ("static", "train.seed", "-1", "--set train.seed=-1: train.seed expects an int seed in [0, 2**63), got -1"),
    ("static", "train.resolution_scale", "2", "--set train.resolution_scale=2: train.resolution_scale expects a scale in (0, 1], got 2"),
    ("static", "train.eval_every", "-1", "--set train.eval_every=-1: train.eval_every expects an int >= 0 (0: never), got -1"),
    ("static", "strategy.densify_every", "0", "--set strategy.densify_every=0: strategy.densify_every expects a positive int, got 0"),
    ("static", "strategy.reset_at_densify_from_if_white", "yes", "--set strategy.reset_at_densify_from_if_white=yes: strategy.reset_at_densify_from_if_white expects true or false, got yes"),
    ("grid4d", "spatial_perturb", "[0.1, 0.2]", "--set spatial_perturb=[0.1, 0.2]: spatial_perturb expects 3 finite numbers (e.g. [1, 1, 1] or 1,1,1), got [0.1, 0.2]"),
    ("fourdgs", "multires", "[1, x]", "--set multires=[1, x]: multires expects a list of ints (e.g. [1, 2] or 1,2), got [1, x]"),
]  # fmt: skip


@pytest.mark.parametrize(("expert", "field", "text", "message"), REFUSED)
def test_bad_set_values_name_the_field_value_and_type(expert, field, text, message):
    with pytest.raises(ValueError) as err:
        typed_overrides(_config(expert), {field: text})
    assert str(err.value) == message


def test_unknown_fields_and_groups_are_named():
    config = _config("static")
    with pytest.raises(
        KeyError, match=r"TrainConfig has no field 'nosuch' \(in 'train.nosuch'\); fields: \["
    ):
        typed_overrides(config, {"train.nosuch": "1"})
    with pytest.raises(
        KeyError, match=r"'train' is a group of fields; set one of them, e.g. train.iterations="
    ):
        typed_overrides(config, {"train": "1"})
    with pytest.raises(
        KeyError, match=r"train.iterations is not a group of fields; cannot set 'train.iterations.x'"
    ):
        typed_overrides(config, {"train.iterations.x": "1"})


def test_a_flag_and_a_set_of_one_field_must_agree():
    texts = {"train.seed": "5"}
    given = typed_overrides(_config("static"), texts)
    with pytest.raises(ValueError, match=r"^--seed 1 and --set train.seed=5 disagree; give one of them$"):
        with_flags(given, texts, {"--seed": 1})
    assert with_flags(given, texts, {"--seed": 5, "--iterations": None}) == {"train.seed": 5}
    assert with_flags({}, {}, {"--seed": None, "--iterations": 7}) == {"train.iterations": 7}


def test_smallest_scale_reaches_the_metrics_minimum():
    from moegs.guards import min_image_size, smallest_scale

    assert min_image_size() == 31  # LPIPS-Alex: conv 11/4 then two 3/2 max-pools need 31 px (SSIM: 11)
    for native, scale in ((100, 0.1), (800, 0.01), (360, 0.05), (1014, 0.02)):
        lowest = smallest_scale(round(native * scale), scale, native)
        assert native * lowest >= 31 > native * (lowest - 0.001)  # 31 px however the loader rounds


def test_lpips_alex_needs_31_pixels():
    """The minimum ``moegs.guards`` enforces is the network's: a 30 px image cannot pass AlexNet's layers."""
    import torch
    import torch.nn.functional as F

    from moegs.metrics.lpips import _ALEX_SLICES, MIN_SIZE

    def passes(side: int) -> bool:
        h = torch.zeros(1, 3, side, side)
        try:
            for _, out, k, stride, pad, pool in _ALEX_SLICES:
                h = F.max_pool2d(h, 3, 2) if pool else h
                h = F.conv2d(h, torch.zeros(out, h.shape[1], k, k), stride=stride, padding=pad)
        except RuntimeError:
            return False
        return True

    assert MIN_SIZE == 31 and passes(31) and not passes(30)


HOLD = "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDONLY); fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)"  # noqa: E501


def test_a_folder_held_by_another_process_is_refused_and_released_on_exit(tmp_path):
    from moegs.guards import FolderInUse, folder_lock

    folder = tmp_path / "run"
    folder.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FolderInUse) as err, folder_lock(folder):
            pass
        assert str(err.value) == (
            f"{folder} is in use by another moegs command (it holds the folder's lock); wait for it to end "
            "or choose another --out"
        )
    finally:
        holder.kill()
        holder.wait()
    with folder_lock(folder):  # the kernel dropped the killed holder's lock
        pass
    assert sorted(folder.iterdir()) == []  # no lock file: the folder holds what the run wrote


def test_a_lock_leaves_no_folder_behind_when_nothing_was_written(tmp_path):
    from moegs.guards import folder_lock

    with folder_lock(tmp_path / "new" / "run"):
        assert (tmp_path / "new" / "run").is_dir()
    assert not (tmp_path / "new" / "run").exists()
    with folder_lock(tmp_path / "kept") as folder:
        (folder / "a.txt").write_text("x")
    assert (tmp_path / "kept" / "a.txt").is_file()


def test_duplicates_are_named():
    from moegs.guards import check_distinct

    check_distinct(["a", "b"], "--experts")
    with pytest.raises(
        ValueError, match=r"^--experts names 'a', 'b' more than once \(a duplicate\); give each once$"
    ):
        check_distinct(["a", "b", "a", "b", "a"], "--experts")
