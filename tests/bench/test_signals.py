"""``bench.signals`` read back from hand-written results: a seed spread is max - min over every seed and
is credited to every table whose cells measured it; the committed summary lends only the quick run's
spreads; the expert and routing rows are of seed 0 at the full budget; a build's minutes count once."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from helpers.cells import write_ok_result

from bench.plan import make_plan
from bench.presets import get_preset
from bench.registry import get_spec
from bench.signals import compute_rows, expert_rows, pruning_rows, routing_rows, run_noise, seed_noise
from bench.store import Workspace

QUICK = get_preset("quick")
STAND_IN = "synthetic:n3v_like"


def test_a_spread_is_max_minus_min_and_every_table_of_the_cells_is_its_source(tmp_path):
    tab09 = get_spec("tab09")  # the N3V stand-in's stability run: three seeds of each row
    plan = make_plan([tab09, replace(tab09, id="tab09_again")], QUICK)  # a second table of the same cells
    ws = Workspace(tmp_path)
    for slot in plan.specs[0].slots:
        write_ok_result(ws, slot.task, psnr=(21.0, 22.0, 21.5)[slot.seed])  # the middle seed is the highest
    (entry,) = seed_noise(plan, ws)["scenes"].values()
    assert entry["metrics"]["PSNR"] == pytest.approx(1.0) and entry["seeds"] == 3
    assert entry["source"] == ["tab09", "tab09_again"]


def test_only_the_quick_runs_spreads_are_borrowed_from_the_committed_summary(tmp_path):
    plan = make_plan(["tab03"], QUICK)  # trains the N3V stand-in once: it borrows a spread
    summary = tmp_path / "summary.json"
    for preset, borrowed in (("standard", False), ("quick", True)):
        entry = {
            "real": False,
            "preset": preset,
            "seeds": 3,
            "source": ["tab09"],
            "rows": {},
            "metrics": {"PSNR": 0.7},
        }
        summary.write_text(
            json.dumps({"header": {"git": {"commit": "abc"}}, "noise": {"scenes": {STAND_IN: entry}}})
        )
        assert (STAND_IN in run_noise(plan, Workspace(tmp_path / "ws"), summary)["scenes"]) is borrowed


def test_expert_rows_are_the_full_budget_cells_whatever_the_column_order(tmp_path):
    tab18 = get_spec("tab18")
    halves_first = replace(
        tab18, id="tab18_reordered", budgets={"50%": 0.5, "100%": 1.0}, columns=("50%", "100%")
    )
    plan = make_plan([halves_first], QUICK)
    ws = Workspace(tmp_path)
    for slot in plan.specs[0].slots:
        if slot.task is not None:
            write_ok_result(ws, slot.task, psnr=30.0 if slot.budget_column == "100%" else 20.0)
    rows = expert_rows(plan, ws)
    assert sorted(r["expert"] for r in rows) == ["ed3dgs", "fourdgs", "stg"]
    assert {r["psnr"]["full"] for r in rows} == {30.0}


def test_routing_rows_are_of_seed_zero(tmp_path):
    plan = make_plan(["tab09"], QUICK)
    ws = Workspace(tmp_path)
    for slot in plan.specs[0].slots:
        routing = {"coherence": 0.1 * (slot.seed + 1), "dynamic_share": {}, "static_share": {}}
        write_ok_result(ws, slot.task, {"details": {"routing": routing}}, psnr=25.0)
    (row,) = routing_rows(plan, ws)
    assert row["table"] == "tab09" and row["row"] == "MoE-GS (N=3)" and row["coherence"] == pytest.approx(0.1)


def test_pruning_rows_stand_beside_the_papers_memory_reduction(tmp_path):
    """Table VII's pruned rows: our share of Gaussians removed; the paper's memory 747 -> 270 MB."""
    from bench.report import pruning_markdown

    plan = make_plan(["tab07"], QUICK)
    ws = Workspace(tmp_path)
    for slot in plan.specs[0].slots:
        details = {}
        if slot.task is not None and slot.task.params.get("prune"):
            details = {
                "pruning": {
                    "when": "training",
                    "before": [60, 40],
                    "after": [30, 20],
                    "removed_fraction": 0.5,
                }
            }
        if slot.task is not None:
            write_ok_result(ws, slot.task, {"details": details}, psnr=25.0)
    rows = pruning_rows(plan, ws)  # every seed Table VII trains at quick
    assert sorted(r["row"] for r in rows) == sorted(
        ["MoE-GS (N=3)", "w/o Single-Pass"] * QUICK.table_seeds["tab07"]
    )
    full = next(r for r in rows if r["row"] == "MoE-GS (N=3)" and r["seed"] == 0)
    assert (full["before"], full["after"], full["removed"]) == (100, 50, 0.5)
    assert full["paper_memory_removed"] == pytest.approx(1 - 270 / 747)
    assert "| tab07 | MoE-GS (N=3) | synthetic:n3v_like | 0 | training | 100 -> 50 | 50.0% | 64% |" in (
        pruning_markdown(rows)
    )


def test_a_build_shared_by_cells_costs_its_minutes_once(tmp_path):
    plan = make_plan(["tab03"], QUICK)
    ws = Workspace(tmp_path)
    shared = {"kind": "expert", "params": {"expert": "stg"}, "build_seconds": 120.0}
    cells = [slot.task for slot in plan.specs[0].slots if slot.task is not None][:2]
    for task in cells:
        write_ok_result(ws, task, {"artifacts": {"stg-key": shared}, "timings": {"eval_s": 6.0}}, psnr=25.0)
    compute = compute_rows(plan, ws)
    assert compute["builds"] == [{"kind": "expert", "what": "stg", "count": 1, "minutes": 2.0}]
    assert compute["minutes"] == pytest.approx(2.0 + 12.0 / 60)
