"""Every bench build trains with the resolver's recipe (``moegs.recipes.config_for``) of its expert, scene,
dataset and preset: only the bench's run fields (seed, evaluation protocol) and a dataset's MoE-GS
conventions (STG† on N3V and Technicolor) differ."""

from __future__ import annotations

import pytest

from bench.cells._lib import RUN_FIELDS, recipe_of
from bench.cells.mode import recipe as mode_recipe
from bench.datasets import get_dataset
from bench.plan import make_plan
from bench.presets import get_preset
from bench.registry import list_specs
from moegs.recipes import changed_fields, config_for


def builds(tables, preset: str = "quick", kinds=("expert",)):
    plan = make_plan(tables, get_preset(preset))
    return [t for level in plan.build_levels() for t in level if t.kind in kinds]


class Ctx:
    def __init__(self, preset: str) -> None:
        self.preset = get_preset(preset)


def test_stg_dagger_on_n3v_and_technicolor(monkeypatch):
    monkeypatch.setenv("MOEGS_DATA", "/nonexistent")  # both datasets on their synthetic stand-in
    n3v = {t.params["expert"]: t for t in builds(["tab06"])}
    technicolor = {t.params["expert"]: t for t in builds(["tab04"])}
    for tasks, name in ((n3v, "n3v"), (technicolor, "technicolor")):
        assert dict(tasks["stg"].params["config"]) == get_dataset(name).expert_config["stg"]
        recipe = recipe_of(Ctx("quick"), tasks["stg"])
        assert recipe.config.color == "sh" and recipe.config.antialiased
    # MoE-GS's README: STG† on N3V is two 150-frame models (0-149, 150-299), not six 50-frame ones
    assert recipe_of(Ctx("quick"), n3v["stg"]).config.segment_frames == 150
    assert recipe_of(Ctx("quick"), n3v["stg"]).config.optimizer == "adam"  # RAdam unverified for STG†
    # one stand-in, two datasets: each build takes its dataset's recipe (E-D3DGS: N3V vs Technicolor)
    assert n3v["ed3dgs"].key != technicolor["ed3dgs"].key
    assert recipe_of(Ctx("quick"), n3v["ed3dgs"]).base == "paper"
    assert recipe_of(Ctx("quick"), technicolor["ed3dgs"]).base == "paper-technicolor"


@pytest.mark.parametrize("preset", ["paper", "quick"])
def test_every_build_config_is_the_resolvers(preset, monkeypatch):
    """Plan every table at ``preset``; each expert and MoDE build's config equals ``config_for``'s, up to
    the bench's run fields and the dataset's conventions."""
    monkeypatch.setenv("MOEGS_DATA", "/nonexistent")  # every table on its stand-in (no real data needed)
    ctx = Ctx(preset)
    scale = get_preset(preset).expert_preset
    tasks = builds(list_specs(), preset, kinds=("expert", "mode"))
    assert {t.kind for t in tasks} == {"expert", "mode"}
    seen = set()
    for task in tasks:
        if task.kind == "mode":
            recipe = mode_recipe(ctx, task)
            expected = config_for(
                "mode",
                task.scene,
                scale,
                dataset=task.params["dataset"],
                overrides={"experts": tuple(task.params["experts"])},
            )
        else:
            recipe = recipe_of(ctx, task)
            conventions = dict(task.params.get("config", {}))
            expected = config_for(
                task.params["expert"],
                task.scene,
                scale,
                dataset=task.params["dataset"],
                overrides=conventions,
            )
        allowed = set(RUN_FIELDS) | {"train.iterations"} if "budget" in task.params else set(RUN_FIELDS)
        extra = set(changed_fields(recipe.config, expected.config)) - allowed
        assert not extra, f"{task.slug}: fields differ from the resolver's: {sorted(extra)}"
        assert recipe.background == expected.background and recipe.base == expected.base
        seen.add((recipe.expert, recipe.dataset))
    # the paper's expert x dataset pairs are all planned
    assert {
        ("stg", "n3v"),
        ("ed3dgs", "technicolor"),
        ("grid4d", "panoptic"),
        ("deformable", "dnerf"),
    } <= seen
