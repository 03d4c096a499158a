r"""``tables/paper/*.json`` against the paper's LaTeX, re-parsed here independently of how the JSON was made.

Rule for which numbers count (the "body" of a table):
  * Each ``tabular`` of a ``table``/``table*`` environment is read from its first ``\midrule`` (the end
    of the header) to ``\bottomrule``. Header numbers ("100\%", "N=2" in captions, citations) are
    never counted. Later ``\midrule``/``\cmidrule``/``\addlinespace`` inside the body are separators.
  * Rows split at top-level ``\\``, cells at unescaped ``&``; ``\multicolumn{n}`` expands to n cells.
  * The leading *label* cells are not data: as many as the tabular spec has columns before its first
    ``|`` (e.g. ``cc|ccc`` -> 2), or 1 when the spec has no ``|``. So "MoE-GS (N=2)", "55\% pruning",
    "3DGS-MCMC" never count. A two-column label is "<first> / <second>", the first carried down a
    ``\multirow``.
  * Every other cell is data: each number in it is a token (``\d+(\.\d+)?`` after stripping
    formatting), N/A cells give none, and a non-numeric cell (Table I's ○/△/×) is one symbol token.
    A cell wrapped in ``\textbf`` is a "best" marker.
Checks: (a) same tables in the same order with the same labels (19); (b) per table the multiset of
numbers is equal both ways (exactly, after parsing the printed decimal) and so is the printed text;
per row the tokens sit under the printed row name in printed order; the JSON's column names occur in
that order in the header text (rows above the first ``\midrule``); bold cells are exactly the JSON's
``marked == "best"``; (c) metadata fields present and consistent.
The paper source is ``bench.paper.paper_tex_path()`` (``$MOEGS_PAPER`` overrides); without it the
LaTeX checks skip.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from bench.paper import FRAME_COLUMNS, list_paper_tables, load_paper_table, paper_tex_path, paper_value

ROMAN = "I II III IV V VI VII VIII IX X XI XII XIII XIV XV XVI XVII XVIII XIX XX".split()
NUMBER = re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?![\w.])")
METADATA = {
    "id": str,
    "label": str,
    "caption": str,
    "numeral": str,
    "datasets": list,
    "expert_sets": dict,
    "rows": list,
    "columns": list,
    "metrics": list,
    "notes": str,
    "values": list,
}
VALUE_KEYS = {"row", "column", "metric", "value", "printed", "unit", "higher_is_better", "marked"}


# ---------------------------------------------------------------- a small LaTeX table reader
@dataclass
class Row:
    label: str
    tokens: list[str]  # data tokens in printed order
    bold: list[str]  # the tokens of \textbf cells


@dataclass
class LatexTable:
    label: str
    header: str  # plain text of the header rows of all sub-tables, in order
    rows: list[Row]


def _split(text: str, sep: str) -> list[str]:
    """Split at ``sep`` outside braces, skipping escaped characters (``\\&``, ``\\%``)."""
    parts, depth, start, i = [], 0, 0, 0
    while i < len(text):
        if text[i] == "\\" and not text.startswith(sep, i):
            i += 2
            continue
        if text[i] in "{}":
            depth += 1 if text[i] == "{" else -1
        elif depth == 0 and text.startswith(sep, i):
            parts.append(text[start:i])
            i = start = i + len(sep)
            continue
        i += 1
    return parts + [text[start:]]


def _arg(text: str, at: int) -> tuple[str, int]:
    """The brace group starting at ``text[at] == '{'``: (content, index after it)."""
    depth = 0
    for j in range(at, len(text)):
        depth += {"{": 1, "}": -1}.get(text[j], 0)
        if depth == 0:
            return text[at + 1 : j], j + 1
    raise ValueError(f"unbalanced braces in {text[at : at + 60]!r}")


def _clean(cell: str) -> str:
    """Plain text of a cell: citations, colours and font commands removed, daggers as '†'."""
    s = re.sub(r"\\cite\{[^}]*\}|\\(rowcolor|cellcolor)\{[^}]*\}|\\raisebox\{[^}]*\}", "", cell)
    s = re.sub(r"\\multirow\{[^}]*\}\{[^}]*\}", "", s)
    s = re.sub(r"\{?\\small\s*\\textdagger\}?|\\textsuperscript\{\\textdagger\}", "†", s)
    s = re.sub(r"\\(text|mbox)\{-\}", "-", s).replace(r"\NA", "N/A")
    s = re.sub(r"\\([%&])", r"\1", s)
    s = re.sub(r"\\(textbf|footnotesize|small)\b", "", s).replace("~", " ")
    s = re.sub(r"[{}$]", "", s)
    return re.sub(r"\s*†", "†", re.sub(r"\s+", " ", s)).strip()


def _header_text(head: str) -> str:
    """Plain text of header rows: spans and rules dropped, ``\\tworow{a}{b}`` -> "a b", commands removed."""
    head = re.sub(r"\\multicolumn\{\d+\}\{[^}]*\}|\\cmidrule(\([^)]*\))?\{[^}]*\}", " ", head)
    head = head.replace(r"\!", "").replace(r"\,", " ")
    head = _clean(re.sub(r"\\tworow\{([^{}]*)\}\{([^{}]*)\}", r"\1 \2", head))
    return re.sub(r"\s+", " ", re.sub(r"\\[a-zA-Z]+|\\\\", " ", head))


def _cells(line: str) -> list[str]:
    """Cells of one row, ``\\multicolumn{n}{spec}{x}`` expanded to x plus n-1 empty cells."""
    out = []
    for cell in _split(line, "&"):
        m = re.search(r"\\multicolumn\{(\d+)\}\{[^}]*\}\s*", cell)
        if m:
            content, end = _arg(cell, m.end())
            out += [cell[: m.start()] + content + cell[end:]] + [""] * (int(m.group(1)) - 1)
        else:
            out.append(cell)
    return out


def read_latex_tables(tex: str) -> list[LatexTable]:
    tex = re.sub(r"(?<!\\)%.*", "", tex)  # comments
    tables = []
    for env in re.findall(r"\\begin\{table\*?\}(.*?)\\end\{table\*?\}", tex, re.S):
        label = re.search(r"\\label\{([^}]*)\}", env).group(1)
        rows, carried, header = [], "", ""
        for m in re.finditer(r"\\begin\{tabular\}", env):
            spec, after = _arg(env, m.end())
            body = env[after : env.index(r"\end{tabular}", after)]
            spec = re.sub(r"@\{[^}]*\}", "", spec)
            n_cols = len(re.findall(r"[lcrp]", spec))
            n_label = len(re.findall(r"[lcrp]", spec.split("|")[0])) if "|" in spec else 1
            head, body = body.split(r"\midrule", 1)
            header += " " + _header_text(head)
            body = body.split(r"\bottomrule", 1)[0]
            body = re.sub(r"\\midrule|\\cmidrule(\([^)]*\))?\{[^}]*\}|\\addlinespace(\[[^]]*\])?", "", body)
            for line in _split(body, r"\\"):
                if not line.strip():
                    continue
                cells = _cells(line)
                # Tables XII and XIII declare 11 columns and use 10, so allow fewer, never more.
                assert n_label < len(cells) <= n_cols, f"{label}: {len(cells)} cells, spec {n_cols}: {line!r}"
                labels = [_clean(c) for c in cells[:n_label]]
                if n_label == 2:
                    carried = labels[0] or carried
                    labels = [carried, labels[1]]
                tokens, bold = [], []
                for cell in cells[n_label:]:
                    text = _clean(cell)
                    found = NUMBER.findall(text) or ([text] if text and text != "N/A" else [])
                    tokens += found
                    bold += found if r"\textbf" in cell else []
                rows.append(Row(" / ".join(labels), tokens, bold))
        tables.append(LatexTable(label, header, rows))
    return tables


# ---------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def latex() -> list[LatexTable]:
    path = paper_tex_path()
    if not path.is_file():
        pytest.skip(f"paper source not found at {path}; set MOEGS_PAPER to moe-gs-mode.tex")
    return read_latex_tables(path.read_text(encoding="utf-8"))


def _pair(latex: list[LatexTable], table_id: str):
    index = int(table_id.removeprefix("tab")) - 1
    assert index < len(latex), f"{table_id}: the LaTeX has only {len(latex)} tables"
    return latex[index], load_paper_table(table_id)


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


# ---------------------------------------------------------------- tests
def test_same_tables_in_same_order(latex):
    ids = list_paper_tables()
    assert ids == [f"tab{i:02d}" for i in range(1, len(ids) + 1)], ids
    assert len(latex) == len(ids) == 19
    assert [t.label for t in latex] == [load_paper_table(i).label for i in ids]


@pytest.mark.parametrize("table_id", list_paper_tables())
def test_metadata(table_id):
    t = load_paper_table(table_id)
    for key, kind in METADATA.items():
        assert isinstance(getattr(t, key), kind), f"{table_id}.{key} should be {kind.__name__}"
    n = int(table_id.removeprefix("tab"))
    assert (t.id, t.numeral) == (table_id, ROMAN[n - 1])
    assert t.caption and t.rows and t.columns and t.metrics and t.values
    for v in t.values:
        assert set(v) == VALUE_KEYS, f"{table_id}: keys {sorted(v)}"
        assert v["row"] in t.rows and v["column"] in t.columns and v["metric"] in t.metrics, v
        assert v["marked"] in ("best", "second", None), v
        if _is_number(v["value"]):
            assert v["value"] == float(v["printed"]), v
            assert isinstance(v["higher_is_better"], bool), v
        else:
            assert v["value"] == v["printed"], v
    assert not t.frame().duplicated(["row", "column", "metric"]).any(), f"{table_id}: duplicate cells"


@pytest.mark.parametrize("table_id", list_paper_tables())
def test_numbers_match_latex(latex, table_id):
    """Every number of the LaTeX body is in the JSON and vice versa (multisets, exact)."""
    tex, t = _pair(latex, table_id)
    tex_tokens = [tok for r in tex.rows for tok in r.tokens]
    in_tex = Counter(float(tok) for tok in tex_tokens if NUMBER.fullmatch(tok))
    in_json = Counter(float(v["value"]) for v in t.values if _is_number(v["value"]))
    assert in_tex == in_json, f"{table_id}: only in LaTeX {in_tex - in_json}, only in JSON {in_json - in_tex}"
    assert Counter(tex_tokens) == Counter(v["printed"] for v in t.values), f"{table_id}: printed text differs"


@pytest.mark.parametrize("table_id", list_paper_tables())
def test_rows_match_latex(latex, table_id):
    """Each row's values sit under the printed row name, in printed order (sub-tables concatenated)."""
    tex, t = _pair(latex, table_id)
    expected: dict[str, list[str]] = {}
    for r in tex.rows:
        expected.setdefault(r.label, []).extend(r.tokens)
    got: dict[str, list[str]] = {}
    for v in t.values:
        got.setdefault(v["row"], []).append(v["printed"])
    assert list(expected) == t.rows, f"{table_id}: row names {list(expected)} vs {t.rows}"
    assert got == expected


