"""``python -m bench.convergence``: quick schedules scaled to N, cached cells, figure and table."""

from __future__ import annotations

import json

import pytest
import torch

from bench import convergence
from bench.report import convergence_markdown

SCENE = "dnerf:mutant"


@pytest.mark.realdata
@pytest.mark.slow
def test_study_runs_caches_and_draws(tmp_path, mutant_root, monkeypatch, capsys):
    out = tmp_path / "reports" / "convergence"
    readme = tmp_path / "README.md"
    readme.write_text("# x\n<!-- results:convergence -->\nSTALE-BODY\n<!-- /results:convergence -->\n")
    args = ["--scene", SCENE, "--experts", "static", "--iterations", "10,20", "--resolutions", "0.0625",
            "--workspace", str(tmp_path / "ws"), "--out", str(out), "--no-progress",
            "--readme", str(readme), "--threads", "1"]  # fmt: skip
    threads, train_cell = torch.get_num_threads(), convergence.run_cell
    assert convergence.main(args) == 0
    assert torch.get_num_threads() == threads  # --threads holds for the study only
    summary = json.loads((out / "dnerf_mutant.json").read_text())
    cells = summary["cells"]
    assert [c["iterations"] for c in cells] == [10, 20]
    for c in cells:
        assert c["image_size"] == [50, 50] and c["native_size"] == [800, 800] and c["test_views"] == 20
        assert c["psnr"] > 10 and c["psnr_dynamic"] is not None and c["psnr_native"] > 10
        assert c["motion_r2"] is None  # D-NeRF's test views never repeat a camera
        assert c["recipe"]["overrides"]["train.iterations"] == c["iterations"]
        assert c["code_version"] == convergence.cell_code_version("static", SCENE) and c["threads"] == 1
    assert (out / "dnerf_mutant.png").stat().st_size > 10_000
    assert "| static | 0.0625 (50x50) | 10 |" in (out / "dnerf_mutant.md").read_text()

    written = readme.read_text()
    assert (
        "STALE-BODY" not in written
        and "![convergence on dnerf:mutant](reports/convergence/dnerf_mutant.png)" in written
    )
    assert "| static | 0.0625 (50x50) | 20 |" in written and "python -m bench.convergence --scene" in written
    version = cells[0]["code_version"]
    assert f"library code version {version} (git " in written and "1 torch thread(s) per cell" in written
    assert f"cells run on {cells[0]['machine']};" in written
    section = "\n".join(convergence_markdown(tmp_path / "reports"))
    assert "![dnerf_mutant](convergence/dnerf_mutant.png)" in section and "| static | 0.0625" in section
    assert "### dnerf:mutant\n" in section

    def no_training(*args, **kwargs):
        raise AssertionError("a cached cell was recomputed")

    monkeypatch.setattr(convergence, "run_cell", no_training)
    assert convergence.main(args) == 0  # resumes from the cache
    # --no-run draws what is computed and names what is not
    more = [*args[:5], "10,20,30", *args[6:], "--no-run"]
    assert convergence.main(more) == 0
    assert "| static | 0.0625 (50x50) | 20 |" in readme.read_text()
    assert "Not run yet: static at 0.0625x, N = 30." in readme.read_text()
    # --num-points: the scene's random initial cloud of that size, in cells and outputs of their own
    fewer = [
        *args[:5],
        "10",
        *args[6:11],
        str(tmp_path / "out_p"),
        *args[12:],
        "--num-points",
        "300",
        "--seed",
        "1",
    ]
    monkeypatch.setattr(convergence, "run_cell", train_cell)
    assert convergence.main(fewer) == 0
    (cell,) = json.loads((tmp_path / "out_p" / "dnerf_mutant-p300-s1.json").read_text())["cells"]
    assert cell["num_points"] == 300 and cell["num_gaussians"] == 300  # no densification in 10 steps
    assert cell["seed"] == 1 and cell["recipe"]["overrides"]["train.seed"] == 1
    assert cell["psnr"] != cells[0]["psnr"]  # another cloud and seed: another run
    assert (tmp_path / "ws" / "dnerf_mutant" / "static-r0.0625-n10-p300-s1.json").is_file()
    assert "1 torch thread(s) per cell, 300 random initial points, seed 1;" in readme.read_text()
    (tmp_path / "convergence").mkdir()
    for f in (tmp_path / "out_p").iterdir():
        (tmp_path / "convergence" / f.name).write_bytes(f.read_bytes())
    report = "\n".join(convergence_markdown(tmp_path))
    assert "### dnerf:mutant, 300 random initial points, seed 1\n" in report
    monkeypatch.setattr(convergence, "run_cell", no_training)  # what follows reuses cached cells only
    with pytest.raises(SystemExit) as err:
        convergence.main([*more[:9], str(tmp_path / "empty"), *more[10:]])
    assert err.value.code == 2
    assert "no cell of this library computed yet (run without --no-run)" in capsys.readouterr().err
    readme.write_text(written + "<!-- results:convergence-b -->\n<!-- /results:convergence-b -->\n")
    assert convergence.main([*args, "--section", "convergence-b"]) == 0  # one README section per scene
    assert readme.read_text().count("![convergence on dnerf:mutant]") == 2

    # a cell cached by other library code is recomputed, the others are reused
    cell = tmp_path / "ws" / "dnerf_mutant" / "static-r0.0625-n20.json"
    cell.write_text(cell.read_text().replace(version, "0ther1ibrary0000"))
    recomputed = []

    def fake_training(expert, scene, resolution, iterations, progress, variant):
        recomputed.append(iterations)
        return {**cells[1], "psnr": 11.0}

    monkeypatch.setattr(convergence, "run_cell", fake_training)
    assert convergence.main(args) == 0
    assert recomputed == [20] and "| static | 0.0625 (50x50) | 20 | " in readme.read_text()
    assert json.loads(cell.read_text())["psnr"] == 11.0


