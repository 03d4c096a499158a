r"""LaTeX tables: the paper's layout, each cell ``ours (paper, Δ)``, booktabs, rank macros.

Every ``tables/tabNN.tex`` is dual-use: ``\input`` it into a document that loads ``booktabs`` and
``graphicx``, or compile it directly (``pdflatex tables/tab03.tex``): when read before any
``\documentclass`` it opens a minimal ``article`` itself. All macros are ``\providecommand``-ed, so a
host document can restyle them:

* ``\rankfirst`` / ``\ranksecond`` / ``\rankthird``: our best / second / third value of a column;
* ``\paperref{p}``: the paper's value when ours is not comparable (stand-in data);
* ``\paperdelta{p}{d}``: the paper's value and Δ = ours − paper (ours on the paper's real scene);
* ``\dynregion{v}``: beside our PSNR, the PSNR of the dynamic region of the same cell;
* ``\oursmissing``, ``\oursni``, ``\oursfail``, ``\ourspending``, ``\oursext``: no value of ours.

Numbers come only from result JSONs and ``tables/paper``.
"""

from __future__ import annotations

import re
from pathlib import Path

from bench.presets import BenchPreset
from bench.results import write_text_atomic
from bench.spec import metric
from bench.values import AVERAGE, STAND_IN, OurCell, SpecValues

MACROS = r"""\providecommand{\rankfirst}[1]{\textbf{#1}}
\providecommand{\ranksecond}[1]{\underline{#1}}
\providecommand{\rankthird}[1]{#1}
\providecommand{\paperref}[1]{{\scriptsize\,(#1)}}
\providecommand{\paperdelta}[2]{{\scriptsize\,(#1, $#2$)}}
\providecommand{\dynregion}[1]{{\scriptsize\,[#1]}}
\providecommand{\oursmissing}{--}
\providecommand{\oursni}{n/i}
\providecommand{\oursfail}{fail}
\providecommand{\ourspending}{?}
\providecommand{\oursext}{ext.}
"""

PREAMBLE = r"""\makeatletter
\ifx\@onlypreamble\@notprerr\makeatother\else\makeatother
  \documentclass{article}
  \usepackage[T1]{fontenc}
  \usepackage{booktabs,graphicx}
  \begin{document}
  \def\moegsendstandalone{\end{document}}
\fi
"""
POSTAMBLE = "\\ifdefined\\moegsendstandalone\\expandafter\\moegsendstandalone\\fi\n"

_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "†": r"\textsuperscript{\textdagger}",
    "Δ": r"$\Delta$",
    "−": "-",
    "≥": r"$\geq$",
    "≤": r"$\leq$",
    "○": r"$\circ$",
    "△": r"$\triangle$",
    "×": r"$\times$",
    "—": "--",
    "–": "--",
    "→": r"$\rightarrow$",
    "·": r"$\cdot$",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
}
_SYMBOL_STATUS = {
    "not implemented yet": r"\oursni",
    "failed": r"\oursfail",
    "pending": r"\ourspending",
    "external": r"\oursext",
}


def tex(text: str) -> str:
    """Escape plain text for LaTeX (non-ASCII characters without a mapping become '?')."""
    out = []
    for ch in str(text):
        if ch in _SPECIAL:
            out.append(_SPECIAL[ch])
        elif ord(ch) < 128:
            out.append(ch)
        else:
            out.append("?")
    return "".join(out)


def fmt(value: float, metric_name: str) -> str:
    return f"{value:.{metric(metric_name).digits}f}"


def fmt_delta(delta: float, metric_name: str) -> str:
    return f"{delta:+.{metric(metric_name).digits}f}"


def _ranks(values: SpecValues, column: str, metric_name: str) -> dict[str, int]:
    """Rank (0 = best) of each row having our value in this column."""
    scored = [
        (r.name, values.cells[(r.name, column, metric_name)].value)
        for r in values.spec.rows
        if values.cells.get((r.name, column, metric_name), OurCell(None, "")).value is not None
    ]
    if len(scored) < 2:
        return {}
    sign = -1.0 if metric(metric_name).higher_is_better else 1.0
    ordered = sorted({v for _, v in scored}, key=lambda v: sign * v)
    return {name: ordered.index(v) for name, v in scored}


def _status_symbol(cell: OurCell) -> str:
    for prefix, sym in _SYMBOL_STATUS.items():
        if cell.status.startswith(prefix):
            return sym
    return r"\oursmissing"