@pytest.mark.parametrize("table_id", list_paper_tables())
def test_bold_is_marked_best(latex, table_id):
    tex, t = _pair(latex, table_id)
    bold = Counter((r.label, tok) for r in tex.rows for tok in r.bold)
    marked = Counter((v["row"], v["printed"]) for v in t.values if v["marked"] == "best")
    assert bold == marked, f"{table_id}: bold only in LaTeX {bold - marked}, only in JSON {marked - bold}"


@pytest.mark.parametrize("table_id", list_paper_tables())
def test_columns_in_header(latex, table_id):
    """The JSON's column names are printed in the LaTeX header, in the same order."""
    tex, t = _pair(latex, table_id)
    at = 0
    for name in t.columns:
        found = tex.header.find(name, at)
        assert found >= 0, f"{table_id}: column {name!r} not in {tex.header[at:]!r} (header {tex.header!r})"
        at = found + len(name)


def test_loader_api():
    assert paper_value("tab03", "MoE-GS (N=3)", "Average", "PSNR") == 33.23
    assert paper_value("tab05", "Ex4DGS", "FPS") == 120  # metric may be left out when unique
    frame = load_paper_table("tab13").frame()
    assert list(frame.columns) == list(FRAME_COLUMNS) and len(frame) == 102  # 108 cells, 6 N/A
    with pytest.raises(KeyError, match="valid: 'tab01'"):
        load_paper_table("tab20")
    with pytest.raises(KeyError, match="unknown row 'MoE-GS'.*'MoE-GS \\(N=4\\)'"):
        paper_value("tab03", "MoE-GS", "Average")
    with pytest.raises(KeyError, match="several metrics"):
        paper_value("tab12", "Ex4DGS", "Flame Steak")


