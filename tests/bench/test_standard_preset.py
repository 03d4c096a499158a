"""The ``standard`` bench preset: real scenes only, quick schedules stretched, the router's full schedule,
every test view, upsampled native-resolution PSNR, its own output folders and the paper | standard |
quick comparison."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

import bench.sidebyside
from bench.all import main, output_dirs
from bench.cells._lib import recipe_of
from bench.cells.moe import router_config
from bench.latex import check_structure
from bench.plan import make_plan
from bench.presets import LATER_FIELDS, PRESETS, get_preset
from bench.registry import get_spec
from bench.results import read_result
from bench.schedules import scaled_overrides
from bench.sidebyside import Cell, Comparison, markdown, render_latex
from bench.store import Workspace
from bench.tasks import Task
from bench.worker import run_job, write_job

STANDARD = get_preset("standard")


class _Ctx:
    def __init__(self, preset):
        self.preset = preset


def _build(expert: str, scene: str, dataset: str, preset: str = "standard") -> Task:
    return Task("build", "expert", {"expert": expert, "dataset": dataset}, scene, {}, preset, 0)


def test_presets_without_the_later_fields_keep_their_definition():
    """Cell keys hash ``to_dict``: the fields added for ``standard`` are absent from the other presets'
    definitions (their cached results keep their keys) and present in ``standard``'s."""
    for name in ("tiny", "quick", "paper"):
        assert not set(LATER_FIELDS) & set(get_preset(name).to_dict()), name
    assert set(LATER_FIELDS) <= set(STANDARD.to_dict())


@pytest.mark.parametrize("expert", ["deformable", "grid4d", "fourdgs"])
def test_real_scenes_train_the_quick_schedules_stretched(expert):
    scene, dataset = ("panoptic:basketball", "panoptic") if expert == "fourdgs" else ("dnerf:mutant", "dnerf")
    recipe = recipe_of(_Ctx(STANDARD), _build(expert, scene, dataset))
    n = STANDARD.schedule_iterations[dataset]
    assert recipe.config.train.iterations == n
    for key, value in scaled_overrides(expert, scene, n).items():
        assert recipe.overrides[key] == value, key
    assert recipe.config.train.max_eval_views is None  # every test view


def test_stand_ins_and_other_presets_are_not_stretched():
    stand_in = recipe_of(_Ctx(STANDARD), _build("deformable", "synthetic:dnerf_like", "dnerf"))
    quick = recipe_of(_Ctx(get_preset("quick")), _build("deformable", "dnerf:mutant", "dnerf", "quick"))
    assert stand_in.config.train.iterations == quick.config.train.iterations == 600


def test_an_expert_without_a_schedule_table_is_refused_by_name():
    with pytest.raises(ValueError, match="no schedule table for expert 'mode'"):
        recipe_of(_Ctx(STANDARD), _build("mode", "dnerf:mutant", "dnerf"))


def test_the_router_trains_its_full_code_schedule():
    task = Task("build", "moe", {"experts": ["deformable", "grid4d"], "router": "vapr"}, "dnerf:mutant", {},
                "standard", 0)  # fmt: skip
    cfg = router_config(_Ctx(STANDARD), task)
    assert (cfg.iterations, cfg.optimizer, cfg.phi_kernel, cfg.train_temperature) == (5000, "radam", 1, 0.01)
    assert cfg.checkpoint_every == STANDARD.checkpoint_every == 1000  # an interrupted router resumes
    quick = router_config(_Ctx(get_preset("quick")), replace(task, preset="quick"))
    assert quick.iterations == 150


def test_output_folders(tmp_path):
    assert output_dirs(tmp_path, STANDARD, ["tab16", "tab17"], ["tab16", "tab17"]) == (
        tmp_path / "tables" / "standard",
        tmp_path / "reports" / "standard",
    )
    subset = tmp_path / "reports" / "subsets" / "standard-tab17"
    assert output_dirs(tmp_path, STANDARD, ["tab17"], ["tab16", "tab17"]) == (
        subset / "tables",
        subset / "reports",
    )
    quick = get_preset("quick")
    assert output_dirs(tmp_path, quick, ["tab01"], ["tab01"]) == (tmp_path / "tables", tmp_path / "reports")


def _comparison() -> Comparison:
    spec = get_spec("tab17")
    rows = [r.name for r in spec.rows]
    ours = {(r, "Mutant", "standard"): Cell(38.5, 30.25, 29.5) for r in rows}
    ours.update({(r, "Mutant", "quick"): Cell(None, None) for r in rows})
    paper = {(r, "Mutant"): 42.0 for r in rows}
    labels = {"standard": "standard (1/8 res., 6000 / 5000 it.)", "quick": "quick (1/8 res., 600 / 150 it.)"}
    return Comparison(spec, "PSNR", ["Mutant"], labels, paper, ours)


def test_comparison_renders_value_dynamic_delta_and_native():
    text = markdown(_comparison())
    assert "| standard (1/8 res., 6000 / 5000 it.) | quick (1/8 res., 600 / 150 it.) |" in text
    assert "| DeformableGS | Mutant | 42.00 | 38.50 [30.25] (-3.50); upsampled to native 29.50 | ? |" in text
    latex = render_latex(_comparison())
    assert check_structure(latex) == []
    assert (
        r"38.50\dynregion{30.25}{\scriptsize\,($-3.50$)}{\scriptsize\,$\uparrow$29.50} & \ourspending"
        in latex
    )