def cell_tex(values: SpecValues, row: str, column: str, metric_name: str, ranks: dict[str, int]) -> str:
    """``ours (paper, Δ)`` of one cell."""
    cell = values.cells.get((row, column, metric_name), OurCell(None, "n/a"))
    paper_col = AVERAGE if column == STAND_IN else column
    printed = values.paper.printed(row, paper_col, metric_name)
    if cell.value is None:
        ours = _status_symbol(cell)
    else:
        ours = fmt(cell.value, metric_name)
        rank = ranks.get(row)
        if rank is not None and rank < 3:
            ours = ("\\rankfirst{", "\\ranksecond{", "\\rankthird{")[rank] + ours + "}"
        dynamic = values.get(row, column, DYNAMIC) if metric_name == "PSNR" else None
        if dynamic is not None:
            ours += f"\\dynregion{{{fmt(dynamic, DYNAMIC)}}}"
    if printed is None or (column == STAND_IN and cell.value is None):
        return ours  # the stand-in column shows the paper's Average only beside a value of ours
    if cell.value is not None and cell.comparable:
        paper = values.paper.get(row, paper_col, metric_name)
        return f"{ours}\\paperdelta{{{tex(printed)}}}{{{fmt_delta(cell.value - paper, metric_name)}}}"
    return f"{ours}\\paperref{{{tex(printed)}}}"


DYNAMIC = "PSNR dynamic"


def _column_header(column: str) -> str:
    if column == STAND_IN:
        return r"Stand-in\textsuperscript{s}"
    return tex(column)