def test_loader_imports_without_torch():
    code = "import sys, bench.paper; assert 'torch' not in sys.modules, 'bench.paper imported torch'"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])


def test_numbers_printed_in_the_text_and_unknown_metrics(monkeypatch, tmp_path):
    import bench.paper
    from bench.paper import load_paper_numbers, paper_tex_path

    roi = load_paper_numbers("static_roi")  # numbers of a sentence of Sec. IV-C (iv), not of a table
    assert roi.value("MoE-GS (N=3)*", "Coffee Martini", "PSNR static") == 22.23
    with pytest.raises(KeyError, match="tab03: unknown metric 'PSNR dynamic'"):
        paper_value("tab03", "MoE-GS (N=3)", "Average", "PSNR dynamic")
    monkeypatch.setenv("MOEGS_PAPER", str(tmp_path / "paper.tex"))
    assert paper_tex_path() == tmp_path / "paper.tex"
    (tmp_path / "unsourced.json").write_text(
        json.dumps({**{k: v for k, v in vars(roi).items() if k != "values"}, "values": [{"row": "x"}]})
    )
    monkeypatch.setattr(bench.paper, "PAPER_ORIGINALS_DIR", tmp_path)
    with pytest.raises(ValueError, match="originals/unsourced.json: values without a source"):
        bench.paper.load_original_table("unsourced")
