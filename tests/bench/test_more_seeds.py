"""More seeds where the claims need them: a preset's ``table_seeds`` and ``bench.all --seeds N`` train N
seeds of a table on every scene, the one a stability run measures included, reusing that run's builds and
keeping every key; the report names the tables whose undecided paper claims more seeds would decide."""

from __future__ import annotations

import re
from dataclasses import replace

import pytest
from helpers.cells import staged_scenes

import bench.plan
from bench.all import main
from bench.presets import get_preset
from bench.report import MAX_SUGGESTED_SEEDS, SpecReport, more_seeds, more_seeds_markdown


def _tasks(spec):
    return {s.task.key for s in spec.slots if s.task is not None}


def test_table_seeds_train_every_scene_of_the_table_and_keep_the_keys(monkeypatch):
    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes())  # stand-ins only
    quick = replace(get_preset("quick"), table_seeds={})
    more = replace(quick, table_seeds={"tab07": 3, "fig_mdc": 3, "tab09": 5})
    assert more.to_dict() == quick.to_dict()  # planning only: no cell key moves
    before = {sp.spec.id: sp for sp in bench.plan.make_plan(["tab07", "tab09", "fig_mdc"], quick).specs}
    after = {sp.spec.id: sp for sp in bench.plan.make_plan(["tab07", "tab09", "fig_mdc"], more).specs}
    # the N3V stand-in has a stability run (Table IX): without table_seeds its tables train once
    assert {s.seed for s in before["tab07"].slots} == {0}
    assert {s.seed for s in after["tab07"].slots} == {0, 1, 2}
    assert _tasks(before["tab07"]) < _tasks(after["tab07"])  # seed 0's cells are the same cells
    assert after["tab07"].averaged_seeds() == {"synthetic:n3v_like": [0, 1, 2]}
    # a stability run keeps the preset's seeds, a figure its one seed
    assert {s.seed for s in after["tab09"].slots} == {0, 1, 2}
    assert {s.seed for s in after["fig_mdc"].slots} == {0}


def test_the_seeds_flag_plans_more_seeds_of_the_selected_tables(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    dirs = ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]

    def planned(*argv: str) -> tuple[int, int]:
        assert main(["--tiny", "--tables", "7", "--dry-run", *dirs, *argv]) == 0
        err = capsys.readouterr().err
        plan = re.search(r"plan: (\d+) builds to compute, 0 cached; (\d+) evaluations", err)
        return int(plan.group(1)), int(plan.group(2))

    (builds, evals), (more_builds, more_evals) = planned(), planned("--seeds", "3")
    assert evals > 0 and more_evals == 3 * evals  # every row at three seeds
    assert builds < more_builds < 3 * builds  # the scene is built once for all seeds


def _report(spec_id: str, *claims: tuple[str, str, int | None], seeds: int = 1) -> SpecReport:
    rows = [{"id": f"c{i}", "kind": kind, "ours": ours, "ours_seeds_to_decide": need}
            for i, (kind, ours, need) in enumerate(claims)]  # fmt: skip
    return SpecReport(spec_id, "t", "table", "ok", [], {}, [], rows, [], [], [], "", seeds=seeds)


def test_the_report_names_the_seeds_that_would_decide_undecided_paper_claims():
    reports = [
        _report("tab07", ("paper", "within noise", 4), ("paper", "within noise", 9), ("paper", "held", None)),
        _report("tab03", ("paper", "within noise", 79), ("suite", "within noise", 2)),
        _report("tab17", ("paper", "failed", None), ("sanity", "within noise", 2)),
        _report("tab16", ("paper", "within noise", 3), seeds=3),  # 3 seeds trained: more would not say
        replace(_report("fig_mdc", ("paper", "within noise", 4)), kind="figure"),  # figures draw one seed
    ]
    rows = more_seeds(reports, "quick")
    assert rows == [
        {
            "spec": "tab07",
            "trained": 1,
            "undecided": 2,
            "decidable": 2,
            "seeds": 9,
            "command": "python -m bench.all --quick --tables tab07 --seeds 9",
        },
        {"spec": "tab03", "trained": 1, "undecided": 1, "decidable": 0, "seeds": None, "command": None},
        {"spec": "tab16", "trained": 3, "undecided": 1, "decidable": 0, "seeds": None, "command": None},
    ]
    assert MAX_SUGGESTED_SEEDS < 79
    quick32 = more_seeds(reports[:1], "quick32")[0]["command"]
    assert quick32.startswith("python -m bench.all --preset quick32 ")
    section = more_seeds_markdown(rows)
    assert section[0] == "## More seeds"
    assert "| tab07 | 1 | 2 | 2 | 9 | `python -m bench.all --quick --tables tab07 --seeds 9` |" in section
    assert "| tab03 | 1 | 1 | 0 | – | – |" in section
    assert more_seeds_markdown([]) == []


