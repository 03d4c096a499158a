"""``bench.floors``: the real-data floors come from the lowest value over seeds and thread counts; cells
already measured are read back, not run again; every cell trains its own router."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from bench import floors


def test_the_summary_is_the_range_over_every_cell_and_cells_on_disk_are_reused(tmp_path, monkeypatch):
    cells = {
        "s0_t1": {"psnr/grid4d": 28.2, "moe/psnr": 29.0},
        "s1_t1": {"psnr/grid4d": 27.6, "moe/psnr": 29.3},
        "s0_t2": {"psnr/grid4d": 28.0, "moe/psnr": 28.7},
    }
    for name, values in cells.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(values))
    monkeypatch.setattr(floors.subprocess, "run", lambda *a, **k: pytest.fail("a measured cell ran again"))
    got = floors.run_cells([0, 1], [1], tmp_path)
    assert got == {"s0_t1": cells["s0_t1"], "s1_t1": cells["s1_t1"]}
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["psnr/grid4d"]["min"] == 27.6 and summary["psnr/grid4d"]["max"] == 28.2
    assert floors.summarize(cells)["moe/psnr"] == {
        "min": 28.7,
        "max": 29.3,
        "cells": {k: v["moe/psnr"] for k, v in cells.items()},
    }


def test_each_cell_trains_its_own_router(tmp_path, monkeypatch):
    """One seed's experts differ between 1 and 2 threads (Grid4D: 855 vs 856 Gaussians at seed 2): a router
    folder shared by the two cells was resumed over the other cell's experts (and refused them)."""
    import moegs.data
    import moegs.moe
    import moegs.recipes
    import moegs.train.entry

    class Trained(Exception):
        pass

    folders = []

    def train_router(experts, scene, config, out_dir, **kwargs):
        folders.append(out_dir)
        raise Trained  # the router is all this test looks at

    monkeypatch.setattr(moegs.recipes, "config_for", lambda *a, **k: SimpleNamespace(load_kwargs={}))
    monkeypatch.setattr(moegs.data, "load_scene", lambda *a, **k: "scene")
    monkeypatch.setattr(
        moegs.train.entry, "train_recipe", lambda *a, **k: ("expert", {"test": {"psnr": 1.0}})
    )
    monkeypatch.setattr(moegs.moe, "train_router", train_router)
    for threads in (1, 2):
        with pytest.raises(Trained):
            floors.measure_cell(2, threads, tmp_path)
    assert folders == [tmp_path / "router_s2_t1", tmp_path / "router_s2_t2"]
