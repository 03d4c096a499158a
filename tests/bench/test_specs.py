"""Specs: one per paper table, rows match the paper, claims hold on the paper's own numbers, ids parse,
and listing needs no torch."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bench.claims import CHECKS, HELD, evaluate
from bench.paper import (
    PAPER_TEXT_DIR,
    list_paper_tables,
    load_paper_numbers,
    load_paper_table,
    paper_tex_path,
)
from bench.registry import TABLE_IDS, figure_ids, get_spec, list_specs, normalize_id, parse_selection
from bench.spec import METRICS, Metric, Spec, by_name
from bench.values import AVERAGE, PaperValues


def test_registries_keep_their_order_and_refuse_a_repeated_name():
    from bench.datasets import DATASETS
    from bench.presets import PRESETS

    assert list(PRESETS) == ["tiny", "quick", "quick32", "standard", "paper"]
    assert list(METRICS)[:3] == ["PSNR", "SSIM", "LPIPS"]
    assert all(name == item.name for table in (METRICS, DATASETS, PRESETS) for name, item in table.items())
    twice = (Metric("PSNR", "psnr", True, 2), Metric("PSNR", "psnr_x", True, 2))
    with pytest.raises(ValueError, match="two metrics are named 'PSNR'"):
        by_name(twice, "metrics")


def test_one_spec_per_paper_table():
    assert list(TABLE_IDS) == list_paper_tables()
    for tid in TABLE_IDS:
        spec = get_spec(tid)
        assert isinstance(spec, Spec) and spec.id == tid and spec.paper == tid and not spec.figure


@pytest.mark.parametrize("tid", TABLE_IDS)
def test_rows_and_columns_follow_the_paper(tid):
    spec, paper = get_spec(tid), load_paper_table(tid)
    names = [r.name for r in spec.rows if not r.variant]
    assert names == paper.rows, "rows must be the paper's rows in the paper's order"
    variants = [i for i, r in enumerate(spec.rows) if r.variant]
    assert variants == list(range(len(names), len(spec.rows))), "variant rows follow the paper's rows"
    for col in spec.columns:
        assert col in paper.columns
    for m in spec.metrics:
        assert m in METRICS
    if spec.axis == "metrics":
        assert {spec.metric_of_column(c) for c in paper.columns} <= set(METRICS)


def _paper_view(spec: Spec) -> PaperValues:
    table = load_paper_numbers(spec.paper)
    scenes = [c for c in table.columns if c != AVERAGE] if spec.axis == "scenes" else []
    return PaperValues(table, scenes)


@pytest.mark.parametrize("sid", [s for s in list_specs() if get_spec(s).paper])
def test_claims_hold_on_the_papers_numbers(sid):
    """Each claim, checked on the paper's own numbers, holds: the claim is encoded as the paper states it."""
    spec = get_spec(sid)
    row_names = {r.name for r in spec.rows}
    view = _paper_view(spec)
    for claim in spec.claims:
        assert claim.check in CHECKS
        for key in ("a", "b", "row", "rows", "among", "others"):
            value = claim.args.get(key)
            names = [value] if isinstance(value, str) else list(value or [])
            assert set(names) <= row_names, f"{sid}/{claim.id}: unknown rows {set(names) - row_names}"
        result = evaluate(claim, view)
        unprinted = (
            claim.args.get("metric", "PSNR") not in view.table.metrics
        )  # e.g. full-image PSNR of a figure
        if result.status == "n/a" and unprinted:
            continue
        assert result.status == HELD, (
            f"{sid}/{claim.id} on the paper's numbers: {result.status}: {result.detail}"
        )


def test_figure_specs():
    ids = figure_ids()
    assert {
        "fig01",
        "fig_gates",
        "fig_trajectories",
        "fig_mdc",
        "fig_static_roi",
        "fig_mode_tradeoff",
    } <= set(ids)
    for fid in ids:
        spec = get_spec(fid)
        assert spec.figure and spec.claims, fid


def test_in_text_numbers_match_the_paper_source():
    import json

    tex = paper_tex_path()
    if not tex.is_file():
        pytest.skip(f"paper source not found at {tex}")
    text = tex.read_text(encoding="utf-8")
    paths = sorted(PAPER_TEXT_DIR.glob("*.json"))
    assert paths, f"no in-text number files under {PAPER_TEXT_DIR}"
    for path in paths:
        data = json.loads(path.read_text())
        assert data["source_sentence"] in text, path
        for v in data["values"]:
            assert v["printed"] in data["source_sentence"], (path, v)


@pytest.mark.parametrize(
    "text,expected",
    [
        ("tab03", "tab03"),
        ("3", "tab03"),
        ("03", "tab03"),
        ("tab3", "tab03"),
        ("repro-tab3", "tab03"),
        ("repro-tab17", "tab17"),
        ("XVII", "tab17"),
        ("fig_mdc", "fig_mdc"),
        ("repro-fig01", "fig01"),
    ],
)
def test_normalize_id(text, expected):
    assert normalize_id(text) == expected


def test_unknown_id_lists_the_valid_ones():
    with pytest.raises(KeyError, match="valid ids: tab01, tab02"):
        normalize_id("tab42")


def test_selection_forms():
    assert parse_selection(["3,17", "fig_mdc"]) == ["tab03", "tab17", "fig_mdc"]
    assert parse_selection(None) == list_specs()
    assert parse_selection(["tables"]) == list(TABLE_IDS)


def test_listing_imports_no_torch():
    code = (
        "import sys; from bench.registry import list_specs, get_spec; [get_spec(s) for s in list_specs()]; "
        "from bench.all import list_table; list_table(); assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_claim_constructors_build_the_common_forms():
    from bench.spec import beats_every_scene, beats_on_average

    every = beats_every_scene("n2-every-scene", "MoE-GS (N=2)", ["Ex4DGS", "STG†"], "Table III")
    assert (every.check, dict(every.args)) == (
        "better",
        {"a": "MoE-GS (N=2)", "b": ["Ex4DGS", "STG†"], "columns": "@scenes"},
    )
    assert every.text == "MoE-GS (N=2) beats Ex4DGS and STG† on every scene"
    average = beats_on_average("n3-gt-n2", "MoE-GS (N=3)", ["MoE-GS (N=2)"], "Table III")
    assert dict(average.args) == {"a": "MoE-GS (N=3)", "b": ["MoE-GS (N=2)"]}
    assert average.text == "MoE-GS (N=3) has a better average than MoE-GS (N=2)"
    three = beats_every_scene("x", "MoE-GS (N=3)", ["STG", "E-D3DGS", "Ex4DGS"], "Table IV")
    assert three.text == "MoE-GS (N=3) beats STG, E-D3DGS and Ex4DGS on every scene"


def test_mode_family_is_the_baseline_and_its_variants():
    from bench.spec import mode_family

    rows = mode_family("Grid4D", "4DGaussians", "E-D3DGS")
    assert [r.name for r in rows] == ["Grid4D", "Grid4D w/ 4DGaussians", "Grid4D w/ E-D3DGS"]
    assert [r.kind for r in rows] == ["expert", "mode", "mode"]
    assert rows[2].params["experts"] == ["grid4d", "ed3dgs"] and rows[2].params["base"] == "grid4d"


def test_paper_numbers_default_to_the_table_id_and_figures_have_none():
    from bench.spec import Spec, expert

    assert Spec(id="tab99", title="t", dataset="n3v", rows=(expert("STG"),)).paper == "tab99"
    figure = Spec(id="fig_x", title="t", dataset="n3v", rows=(expert("STG"),), figure=True)
    assert figure.paper == "" and figure.axis == "scenes"