def test_a_stability_scenes_noise_stays_its_stability_runs(monkeypatch, tmp_path):
    """More seeds of a table on the N3V stand-in give its rows their own and paired spreads, but the
    scene's spread (every one-seed row's noise) stays Table IX's: a row that fails at one seed (a pruning
    that breaks the model) is that row's spread, not the scene's."""
    from helpers.cells import write_ok_result

    from bench.signals import seed_noise
    from bench.store import Workspace

    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes())
    quick = replace(get_preset("quick"), table_seeds={"tab05": 3})
    plan = bench.plan.make_plan(["tab05", "tab09"], quick)
    ws = Workspace(tmp_path)
    for sp in plan.specs:
        for slot in sp.slots:
            wild = sp.spec.id == "tab05" and "pruning" in slot.row and slot.seed == 1
            write_ok_result(ws, slot.task, psnr=12.0 if wild else 26.0 + 0.2 * slot.seed)
    stand_in = seed_noise(plan, ws)["scenes"]["synthetic:n3v_like"]
    assert stand_in["metrics"]["PSNR"] == pytest.approx(0.4)  # Table IX's rows: 26.0 to 26.4
    assert stand_in["rows"]["MoE-GS (55% pruning)"]["PSNR"] == pytest.approx(14.4)
    assert {"tab05", "tab09"} <= set(stand_in["source"])


def test_a_label_the_stability_run_measures_keeps_that_runs_spread(monkeypatch, tmp_path):
    """Table VII's "MoE-GS (N=3)" is pruned, Table IX's is not: when VII's breaks at one seed, the spread
    other tables judge "MoE-GS (N=3)" by stays IX's, while VII's own pairs keep theirs."""
    from helpers.cells import write_ok_result

    from bench.signals import seed_noise
    from bench.store import Workspace

    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes())
    quick = replace(get_preset("quick"), table_seeds={"tab07": 3})
    plan = bench.plan.make_plan(["tab07", "tab09"], quick)
    ws = Workspace(tmp_path)
    pruned = ("w/o Single-Pass", "MoE-GS (N=3)")
    for sp in plan.specs:
        for slot in sp.slots:
            wild = sp.spec.id == "tab07" and slot.row in pruned and slot.seed == 1
            write_ok_result(ws, slot.task, psnr=12.0 if wild else 26.0 + 0.2 * slot.seed)
    stand_in = seed_noise(plan, ws)["scenes"]["synthetic:n3v_like"]
    assert stand_in["rows"]["MoE-GS (N=3)"]["PSNR"] == pytest.approx(0.4)  # Table IX's: 26.0 to 26.4
    assert stand_in["rows"]["w/o Single-Pass"]["PSNR"] == pytest.approx(14.4)  # only VII measures it
    pairs = {tuple(p["rows"]): p["metrics"]["PSNR"] for p in stand_in["pairs"]}
    assert pairs[("MoE-GS (N=3)", "w/o Pruning")] == pytest.approx(14.2)  # VII's pair: 0, -14.2, 0
    assert pairs[("E-D3DGS", "MoE-GS (N=3)")] == pytest.approx(0.0)  # IX's pair: both rise 0.2 a seed
