"""From cached cell results to the printed table: the seeds axis (Min / Max / Average), the budgets axis, the
dataset Average and its comparability, the paper's view, and the LaTeX cell ``ours (paper, Δ)`` with its
ranks and digits. Results are written by hand into a workspace; no cell runs."""

from __future__ import annotations

import pytest
from helpers.cells import staged_scenes, write_ok_result

import bench.plan
from bench.latex import _ranks, cell_tex, fmt
from bench.presets import get_preset
from bench.store import Workspace
from bench.values import AVERAGE, MEAN, STAND_IN, SpecValues


def _plan(table: str, monkeypatch, *real: str):
    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes(*real))
    return bench.plan.make_plan([table], get_preset("quick")).specs[0]


def _uniform(table: str, monkeypatch, tmp_path, **metrics: float) -> SpecValues:
    """``table``'s values (stand-ins only) with every cell's result holding the same ``metrics``."""
    sp = _plan(table, monkeypatch)
    ws = Workspace(tmp_path)
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, **metrics)
    return SpecValues(sp, ws)


def test_the_seeds_axis_prints_min_max_and_average_of_every_seed(tmp_path, monkeypatch):
    sp = _plan("tab09", monkeypatch)
    assert len(sp.seeds) >= 3
    ws = Workspace(tmp_path)
    slots = [s for s in sp.slots if s.task is not None]
    for s in slots:
        write_ok_result(ws, s.task, psnr=20.0 + s.seed + (1.0 if s.row == "E-D3DGS" else 0.0))
    values = SpecValues(sp, ws)
    seeds = sp.seeds
    for row, offset in (("E-D3DGS", 1.0), ("MoE-GS (N=3)", 0.0)):
        got = [values.get(row, c, "PSNR") for c in ("Min", "Max", "Average")]
        expected = [20 + offset + min(seeds), 20 + offset + max(seeds), 20 + offset + sum(seeds) / len(seeds)]
        assert got == pytest.approx(expected), row
    # a seed still missing leaves the row's Min / Max / Average open, whichever seed it is
    last = max(seeds)
    partial = Workspace(tmp_path / "partial")
    for s in slots:
        if not (s.row == "E-D3DGS" and s.seed == last):
            write_ok_result(partial, s.task, psnr=20.0)
    values = SpecValues(sp, partial)
    assert [values.get("E-D3DGS", c, "PSNR") for c in ("Min", "Max", "Average")] == [None] * 3
    assert values.get("MoE-GS (N=3)", "Average", "PSNR") == pytest.approx(20.0)


def test_the_budgets_axis_prints_each_budgets_own_cells(tmp_path, monkeypatch):
    sp = _plan("tab18", monkeypatch)
    ws = Workspace(tmp_path)
    budgets = sp.spec.budgets
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=20.0 + 10.0 * budgets[s.budget_column])
    values = SpecValues(sp, ws)
    for column, fraction in budgets.items():
        assert values.get("STG", column, "PSNR") == pytest.approx(20.0 + 10.0 * fraction), column


def test_the_average_and_dataset_means_need_all_of_the_papers_scenes(tmp_path, monkeypatch):
    """One real D-NeRF scene of the paper's eight: its column compares with the paper, the Average does not
    exist; a metrics-axis table over one real N3V scene is a mean over a subset, not the paper's number."""
    sp = _plan("tab17", monkeypatch, "dnerf:mutant")
    ws = Workspace(tmp_path)
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=20.0)
    values = SpecValues(sp, ws)
    mutant = values.cells[("Grid4D", "Mutant", "PSNR")]
    assert mutant.value == pytest.approx(20.0) and mutant.comparable
    average = values.cells[("Grid4D", AVERAGE, "PSNR")]
    assert average.value is None and average.status == "partial"

    sp = _plan("tab06", monkeypatch, "n3v:coffee_martini")
    assert [s.name for s in sp.scenes] == ["n3v:coffee_martini"]
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=20.0)
    values = SpecValues(sp, ws)
    cell = values.cells[("Pixel Router", "PSNR", "PSNR")]
    assert cell.value == pytest.approx(20.0) and not cell.comparable
    assert cell.detail == "mean over a subset of the paper's scenes"
    assert values.deltas() == []


