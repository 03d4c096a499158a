"""``python -m bench.readme``: the README results section from (fake) finished runs and tables/paper."""

from __future__ import annotations

import json
import re

import pytest

from bench.paper import list_original_tables, load_original_table, load_paper_table
from bench.readme import PUBLISHED, main, paper_name, published_numbers, readme_section
from bench.spec import EXPERTS
from moegs.io import to_dict
from moegs.recipes import config_for

PROFILE = "moegs/psnr_raw-ssim_3dgs-lpips_alex_legacy01"
README = "# title\n\nintro\n\n<!-- results:mutant -->\nstale table\n<!-- /results:mutant -->\n\n## After\n"


def fake_run(out, expert, psnr, ssim=0.9, lpips=0.05, seconds=12.0):
    """A finished run as the training loop writes it (only what compare reads)."""
    result = {
        "expert": expert,
        "scene": "dnerf:mutant",
        "stand_in": "",
        "completed": True,
        "iterations": 600,
        "num_gaussians": 1234,
        "train_seconds": seconds,
        "test": {
            "psnr": psnr,
            "ssim": ssim,
            "lpips": lpips,
            "profile": {"id": PROFILE},
            "num_views": 2,
            "per_view": [{"key": f"dnerf:mutant/test/{i}@100x100", "psnr": psnr} for i in range(2)],
        },
    }
    (out / expert).mkdir(parents=True)
    (out / expert / "metrics.json").write_text(json.dumps(result))
    config = to_dict(config_for(expert, "dnerf:mutant", "quick").config)  # the quick recipe's, as trained
    (out / expert / "config.json").write_text(json.dumps({"config": config}))


def printed(table, row, metrics=("PSNR", "SSIM", "LPIPS")):
    return " / ".join(table.cell(row, "Mutant", m)["printed"] for m in metrics)


@pytest.fixture
def runs(tmp_path):
    out = tmp_path / "runs"
    fake_run(out, "static", 22.5, 0.93, 0.08, 18.6)
    fake_run(out, "deformable", 25.25, 0.95, 0.04, 140.4)
    fake_run(out, "ed3dgs", 24.0, lpips=None)
    return out


