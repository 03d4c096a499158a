"""Per-dataset expert configs: STG† (SH colours, Ex4DGS rasteriser) in every N3V cell, the original
STG elsewhere, and experts without a dataset config shared between the tables of both datasets."""

from __future__ import annotations

from dataclasses import replace

from bench.cells import expert as expert_kind
from bench.datasets import get_dataset
from bench.plan import make_plan
from bench.presets import get_preset


def expert_builds(tables):
    plan = make_plan(tables, get_preset("quick"))
    return [t for level in plan.build_levels() for t in level if t.kind == "expert"]


def test_stg_dagger_on_n3v_only(monkeypatch):
    monkeypatch.setenv("MOEGS_DATA", "/nonexistent")  # both datasets on their synthetic stand-in
    n3v = {t.params["expert"]: t for t in expert_builds(["tab06"])}  # volume router needs RGB experts
    technicolor = {t.params["expert"]: t for t in expert_builds(["tab04"])}
    assert dict(n3v["stg"].params["config"]) == get_dataset("n3v").expert_config["stg"]
    assert "config" not in technicolor["stg"].params and n3v["stg"].key != technicolor["stg"].key
    assert n3v["ed3dgs"].key == technicolor["ed3dgs"].key  # one shared run


def test_build_config_applies_the_dataset_fields():
    from moegs.experts import get_expert_class

    class Ctx:
        preset = get_preset("quick")

    stg = get_expert_class("stg")
    task = next(t for t in expert_builds(["tab06"]) if t.params["expert"] == "stg")
    cfg = expert_kind.train_config(stg, Ctx, task)
    assert cfg.color == "sh" and cfg.antialiased and cfg.train.seed == task.seed
    plain = expert_kind.train_config(stg, Ctx, replace(task, params={"expert": "stg"}))
    assert plain.color == "full"
