"""``python -m bench.status``: the README's status section, read from the committed summaries only."""

from __future__ import annotations

import json
from pathlib import Path

from bench.readme import split_section
from bench.status import (
    QUICK,
    STANDARD,
    claim_counts,
    claims_cell,
    main,
    motion_rows,
    real_scene_rows,
    routing_cell,
    section,
    wall_clock_cell,
)
from moegs.io import read_json

REPO = Path(__file__).resolve().parents[2]


def _summary(claims, experts=(), routing=(), values=(), minutes=1.0):
    return {
        "header": {"git": {"commit": "abcdef0123"}, "moegs_code_version": "0123456789abcdef"},
        "specs": [{"id": "tab17", "claims": [{"ours": c} for c in claims], "values": list(values)}],
        "experts": list(experts),
        "routing": list(routing),
        "compute": {"minutes": minutes},
    }


def _expert(name, dynamic, r2=0.5):
    return {
        "scene": "synthetic:n3v_like",
        "dataset": "n3v",
        "expert": name,
        "psnr": {"dynamic": dynamic},
        "motion_r2": r2,
    }


def test_readme_section_is_the_committed_summaries():
    """The README's table says what the committed outputs say: regenerate it when they change."""
    head, _ = split_section(REPO / "README.md", "status")
    body = (REPO / "README.md").read_text().split(head, 1)[1].split("<!-- /results:status -->", 1)[0]
    assert body.strip() == section(read_json(REPO / QUICK), read_json(REPO / STANDARD)).strip()


def test_counts_floors_and_routing():
    quick = _summary(
        ["held", "failed", "within noise", "within noise"],
        experts=[
            {
                **_expert("stg", 26.0, 0.7),
                "psnr_regimes": {"transient": 15.99, "nonrigid": 28.0, "rigid_smooth": 28.97},
            },
            _expert("ed3dgs", 18.0, 0.04),
            _expert("grid4d", 29.0),  # not one of the floor experts, but the best
            {**_expert("stg", 40.0), "dataset": "technicolor"},  # another recipe: not the floors' row
        ],
        routing=[
            {
                "table": "tab03",
                "row": "MoE-GS (N=3)",
                "experts": ["ex4dgs", "stg"],
                "coherence": 0.55,
                "dynamic_share": [0.25, 0.75],
                "static_share": [0.9, 0.1],
            }
        ],
    )
    assert claim_counts(quick) == {"held": 1, "failed": 1, "within noise": 2}
    assert claims_cell(quick, "sanity") == "none"  # a run without such claims
    quick["specs"][0]["claims"] += [
        {"ours": "held", "kind": "sanity"},
        {"ours": "within noise", "ours_leans": "against the paper", "kind": "suite"},
    ]
    assert claims_cell(quick) == "1 held, 1 failed, 2 within noise (0 against the paper) (of 4)"
    assert claims_cell(quick, "sanity") == "1 held (of 1)"
    assert claims_cell(quick, "suite") == "1 within noise (1 against the paper) (of 1)"
    rows = motion_rows(quick)
    assert rows == [
        "| Grid4D | 29.00 | 0.50 | – | – |",
        "| STG | 26.00 | 0.70 | ≥ 25: met | rigid_smooth 29.0, nonrigid 28.0, transient 16.0 |",
        "| E-D3DGS | 18.00 | 0.04 | ≥ 25: missed | – |",
        "| best | 29.00 | | ≥ 28: met | |",
    ]
    at_the_floors = motion_rows(
        _summary([], experts=[_expert("ex4dgs", 25.0, 0.5), _expert("stg", 28.0, 0.5)])
    )
    assert at_the_floors == [
        "| STG | 28.00 | 0.50 | ≥ 25: met | – |",
        "| Ex4DGS | 25.00 | 0.50 | ≥ 25: met | – |",  # a floor is reached at its value
        "| best | 28.00 | | ≥ 28: met | |",
    ]
    cell = routing_cell(quick)
    assert "coherence 0.55 (≥ 0.6: missed)" in cell and "STG 75% / 10%" in cell
    assert routing_cell(_summary([])) == "not in this run"


def test_wall_clock_is_the_recorded_run_that_computed_the_cells():
    run = {
        "seconds": 2682.0,
        "jobs": 2,
        "executor": "local",
        "machine": "Intel Xeon, 2 logical CPUs",
        "failures": 0,
    }
    cold = {**run, "builds_run": 89, "evals_run": 97, "builds_reused": 0, "evals_reused": 0}
    warm = {**run, "seconds": 21.0, "builds_run": 0, "evals_run": 0, "builds_reused": 89, "evals_reused": 97}
    summary = _summary([])
    assert wall_clock_cell(summary) == "not recorded"
    summary["header"]["history"] = [cold, warm]
    assert wall_clock_cell(summary) == "44.7 min cold (2 jobs, 2 CPU threads)"
    summary["header"]["history"] = [warm]
    assert wall_clock_cell(summary) == "not recorded"
    slurm = {**cold, "jobs": None, "executor": "slurm", "builds_reused": 9, "builds_run": 80, "failures": 2}
    summary["header"]["history"] = [cold, slurm, warm]
    assert wall_clock_cell(summary) == "44.7 min resumed (slurm, 2 CPU threads), 2 cells failed"


def test_real_scene_rows_pair_standard_with_quick():
    value = {"row": "Grid4D", "column": "Mutant", "metric": "PSNR", "paper": 43.95}
    dynamic = {**value, "metric": "PSNR dynamic", "ours": 30.0}
    standard = _summary([], values=[{**value, "ours": 38.32}, dynamic])
    quick = _summary([], values=[{**value, "ours": 28.84}])
    row = "| tab17 | Grid4D | Mutant | 43.95 | 38.32 (-5.63) | 28.84 (-15.11) |"
    assert real_scene_rows(standard, quick) == [row]
    # no paper value (a stand-in's cell): not a row
    stand_in = _summary([], values=[{**value, "paper": None, "ours": 30.0}])
    assert real_scene_rows(stand_in, quick) == []


def test_cli_writes_the_section_and_names_bad_files(tmp_path, capsys):
    quick, standard = tmp_path / "quick.json", tmp_path / "standard.json"
    quick.write_text(json.dumps(_summary(["held"], experts=[_expert("stg", 26.0)])))
    standard.write_text(json.dumps(_summary(["within noise"])))
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- results:status -->\nold\n<!-- /results:status -->\noutro\n")
    assert main(["--quick", str(quick), "--standard", str(standard), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert "old" not in text and "1 held (of 1)" in text and "| STG | 26.00 | 0.50 | ≥ 25: met |" in text
    assert text.startswith("intro\n") and text.endswith("outro\n")
    assert main(["--quick", str(tmp_path / "missing.json"), "--standard", str(standard)]) == 2
    assert "missing.json" in capsys.readouterr().err
    standard.write_text(json.dumps({"header": {}}))
    assert main(["--quick", str(quick), "--standard", str(standard)]) == 2
    assert "lacks the field 'specs'" in capsys.readouterr().err