def test_a_cell_over_seeds_needs_every_seed_and_a_nan_metric_is_no_value(tmp_path, monkeypatch):
    """Mutant trains 3 seeds at quick: one failed seed leaves the cell failed, not the mean of the other
    two; a NaN metric (an empty region, a diverged run) prints as no value, not as "nan"."""
    sp = _plan("tab17", monkeypatch, "dnerf:mutant")
    slots = [s for s in sp.slots if s.task is not None and s.row == "Grid4D"]
    assert len({s.seed for s in slots}) == 3
    ws = Workspace(tmp_path)
    for s in slots[:-1]:
        write_ok_result(ws, s.task, psnr=30.0)
    write_ok_result(ws, slots[-1].task, {"status": "failed", "error": "diverged"})
    cell = SpecValues(sp, ws).cells[("Grid4D", "Mutant", "PSNR")]
    assert cell.value is None and cell.status == "failed" and "diverged" in cell.detail

    for s in slots:
        write_ok_result(ws, s.task, psnr=float("nan"))
    cell = SpecValues(sp, ws).cells[("Grid4D", "Mutant", "PSNR")]
    assert cell.value is None and "not reported" in cell.detail


def test_a_stability_run_on_a_stand_in_is_not_comparable(tmp_path, monkeypatch):
    """Table IX's Min / Max / Average over seeds on the N3V stand-in: values, but no delta to the paper."""
    values = _uniform("tab09", monkeypatch, tmp_path, psnr=25.0)
    cell = values.cells[("E-D3DGS", "Average", "PSNR")]
    assert cell.value == pytest.approx(25.0) and not cell.comparable
    assert values.deltas() == []


def test_the_scene_mean_of_a_claim_is_over_scene_columns_not_the_average(tmp_path, monkeypatch):
    """With all eight D-NeRF scenes the Average column has a value; ``@scenes`` (what claims compare and
    ``@mean`` averages) still lists the scenes only."""
    from bench.datasets import get_dataset

    names = [f"dnerf:{n}" for n in get_dataset("dnerf").scene_names()]
    sp = _plan("tab17", monkeypatch, *names)
    ws = Workspace(tmp_path)
    psnr = {name: 30.0 + i for i, name in enumerate(names)}
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=psnr[s.scene.name])
    values = SpecValues(sp, ws)
    assert values.cells[("Grid4D", AVERAGE, "PSNR")].value == pytest.approx(33.5)
    assert AVERAGE not in values.columns("@scenes") and len(values.columns("@scenes")) == 8
    assert values.get("Grid4D", MEAN, "PSNR") == pytest.approx(33.5)


def test_cells_mixing_real_and_stand_in_scenes_are_not_comparable():
    from types import SimpleNamespace

    from bench.values import _combine

    class Results:
        def status(self, slot):
            return "ok", ""

        def value(self, slot, metric_name):
            return 20.0

    real, stand_in = (SimpleNamespace(scene=SimpleNamespace(real=r)) for r in (True, False))
    assert _combine([real, real], Results(), "PSNR").comparable
    assert not _combine([real, stand_in], Results(), "PSNR").comparable


def test_the_papers_mean_is_its_average_column(tmp_path, monkeypatch):
    values = SpecValues(_plan("tab03", monkeypatch), Workspace(tmp_path))
    average = values.paper.get("MoE-GS (N=3)", AVERAGE, "PSNR")
    assert average is not None and values.paper.get("MoE-GS (N=3)", MEAN, "PSNR") == average
    assert values.paper.columns("@mean") == [AVERAGE]


def test_a_latex_cell_shows_ours_its_rank_the_paper_and_ours_minus_the_paper(tmp_path, monkeypatch):
    sp = _plan("tab17", monkeypatch, "dnerf:mutant")
    ws = Workspace(tmp_path)
    ours = {"DeformableGS": (30.0, 0.05), "Grid4D": (32.0, 0.04), "MoE-GS (N=2)": (31.0, 0.1234)}
    for s in sp.slots:
        if s.task is not None:
            psnr, lpips = ours[s.row]
            write_ok_result(ws, s.task, psnr=psnr, lpips=lpips)
    values = SpecValues(sp, ws)
    paper = values.paper.get("Grid4D", "Mutant", "PSNR")
    printed = values.paper.printed("Grid4D", "Mutant", "PSNR")
    ranks = {"Grid4D": 0, "MoE-GS (N=2)": 1}
    text = cell_tex(values, "Grid4D", "Mutant", "PSNR", ranks)
    assert text.startswith(r"\rankfirst{32.00}")
    assert text.endswith(rf"\paperdelta{{{printed}}}{{{32.0 - paper:+.2f}}}")
    assert _ranks(values, "Mutant", "PSNR") == {"DeformableGS": 2, "Grid4D": 0, "MoE-GS (N=2)": 1}
    assert fmt(0.1234, "LPIPS") == "0.123" and fmt(31.0, "PSNR") == "31.00"


def test_the_best_lpips_is_the_lowest(tmp_path, monkeypatch):
    sp = _plan("tab12", monkeypatch)
    ws = Workspace(tmp_path)
    lpips = {"4DGaussians": 0.2, "E-D3DGS": 0.1, "STG†": 0.3, "Ex4DGS": 0.25, "MoE-GS (N=4)": 0.15}
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=20.0, ssim=0.8, lpips=lpips[s.row])
    ranks = _ranks(SpecValues(sp, ws), STAND_IN, "LPIPS")
    assert ranks == {"E-D3DGS": 0, "MoE-GS (N=4)": 1, "4DGaussians": 2, "Ex4DGS": 3, "STG†": 4}


