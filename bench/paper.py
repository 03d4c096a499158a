"""The paper's published numbers, one JSON file per table in ``tables/paper/`` (stdlib, no torch; pandas
only for ``PaperTable.frame``).

Each ``tabNN.json`` holds one table of the paper in long format: a list of values, one per printed
cell, with ``row``, ``column``, ``metric``, ``value``, the ``printed`` text (keeps trailing zeros,
e.g. ``"0.930"``), ``unit``, ``higher_is_better`` and ``marked`` (``"best"`` for a bold cell, else
``None``). Tables are numbered in the paper's order, ``tab01`` (Table I) .. ``tab19`` (Table XIX).
These files are the only hand-typed numbers in the project; ``tests/bench/test_paper_tables.py``
checks them against the LaTeX source. ``tables/paper/originals/*.json`` (same schema, plus a ``source``
citation per value) hold numbers that the experts' own papers publish (``load_original_table``).

    >>> from bench.paper import load_paper_table, paper_value
    >>> paper_value("tab03", "MoE-GS (N=3)", "Average", "PSNR")
    33.23
    >>> load_paper_table("tab13").frame().query("metric == 'SSIM'").shape[0]
    30
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_REPO = Path(__file__).resolve().parent.parent
PAPER_TABLES_DIR = _REPO / "tables" / "paper"
#: Numbers the paper prints in its text rather than in a table (same schema plus ``source_sentence``).
PAPER_TEXT_DIR = PAPER_TABLES_DIR / "text"
#: Numbers the experts' own papers publish (DeformableGS, 3D-GS ...), not the MoE-GS paper: same schema,
#: plus a ``source`` citation on every value. Not checked against the MoE-GS LaTeX.
PAPER_ORIGINALS_DIR = PAPER_TABLES_DIR / "originals"
#: Columns of :meth:`PaperTable.frame`, in order.
FRAME_COLUMNS = ("row", "column", "metric", "value", "printed", "unit", "higher_is_better", "marked")


def paper_tex_path() -> Path:
    """The paper's LaTeX: ``$MOEGS_PAPER``, else ``../shared/paper/moe-gs-mode.tex`` beside the repo."""
    env = os.environ.get("MOEGS_PAPER")
    if env:
        return Path(env).expanduser()
    return _REPO.parent / "shared" / "paper" / "moe-gs-mode.tex"


@dataclass(frozen=True)
class PaperTable:
    """One table of the paper: metadata plus its printed values in long format."""

    id: str  # "tab03"
    label: str  # the LaTeX \label, e.g. "tab:N3V"
    numeral: str  # the paper's number, "III"
    caption: str  # plain-text caption
    datasets: list[str]  # e.g. ["N3V"]; inferred ones are said so in ``notes``
    expert_sets: dict[str, list[str]]  # e.g. {"N=2": ["Ex4DGS", "STG"]}
    rows: list[str]  # row names as printed, in order
    columns: list[str]  # column names (scenes, or metrics when the columns are metrics), in order
    metrics: list[str]  # metrics present, in order
    notes: str  # transcription notes: inferred metadata, inconsistencies, marker conventions
    values: list[dict[str, Any]] = field(repr=False)  # one dict per printed cell (FRAME_COLUMNS keys)

    def frame(self):
        """The values as a ``pandas.DataFrame`` with columns ``FRAME_COLUMNS`` (``value`` is text only in
        Table I); pandas is an optional dependency (the ``test`` / ``analysis`` extras)."""
        import pandas as pd

        records = [{k: v.get(k) for k in FRAME_COLUMNS} for v in self.values]
        return pd.DataFrame(records, columns=FRAME_COLUMNS)

    def value(self, row: str, column: str, metric: str | None = None) -> Any:
        """The value of one cell; ``metric`` may be left out when the cell has only one."""
        return self.cell(row, column, metric)["value"]

    def cell(self, row: str, column: str, metric: str | None = None) -> dict[str, Any]:
        """The full record of one cell (value, printed text, unit, marker)."""
        _check_key("row", row, self.rows, self.id)
        _check_key("column", column, self.columns, self.id)
        if metric is not None:
            _check_key("metric", metric, self.metrics, self.id)
        hits = [
            v
            for v in self.values
            if v["row"] == row and v["column"] == column and (metric is None or v["metric"] == metric)
        ]
        if not hits:
            raise KeyError(
                f"{self.id}: no printed value for row={row!r}, column={column!r}, "
                f"metric={metric!r} (empty or N/A in the paper; see the table's notes)"
            )
        if len(hits) > 1:
            raise KeyError(
                f"{self.id}: row={row!r}, column={column!r} has several metrics "
                f"{[h['metric'] for h in hits]}; pass metric="
            )
        return hits[0]


def list_paper_tables() -> list[str]:
    """Ids of the transcribed tables in paper order: ``["tab01", ..., "tab19"]``."""
    return sorted(p.stem for p in PAPER_TABLES_DIR.glob("tab*.json"))


def load_paper_table(table_id: str) -> PaperTable:
    """Load ``tables/paper/<table_id>.json``; ``KeyError`` listing the valid ids if unknown."""
    _check_key("table id", table_id, list_paper_tables(), "tables/paper")
    data = json.loads((PAPER_TABLES_DIR / f"{table_id}.json").read_text(encoding="utf-8"))
    return PaperTable(**data)


def list_paper_texts() -> list[str]:
    """Ids of the in-text number sets (``tables/paper/text/*.json``), e.g. ``["static_roi"]``."""
    return sorted(p.stem for p in PAPER_TEXT_DIR.glob("*.json"))


def load_paper_text(text_id: str) -> PaperTable:
    """Load ``tables/paper/text/<text_id>.json`` (numbers printed in the paper's text) as a ``PaperTable``."""
    _check_key("text id", text_id, list_paper_texts(), "tables/paper/text")
    data = json.loads((PAPER_TEXT_DIR / f"{text_id}.json").read_text(encoding="utf-8"))
    data.pop("source_sentence", None)
    return PaperTable(**data)


def load_paper_numbers(source_id: str) -> PaperTable:
    """A table (``tab03``) or an in-text number set (``static_roi``) by id."""
    return load_paper_table(source_id) if source_id in list_paper_tables() else load_paper_text(source_id)


def list_original_tables() -> list[str]:
    """Ids of the experts' own published numbers (``tables/paper/originals/*.json``)."""
    return sorted(p.stem for p in PAPER_ORIGINALS_DIR.glob("*.json"))


def load_original_table(table_id: str) -> PaperTable:
    """Load ``tables/paper/originals/<table_id>.json``; each value keeps its ``source`` citation."""
    _check_key("originals id", table_id, list_original_tables(), "tables/paper/originals")
    data = json.loads((PAPER_ORIGINALS_DIR / f"{table_id}.json").read_text(encoding="utf-8"))
    missing = [v for v in data["values"] if not v.get("source")]
    if missing:
        raise ValueError(f"tables/paper/originals/{table_id}.json: values without a source: {missing}")
    return PaperTable(**data)


def paper_value(table: str | PaperTable, row: str, column: str, metric: str | None = None) -> Any:
    """One published value, e.g. ``paper_value("tab04", "MoE-GS (N=3)", "Average", "PSNR") == 34.55``."""
    t = table if isinstance(table, PaperTable) else load_paper_table(table)
    return t.value(row, column, metric)


def _check_key(kind: str, key: str, valid: list[str], where: str) -> None:
    if key not in valid:
        raise KeyError(f"{where}: unknown {kind} {key!r}; valid: {', '.join(map(repr, valid))}")