def _tabular(values: SpecValues, metric_name: str | None) -> list[str]:
    cols = values.display_columns
    lines = [r"\begin{tabular}{l|" + "c" * len(cols) + "}", r"\toprule"]
    if metric_name is not None:
        arrow = r"$\uparrow$" if metric(metric_name).higher_is_better else r"$\downarrow$"
        lines.append(f" & \\multicolumn{{{len(cols)}}}{{c}}{{{tex(metric_name)} {arrow}}} \\\\")
        lines.append(f"\\cmidrule(lr){{2-{len(cols) + 1}}}")
    lines.append("Model & " + " & ".join(_column_header(c) for c in cols) + r" \\")
    lines.append(r"\midrule")
    metric_of = (lambda c: metric_name) if metric_name is not None else (lambda c: values.metrics_of(c)[0])
    ranks = {c: _ranks(values, c, metric_of(c)) for c in cols}
    for row in values.spec.rows:
        cells = [cell_tex(values, row.name, c, metric_of(c), ranks[c]) for c in cols]
        lines.append(tex(row.display) + " & " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return lines


def _qualitative(values: SpecValues) -> list[str]:
    table = values.paper_table
    cols = list(table.columns) if table else []
    lines = [
        r"\begin{tabular}{l|" + "c" * len(cols) + "|l}",
        r"\toprule",
        "Property & " + " & ".join(tex(c) for c in cols) + r" & Evidence in this suite \\",
        r"\midrule",
    ]
    for row in values.spec.rows:
        syms = [tex(values.paper.printed(row.name, c, "Support") or "") for c in cols]
        lines.append(
            f"{tex(row.name)} & " + " & ".join(syms) + f" & {tex(row.params.get('evidence', ''))}" + r" \\"
        )
    lines += [r"\bottomrule", r"\end{tabular}"]
    return lines


def caption(values: SpecValues, preset: BenchPreset) -> str:
    spec, table = values.spec, values.paper_table
    head = f"Table {table.numeral} ({table.label}) reproduced: {spec.title}." if table else f"{spec.title}."
    if spec.axis == "none":
        return tex(head + " Qualitative: the paper's symbols, nothing computed.")
    parts = [
        head,
        "Each cell: ours (paper, Δ = ours - paper); Δ only where ours was computed on the paper's "
        "real scene(s), otherwise ours (paper).",
    ]
    scale = f"Preset {preset.name}: {preset.description}."
    parts.append(("Reduced scale. " if preset.reduced else "") + scale)
    if values.plan.scenes:
        stand = [s for s in values.plan.scenes if not s.real]
        parts.append("Scenes: " + ", ".join(s.label for s in values.plan.scenes) + ".")
        if stand:
            parts.append(
                "s: synthetic stand-in scene (numbers not comparable with the paper; the paper value "
                "shown beside it is its Average)."
            )
    averaged = values.plan.averaged_seeds()
    if averaged:
        parts.append(
            "Mean over seeds: "
            + ", ".join(f"{name} {seeds[0]}-{seeds[-1]}" for name, seeds in sorted(averaged.items()))
            + "; claims within their seed spread are 'within noise' (report)."
        )
    parts.append(
        "[x]: PSNR of the dynamic region (stand-ins: ground-truth dynamic mask; D-NeRF: object alpha; "
        "Panoptic: foreground masks)."
    )
    missing = values.missing_pieces()
    if missing:
        parts.append("n/i: not implemented yet in the library (missing: " + ", ".join(missing) + ").")
    parts.append(
        "--: not computed; ext.: method outside the suite (paper value only); fail: see report; "
        "?: not run yet."
    )
    return tex(" ".join(parts))


def render_table(values: SpecValues, preset: BenchPreset, header: str = "") -> str:
    """The complete ``tabNN.tex`` text."""
    spec = values.spec
    label = f"moegs:{spec.id}"
    body: list[str] = []
    if spec.axis == "none":
        body += _qualitative(values)
    elif spec.axis == "scenes" and len(spec.metrics) > 1:
        for i, m in enumerate(spec.metrics):
            if i:
                body.append(r"\par\medskip")
            body += [r"\resizebox{\linewidth}{!}{%", *_tabular(values, m), "}"]
    else:
        wide = len(values.display_columns) > 5
        tab = _tabular(values, spec.metrics[0] if spec.axis in ("scenes", "seeds", "budgets") else None)
        body += [r"\resizebox{\linewidth}{!}{%", *tab, "}"] if wide else tab
    lines = [
        f"% {header}".rstrip(),
        "% Generated by `python -m bench.all`; do not edit. Needs booktabs and graphicx.",
        PREAMBLE.rstrip(),
        MACROS.rstrip(),
        r"\begin{table}[t]",
        r"\centering",
        r"\scriptsize",
        f"\\caption{{{caption(values, preset)}}}",
        f"\\label{{{label}}}",
        *body,
        r"\end{table}",
        POSTAMBLE.rstrip(),
    ]
    return "\n".join(lines) + "\n"


def write_table(values: SpecValues, preset: BenchPreset, out_dir: Path, header: str = "") -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{values.spec.id}.tex"
    write_text_atomic(path, render_table(values, preset, header))
    return path


def write_index(paths: list[Path], out_dir: Path) -> Path:
    """``all.tex``: one document with every generated table."""
    lines = [
        r"\documentclass{article}",
        r"\usepackage[T1]{fontenc}",
        r"\usepackage{booktabs,graphicx}",
        r"\begin{document}",
    ]
    lines += [f"\\input{{{p.stem}}}\n\\clearpage" for p in paths]
    lines.append(r"\end{document}")
    path = out_dir / "all.tex"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


# ---------------------------------------------------------------- structural check (no TeX engine needed)
_ENV = re.compile(r"\\(begin|end)\{([^}]+)\}")


def check_structure(text: str) -> list[str]:
    """Problems found without a TeX engine: unbalanced braces/environments, wrong cell counts per row."""
    problems = []
    depth = 0
    stripped = re.sub(r"(?<!\\)%.*", "", text)
    i = 0
    while i < len(stripped):
        ch = stripped[i]
        if ch == "\\":
            i += 2
            continue
        depth += {"{": 1, "}": -1}.get(ch, 0)
        if depth < 0:
            problems.append(f"unbalanced '}}' at character {i}")
            depth = 0
        i += 1
    if depth:
        problems.append(f"{depth} unclosed '{{'")
    stack = []
    for kind, name in _ENV.findall(stripped):
        if kind == "begin":
            stack.append(name)
        elif not stack or stack.pop() != name:
            problems.append(f"\\end{{{name}}} does not match the open environment")
    # the standalone preamble opens `document` conditionally; it is closed by \moegsendstandalone
    if [s for s in stack if s != "document"]:
        problems.append(f"unclosed environments {stack}")
    for m in re.finditer(r"\\begin\{tabular\}\{([^}]*)\}(.*?)\\end\{tabular\}", stripped, re.S):
        ncols = len(re.sub(r"[^lcrp]", "", m.group(1)))
        body = m.group(2)
        for line in body.split("\\\\"):
            line = re.sub(r"\\(toprule|midrule|bottomrule|cmidrule\(lr\)\{[^}]*\})", "", line).strip()
            if not line:
                continue
            cells = _count_cells(line)
            if cells != ncols:
                problems.append(f"row has {cells} cells, tabular has {ncols}: {line[:60]!r}")
    return problems


def _count_cells(line: str) -> int:
    count, depth, i = 1, 0, 0
    span_total = 0
    for m in re.finditer(r"\\multicolumn\{(\d+)\}", line):
        span_total += int(m.group(1)) - 1
    while i < len(line):
        ch = line[i]
        if ch == "\\":
            i += 2
            continue
        if ch in "{}":
            depth += 1 if ch == "{" else -1
        elif ch == "&" and depth == 0:
            count += 1
        i += 1
    return count + span_total
