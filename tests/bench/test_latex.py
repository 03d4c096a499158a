"""LaTeX of all 19 tables from an empty workspace (paper values, ours pending / not implemented): structure,
captions, and compilation (standalone and through ``all.tex``) when pdflatex is installed."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from bench.latex import check_structure, render_table, tex, write_index, write_table
from bench.plan import make_plan
from bench.presets import get_preset
from bench.registry import TABLE_IDS
from bench.store import Workspace
from bench.values import SpecValues


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    root = tmp_path_factory.mktemp("latex")
    preset = get_preset("quick")
    plan = make_plan(list(TABLE_IDS), preset)
    ws = Workspace(root / "ws")
    values = {sp.spec.id: SpecValues(sp, ws) for sp in plan.specs}
    paths = [write_table(v, preset, root / "tables") for v in values.values()]
    return {"root": root, "values": values, "paths": paths, "preset": preset}


@pytest.mark.parametrize("tid", TABLE_IDS)
def test_structure(tables, tid):
    text = render_table(tables["values"][tid], tables["preset"])
    assert check_structure(text) == [], tid
    assert r"\providecommand{\rankfirst}" in text and r"\begin{tabular}" in text


def test_paper_values_and_stand_in_labels(tables):
    text = (tables["root"] / "tables" / "tab03.tex").read_text()
    assert r"\paperref{33.23}" in text, "paper value printed beside ours"
    if tables["values"]["tab03"].plan.uses_stand_in:
        assert "synthetic stand-in" in text and r"Stand-in\textsuperscript{s}" in text
    t01 = (tables["root"] / "tables" / "tab01.tex").read_text()
    assert r"$\circ$" in t01 and r"$\triangle$" in t01


def test_structure_check_catches_errors():
    assert check_structure(r"\begin{tabular}{lc} a & b & c \\ \end{tabular}")
    assert check_structure(r"\begin{table}{")
    assert tex("a_b & 50% †") == r"a\_b \& 50\% \textsuperscript{\textdagger}"


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="no TeX engine; structure is checked above")
def test_compiles(tables):
    folder = tables["root"] / "tables"
    write_index(tables["paths"], folder)
    for name in ("all.tex", "tab03.tex", "tab12.tex"):
        proc = subprocess.run(
            ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", name],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, f"{name}: {proc.stdout[-1500:]}"