def test_a_study_stops_at_each_resolutions_limit_and_force_recomputes(tmp_path, monkeypatch):
    """Without training: ``run_cell`` records what it was asked for."""
    trained = []

    def fake_cell(expert, scene, resolution, iterations, progress, variant):
        trained.append((resolution, iterations))
        return {
            "expert": expert,
            "resolution_scale": resolution,
            "iterations": iterations,
            "code_version": "v",
        }

    monkeypatch.setattr(convergence, "run_cell", fake_cell)
    monkeypatch.setattr(convergence, "cell_code_version", lambda expert, scene: "v")
    study = dict(scene=SCENE, experts=["static"], iterations=[10, 20, 30], resolutions=[0.25, 0.5],
                 workspace=tmp_path, limits={0.25: 20}, progress=False)  # fmt: skip
    records, missing = convergence.run_study(**study)
    assert trained == [(0.25, 10), (0.25, 20), (0.5, 10), (0.5, 20), (0.5, 30)] and missing == []
    assert [(r["resolution_scale"], r["iterations"]) for r in records] == trained
    assert convergence.run_study(**study)[0] == records and len(trained) == 5  # cached
    convergence.run_study(**study, force=True)
    assert len(trained) == 10


def test_provenance_names_the_machine_of_every_cell():
    """A study may gather cells computed on several machines: the footer names each, not the machine
    that drew the table."""
    cells = [
        {"machine": "Intel Xeon, 2 logical CPUs", "code_version": "v1", "git": "a" * 40, "threads": 1},
        {"machine": "AMD EPYC, 2 logical CPUs", "code_version": "v1", "git": "b" * 40, "threads": 1},
    ]
    words = convergence.provenance(cells)
    assert words.startswith("cells run on AMD EPYC, 2 logical CPUs; Intel Xeon, 2 logical CPUs; ")
    assert "library code version v1 (git aaaaaaaaaa, bbbbbbbbbb), 1 torch thread(s) per cell" in words
    assert "cells run on unrecorded;" in convergence.provenance([{"code_version": "v1"}])
    variant = convergence.Variant.of({"num_points": 5000, "seed": 1})
    assert variant == convergence.Variant(5000, 1) and variant.suffix == "-p5000-s1"
    assert convergence.provenance(cells, variant).endswith("per cell, 5000 random initial points, seed 1")
    assert convergence.Variant.of({}) == convergence.Variant() and convergence.Variant().suffix == ""


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--num-points", "0"], "--num-points must be >= 1, got 0"),
        (["--seed", "-1"], "--seed must be >= 0, got -1"),
    ],
)
def test_cli_rejects_a_bad_variant(capsys, argv, message):
    with pytest.raises(SystemExit) as err:
        convergence.main([*argv, "--no-run"])
    assert err.value.code == 2 and message in capsys.readouterr().err


def test_cli_rejects_a_thread_count_below_one(capsys):
    with pytest.raises(SystemExit) as err:
        convergence.main(["--experts", "static", "--threads", "0", "--workspace", "/nonexistent"])
    assert err.value.code == 2 and "--threads must be >= 1, got 0" in capsys.readouterr().err


def test_cli_rejects_an_expert_without_a_schedule_table(capsys):
    with pytest.raises(SystemExit) as err:
        convergence.main(["--experts", "mode", "--workspace", "/nonexistent"])
    assert err.value.code == 2 and "no schedule table for expert 'mode'" in capsys.readouterr().err