def test_readme_section_rewritten_from_runs_and_published_tables(runs, tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text(README)
    args = [
        str(readme),
        "--experts",
        "static,deformable,ed3dgs",
        "--scene",
        "dnerf:mutant",
        "--out",
        str(runs),
    ]
    assert main([*args, "--quiet"]) == 0
    assert "README section 'mutant'" in capsys.readouterr().out
    text = readme.read_text()
    head, rest = text.split("<!-- results:mutant -->\n")
    body, tail = rest.split("<!-- /results:mutant -->")
    assert head == "# title\n\nintro\n\n" and tail == "\n\n## After\n" and "stale" not in body

    own, moegs = load_original_table("dnerf_mutant"), load_paper_table("tab17")
    lines = body.splitlines()
    row = next(line for line in lines if line.startswith("| deformable |"))
    assert row.startswith(
        "| deformable | DeformableGS | 25.25 | 0.9500 | 0.0400 | +2.75 | 140 | 1234 | 600 |"
    )
    sources = dict(re.findall(r"^(\d+)\. (.+)$", body, re.M))
    own_cell, moegs_cell = row.split(" | ")[-2:]
    ref = re.fullmatch(re.escape(printed(own, "DeformableGS")) + r" \[(\d)\]", own_cell).group(1)
    assert sources[ref] == own.cell("DeformableGS", "Mutant", "PSNR")["source"]
    ref = re.fullmatch(
        re.escape(printed(moegs, "DeformableGS", ["PSNR"])) + r" \(PSNR\) \[(\d)\] \|", moegs_cell
    )
    assert "MoE-GS paper, Table XVII" in sources[ref.group(1)]
    static = next(line for line in lines if line.startswith("| static |"))
    assert "| 3D-GS | 22.50 | 0.9300 | 0.0800 | – | 19 |" in static and printed(own, "3D-GS") in static
    ed3dgs = next(line for line in lines if line.startswith("| ed3dgs |"))
    assert "| 24.00 | 0.9000 | n/a | +1.50 |" in ed3dgs and ed3dgs.endswith("| – | – |")
    moe = next(line for line in lines if "MoE-GS (N=2)" in line)  # published row that no expert maps to
    assert moe.startswith("| – | MoE-GS (N=2) | – |") and printed(moegs, "MoE-GS (N=2)", ["PSNR"]) in moe
    grid4d = next(line for line in lines if "| Grid4D |" in line)  # no run: published numbers only
    assert grid4d.startswith("| – | Grid4D | – |") and printed(own, "Grid4D") in grid4d
    assert printed(moegs, "Grid4D", ["PSNR"]) in grid4d
    assert "100x100" in body and PROFILE in body
    assert len(sources) == 4  # DeformableGS Table 1 (2 rows), Grid4D README, MoE-GS Table XVII

    assert main([*args, "--quiet"]) == 0  # finished runs: same text again
    assert readme.read_text() == text


def test_readme_without_markers_fails(runs, tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("# no section\n")
    argv = [str(readme), "--experts", "static", "--scene", "dnerf:mutant", "--out", str(runs), "--quiet"]
    assert main(argv) == 2
    assert "<!-- results:mutant -->" in capsys.readouterr().err
    assert readme.read_text() == "# no section\n"
    empty = tmp_path / "none"  # no finished runs: the markers fail before any training starts
    assert main([*argv[:-2], str(empty), "--quiet"]) == 2 and not empty.exists()
    assert "<!-- results:mutant -->" in capsys.readouterr().err


def test_a_run_folder_in_use_is_one_line(runs, tmp_path, capsys, monkeypatch):
    """The runs folder locked by another moegs command (``moegs.guards``): one line, no traceback."""
    import moegs.compare
    from moegs.guards import FolderInUse

    readme = tmp_path / "README.md"
    readme.write_text("<!-- results:mutant -->\n<!-- /results:mutant -->\n")
    message = f"{runs} is in use by another moegs command (it holds the folder's lock)"

    def busy(*args, **kwargs):
        raise FolderInUse(message)

    monkeypatch.setattr(moegs.compare, "compare", busy)
    argv = [str(readme), "--experts", "static", "--scene", "dnerf:mutant", "--out", str(runs), "--quiet"]
    assert main(argv) == 2
    assert capsys.readouterr().err == f"bench.readme: {message}\n"


def test_section_without_published_numbers():
    table = {"scene": "synthetic:x", "preset": "quick", "rows": []}
    assert published_numbers("synthetic:x") == []
    text = readme_section(table, [], machine="test cpu")
    assert "Sources" not in text and "test cpu" in text


def test_published_tables_have_sources_and_known_rows():
    assert list_original_tables(), "no tables/paper/originals/*.json"
    for table_id in list_original_tables():
        table = load_original_table(table_id)
        assert all(v["source"] and v["printed"] for v in table.values)
    for scene, spec in PUBLISHED.items():
        entries = published_numbers(scene)
        assert len(entries) == len(spec["originals"]) + len(spec["moegs"])
        rows = {row for e in entries for row in e["rows"]}
        assert rows & {paper_name(e) for e in EXPERTS.values()}, rows


def test_a_published_row_of_two_tables_is_listed_once_and_nan_is_not_a_number():
    row = {"expert": "static", "psnr": float("nan"), "ssim": 0.9, "lpips": None, "train_seconds": 3.0,
           "num_gaussians": 10, "iterations": 5, "run": "runs/x/static"}  # fmt: skip
    table = {"scene": "dnerf:mutant", "preset": "quick", "rows": [row]}
    cell = {"printed": "30.00", "source": "a paper"}
    published = [
        {"kind": "original", "title": "own", "rows": {"MoE-GS (N=2)": {"PSNR": cell}}},
        {"kind": "moegs", "numeral": "XVII", "title": "moe", "rows": {"MoE-GS (N=2)": {"PSNR": cell}}},
    ]
    lines = readme_section(table, published, machine="cpu").splitlines()
    assert sum(line.startswith("| – | MoE-GS (N=2) |") for line in lines) == 1
    assert any(line.startswith("| static | 3D-GS | n/a | 0.9000 | n/a | – |") for line in lines)


def test_a_section_whose_end_comes_first_is_refused(tmp_path):
    from bench.readme import split_section

    path = tmp_path / "README.md"
    path.write_text("<!-- /results:mutant -->\nbody\n<!-- results:mutant -->\n")
    with pytest.raises(
        ValueError, match="README.md: needs exactly one '<!-- results:mutant -->' followed by"
    ):
        split_section(path, "mutant")
