"""``moegs compare``: every registered expert on Panoptic basketball at the quick preset, one table."""

from __future__ import annotations

import json
import math

import pytest

from moegs.cli import main
from moegs.compare import markdown
from moegs.experts import list_experts


def test_markdown_table_layout():
    rows = [
        {
            "expert": "stg",
            "psnr": 25.123,
            "ssim": 0.81234,
            "lpips": None,
            "train_seconds": 12.34,
            "num_gaussians": 1234,
            "iterations": 600,
        }
    ]
    text = markdown(rows, "x")
    assert "| stg | 25.12 | 0.8123 | n/a | 12.3 | 1234 | 600 |" in text


def test_unknown_expert_fails_before_training(tmp_path, capsys):
    assert (
        main(["compare", "--experts", "nope", "--scene", "panoptic:basketball", "--out", str(tmp_path)]) == 2
    )
    assert "unknown expert 'nope'" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.realdata
def test_all_experts_on_basketball_quick(basketball_root, tmp_path):
    from helpers.training import code_hash

    from moegs.paths import cache_root

    # one folder per library version: compare reuses any finished run in it (moegs.train.reuse)
    out = cache_root() / "tests" / f"compare-panoptic-basketball-quick_{code_hash()}"
    assert (
        main(
            [
                "compare",
                "--experts",
                "all",
                "--scene",
                "panoptic:basketball",
                "--preset",
                "quick",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    table = json.loads((out / "table.json").read_text())
    names = {s.name for s in list_experts() if not s.composite}
    assert {r["expert"] for r in table["rows"]} == names
    assert {"deformable", "grid4d", "fourdgs", "ed3dgs", "stg", "ex4dgs", "mcmc"} <= names
    for row in table["rows"]:
        assert math.isfinite(row["psnr"]) and row["psnr"] > 15.0, row
        assert 0.3 < row["ssim"] <= 1.0 and row["num_gaussians"] > 0, row
        assert row["lpips"] is None or 0.0 <= row["lpips"] < 0.8, row
    assert (out / "table.md").read_text().count("\n| ") == len(names) + 1
    # resumable: a second call skips every finished expert
    assert (
        main(["compare", "--experts", "all", "--scene", "panoptic:basketball", "--out", str(out), "--quiet"])
        == 0
    )
    assert set(json.loads((out / "table.json").read_text())["skipped"]) == names