@pytest.mark.realdata
def test_cli_runs_real_tables_only_into_its_own_folders(tmp_path, mutant_root, basketball_root, capsys):
    """``--preset standard --no-run``: the stand-in tables are named as staying at quick, and the outputs
    go to ``tables/standard`` and ``reports/standard`` (nothing is trained)."""
    args = ["--preset", "standard", "--no-run", "--no-progress", "--workspace", str(tmp_path / "ws")]
    assert main([*args, "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "runs real scenes only; stand-in tables stay at quick: tab01," in err
    assert "4 spec(s)" in err  # Tables XVI, XVII and their routers' gate figures
    assert "fig_gates_dnerf" not in err.split("stay at quick:")[1].split("\n")[0]
    assert {p.name for p in (tmp_path / "tables" / "standard").glob("*.tex")} == {
        "tab16.tex",
        "tab17.tex",
        "all.tex",
    }  # fmt: skip  (no results: no comparison tables)
    assert (tmp_path / "reports" / "standard" / "summary.json").is_file()
    assert not (tmp_path / "tables" / "tab17.tex").exists()
    assert main([*args, "--out", str(tmp_path), "--tables", "3"]) == 2
    assert "no selected table runs on real data at preset standard" in capsys.readouterr().err


@pytest.mark.realdata
def test_tox_repro_env_accepts_the_standard_preset(tmp_path, mutant_root, basketball_root, monkeypatch):
    """``MOEGS_PRESET=standard tox -e repro-tab17`` runs ``bench.all --tables repro-tab17``: a subset of
    the standard run, written under ``reports/subsets/standard-tab17``."""
    monkeypatch.setenv("MOEGS_PRESET", "standard")
    args = ["--tables", "repro-tab17", "--no-run", "--no-progress", "--workspace", str(tmp_path / "ws")]
    assert main([*args, "--out", str(tmp_path)]) == 0
    subset = tmp_path / "reports" / "subsets" / "standard-tab17"
    assert (subset / "tables" / "tab17.tex").is_file() and (subset / "reports" / "summary.json").is_file()
    assert "Preset standard" in (subset / "tables" / "tab17.tex").read_text()


@pytest.mark.realdata
@pytest.mark.slow
def test_table_xvii_at_a_tiny_standard_scale(tmp_path, mutant_root, monkeypatch):
    """Table XVII end to end in this process at a tiny copy of ``standard``: the experts train their
    stretched schedules, every cell scores the upsampled native PSNR, and the outputs hold the
    comparison and the preset of each expert row."""
    tiny = replace(
        STANDARD,
        name="standard-test",
        real={"dnerf": {"resolution_scale": 1 / 16, "num_points": 2000}},
        schedule_iterations={"dnerf": 40},
        router_steps=6,
        test_views=2,
        speed_views=1,
        speed_warmup=1,
        speed_repeats=1,
        checkpoint_every=0,
    )
    monkeypatch.setitem(PRESETS, tiny.name, tiny)
    monkeypatch.setattr(bench.sidebyside, "COMPARED", (tiny.name, "quick"))
    ws = Workspace(tmp_path / "ws")
    plan = make_plan(["tab17", "fig_gates_dnerf"], tiny)
    routers = [t for level in plan.build_levels() for t in level if t.kind == "moe"]
    assert len(routers) == 1  # the gate figure reads the table's own router: no extra training
    for task in plan.eval_tasks():
        assert run_job(write_job(ws, task, None))["status"] == "ok"
        result = read_result(ws.result_path(task))
        m = result["metrics"]
        if task.kind == "gates":  # the table's own router, on one real test view
            assert m["gate_experts"] in (1, 2) and m["psnr"] > 10 and "gates.npz" in result["files"]
            continue
        assert m["psnr_native"] > 10 and result["details"]["native_size"] == [800, 800]
        assert result["details"]["num_views"] == 2
    builds = [t for level in plan.build_levels() for t in level if t.kind == "expert"]
    assert builds
    for build in builds:
        meta = json.loads((ws.artifact_dir(build) / "artifact.json").read_text())
        assert meta["iterations"] == 40
        overrides = meta["recipe"]["overrides"]
        for key, value in scaled_overrides(build.params["expert"], build.scene, 40).items():
            assert overrides[key] == json.loads(json.dumps(value)), key  # as JSON: tuples are lists

    from bench.all import write_outputs

    out = write_outputs(plan, ws, ["tab17", "fig_gates_dnerf"], tmp_path / "tables", tmp_path / "reports")
    assert (tmp_path / "reports" / "figures" / "fig_gates_dnerf.png").is_file()
    latex = (tmp_path / "tables" / "tab17_presets.tex").read_text()
    assert check_structure(latex) == [] and r"\uparrow" in latex
    report = out["paths"]["md"].read_text()
    assert (
        "## Real scenes: paper | standard | quick" in report
        and "standard-test (1/16 res., 40 / 6 it.)" in report
    )
    summary = json.loads(out["paths"]["json"].read_text())
    assert {r["preset"] for r in summary["experts"]} == {"standard-test"}

    readme = tmp_path / "README.md"
    readme.write_text("# x\n<!-- results:standard -->\nSTALE-BODY\n<!-- /results:standard -->\n")
    assert bench.sidebyside.main(["--workspace", str(ws.root), "--readme", str(readme)]) == 0
    written = readme.read_text()
    assert "STALE-BODY" not in written and "tab17: Large motion: D-NeRF (PSNR)" in written
    assert "| DeformableGS | Mutant | 42.03 |" in written and "upsampled to native" in written


def test_sidebyside_without_results_says_what_to_run(tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        bench.sidebyside.main(["--workspace", str(tmp_path / "empty")])
    assert err.value.code == 1 and "no real-scene results in the workspace" in capsys.readouterr().err
