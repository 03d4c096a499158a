"""``python -m bench.convergence``: quick schedules scaled to N, cached cells, figure and table."""

from __future__ import annotations

import json

import pytest

from bench import convergence
from bench.report import convergence_markdown
from moegs.experts.static import QUICK_ITERATIONS
from moegs.recipes import config_for
from moegs.train.strategy import NEVER

SCENE = "dnerf:mutant"
KEPT = ("strategy.densify_every", "strategy.prune_every")
"""Iteration-valued quick fields that are intervals and keep their quick value (see the module docstring)."""


def test_quick_length_matches_the_library():
    assert convergence.QUICK_ITERATIONS == QUICK_ITERATIONS


@pytest.mark.parametrize("expert", sorted(convergence.SCHEDULE_FIELDS))
def test_scaling_is_the_identity_at_the_quick_length_and_linear_beyond(expert):
    quick = config_for(expert, SCENE, "quick").reductions
    same = convergence.scaled_overrides(expert, SCENE, QUICK_ITERATIONS)
    assert all(quick[k] == v for k, v in same.items())
    five = convergence.scaled_overrides(expert, SCENE, 5 * QUICK_ITERATIONS)
    assert five["train.iterations"] == 3000
    for key in convergence.SCHEDULE_FIELDS[expert]:
        assert five[key] == (quick[key] if quick[key] >= NEVER else 5 * quick[key]), key
    scaled = config_for(expert, SCENE, "quick", overrides=five).config
    assert scaled.strategy.densify_every == config_for(expert, SCENE, "quick").config.strategy.densify_every


@pytest.mark.parametrize("expert", sorted(convergence.SCHEDULE_FIELDS))
def test_no_schedule_field_of_the_quick_reduction_is_forgotten(expert):
    quick = config_for(expert, SCENE, "quick").reductions
    words = ("steps", "warm_up", "_from", "_until", "reset_every", "_every", "iterations", "_at")
    schedule_like = {k for k in quick if any(w in k for w in words) and k != "train.iterations"}
    assert schedule_like == set(convergence.SCHEDULE_FIELDS[expert]) | (schedule_like & set(KEPT))


def test_unknown_expert_names_the_table():
    with pytest.raises(ValueError, match="no schedule table for expert 'stg'.*deformable"):
        convergence.scaled_overrides("stg", SCENE, 600)


@pytest.mark.realdata
@pytest.mark.slow
def test_study_runs_caches_and_draws(tmp_path, mutant_root, monkeypatch):
    out = tmp_path / "reports" / "convergence"
    readme = tmp_path / "README.md"
    readme.write_text("# x\n<!-- results:convergence -->\nold\n<!-- /results:convergence -->\n")
    args = ["--scene", SCENE, "--experts", "static", "--iterations", "10,20", "--resolutions", "0.0625",
            "--workspace", str(tmp_path / "ws"), "--out", str(out), "--no-progress",
            "--readme", str(readme)]  # fmt: skip
    assert convergence.main(args) == 0
    summary = json.loads((out / "dnerf_mutant.json").read_text())
    cells = summary["cells"]
    assert [c["iterations"] for c in cells] == [10, 20]
    for c in cells:
        assert c["image_size"] == [50, 50] and c["native_size"] == [800, 800] and c["test_views"] == 20
        assert c["psnr"] > 10 and c["psnr_dynamic"] is not None and c["psnr_native"] > 10
        assert c["recipe"]["overrides"]["train.iterations"] == c["iterations"]
    assert (out / "dnerf_mutant.png").stat().st_size > 10_000
    assert "| static | 0.0625 (50x50) | 10 |" in (out / "dnerf_mutant.md").read_text()

    written = readme.read_text()
    assert (
        "old" not in written
        and "![convergence on dnerf:mutant](reports/convergence/dnerf_mutant.png)" in written
    )
    assert "| static | 0.0625 (50x50) | 20 |" in written and "python -m bench.convergence --scene" in written
    section = "\n".join(convergence_markdown(tmp_path / "reports"))
    assert "![dnerf_mutant](convergence/dnerf_mutant.png)" in section and "| static | 0.0625" in section

    def no_training(*args, **kwargs):
        raise AssertionError("a cached cell was recomputed")

    monkeypatch.setattr(convergence, "run_cell", no_training)
    assert convergence.main(args) == 0  # resumes from the cache


def test_cli_rejects_an_expert_without_a_schedule_table(capsys):
    with pytest.raises(SystemExit) as err:
        convergence.main(["--experts", "stg", "--workspace", "/nonexistent"])
    assert err.value.code == 2 and "no schedule table for expert 'stg'" in capsys.readouterr().err
