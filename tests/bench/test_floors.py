"""``bench.floors``: the real-data floors come from the lowest value over seeds and thread counts; cells
already measured are read back, not run again."""

from __future__ import annotations

import json

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