def test_ties_share_a_rank_three_ranks_are_marked_and_a_lone_value_has_none(tmp_path, monkeypatch):
    """Dense ranks: two rows tied at the top are both first and the next value is second; the fourth
    value carries no mark; a column where one row has a value ranks nothing."""
    sp = _plan("tab12", monkeypatch)
    ws = Workspace(tmp_path)
    psnr = {"4DGaussians": 30.0, "E-D3DGS": 30.0, "STG†": 29.0, "Ex4DGS": 28.0, "MoE-GS (N=4)": 27.0}
    for s in sp.slots:
        if s.task is not None:
            write_ok_result(ws, s.task, psnr=psnr[s.row], ssim=0.8, lpips=0.1, psnr_dynamic=21.0)
    values = SpecValues(sp, ws)
    ranks = _ranks(values, STAND_IN, "PSNR")
    assert ranks == {"4DGaussians": 0, "E-D3DGS": 0, "STG†": 1, "Ex4DGS": 2, "MoE-GS (N=4)": 3}
    assert cell_tex(values, "Ex4DGS", STAND_IN, "PSNR", ranks).startswith(r"\rankthird{28.00}")
    assert cell_tex(values, "MoE-GS (N=4)", STAND_IN, "PSNR", ranks).startswith("27.00")
    assert cell_tex(values, "STG†", STAND_IN, "LPIPS", {}) == "0.100"  # the dynamic region: under PSNR only

    lone = Workspace(tmp_path / "lone")
    for s in sp.slots:
        if s.task is not None and s.row == "STG†":
            write_ok_result(lone, s.task, psnr=29.0)
    assert _ranks(SpecValues(sp, lone), STAND_IN, "PSNR") == {}


def test_a_stand_in_cell_shows_the_papers_average_beside_ours_and_its_dynamic_region(tmp_path, monkeypatch):
    values = _uniform("tab03", monkeypatch, tmp_path, psnr=30.0, psnr_dynamic=21.0)
    average = values.paper.printed("MoE-GS (N=3)", AVERAGE, "PSNR")
    assert average is not None
    text = cell_tex(values, "MoE-GS (N=3)", STAND_IN, "PSNR", {})
    assert text == rf"30.00\dynregion{{21.00}}\paperref{{{average}}}"


def test_a_stand_in_value_shows_the_papers_number_without_a_delta(tmp_path, monkeypatch):
    values = _uniform("tab06", monkeypatch, tmp_path, psnr=20.0)
    printed = values.paper.printed("Pixel Router", "PSNR", "PSNR")
    assert printed is not None
    text = cell_tex(values, "Pixel Router", "PSNR", "PSNR", {})
    assert text == rf"20.00\paperref{{{printed}}}"


def test_the_report_says_a_partly_computed_table_is_partly_reproduced(tmp_path, monkeypatch):
    from bench.report import _status

    sp = _plan("tab17", monkeypatch, "dnerf:mutant")
    quick = get_preset("quick")
    ws = Workspace(tmp_path)
    assert _status(SpecValues(sp, ws), quick) == "not run yet (3 row(s) pending)"
    for s in sp.slots:
        if s.task is not None and s.row == "Grid4D":
            write_ok_result(ws, s.task, psnr=20.0)
    status = _status(SpecValues(sp, ws), quick)
    assert status.startswith(
        "reproduced at quick preset (reduced scale) on real data (dnerf:mutant): 1/3 rows"
    )


def test_summary_rows_keep_each_experts_full_dynamic_and_static_scores_apart(tmp_path, monkeypatch):
    from bench.signals import expert_rows

    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes("dnerf:mutant"))
    plan = bench.plan.make_plan(["tab17"], get_preset("quick"))
    ws = Workspace(tmp_path)
    for s in plan.specs[0].slots:
        if s.task is not None:
            write_ok_result(
                ws,
                s.task,
                psnr=30.0,
                psnr_dynamic=25.0,
                psnr_static=32.0,
                ssim=0.9,
                ssim_dynamic=0.8,
                ssim_static=0.95,
            )
    rows = {r["expert"]: r for r in expert_rows(plan, ws)}
    assert set(rows) == {"deformable", "grid4d"}
    for row in rows.values():
        assert row["scene"] == "dnerf:mutant"
        assert row["psnr"] == {"full": 30.0, "dynamic": 25.0, "static": 32.0}
        assert row["ssim"] == {"full": 0.9, "dynamic": 0.8, "static": 0.95}
