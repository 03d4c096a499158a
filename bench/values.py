"""Our values of a spec, read back from local result JSONs only, next to the paper's.

``SpecValues`` maps (row, printed column, metric) to an ``OurCell``: the value (or None), a status
(``ok``, ``not implemented yet: ...``, ``failed: ...``, ``pending``, ``external``, ``partial ...``),
and whether it is *comparable* with the paper's number (computed on all the paper's real scenes; only
then a delta is shown). Columns of the ``scenes`` axis: the paper's scene columns, a ``Stand-in``
column when the dataset had no real scene, and ``Average`` (ours only when every paper scene was
computed). Both ``SpecValues`` and ``PaperValues`` are claim views (``bench.claims.ValuesView``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from bench.datasets import get_dataset
from bench.paper import PaperTable, load_paper_numbers
from bench.plan import Slot, SpecPlan
from bench.results import ResultError, read_result
from bench.spec import metric
from bench.store import Workspace

STAND_IN = "Stand-in"
AVERAGE = "Average"
MEAN = "@mean"


@dataclass(frozen=True)
class OurCell:
    value: float | None
    status: str
    comparable: bool = False
    detail: str = ""


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


class SlotResults:
    """Status and metrics of every slot, read once."""

    def __init__(self, plan: SpecPlan, workspace: Workspace) -> None:
        self.workspace = workspace
        self.errors: list[str] = []
        self._cache: dict[str, dict[str, Any] | None] = {}
        self.plan = plan

    def result(self, slot: Slot) -> dict[str, Any] | None:
        if slot.task is None:
            return None
        key = slot.task.key
        if key not in self._cache:
            path = self.workspace.result_path(slot.task)
            try:
                self._cache[key] = read_result(path) if path.is_file() else None
            except ResultError as err:
                self.errors.append(str(err))
                self._cache[key] = None
        return self._cache[key]

    def status(self, slot: Slot) -> tuple[str, str]:
        """``(status, detail)`` of a slot."""
        if slot.task is None:
            return slot.status, ""
        res = self.result(slot)
        if res is None:
            return "pending", "not run yet"
        if res["status"] != "ok":
            log = res.get("log") or ""
            return "failed", f"{res.get('error', 'failed')}" + (f" (log: {log})" if log else "")
        return "ok", ""

    def value(self, slot: Slot, metric_name: str) -> float | None:
        res = self.result(slot)
        if res is None or res["status"] != "ok":
            return None
        v = res["metrics"].get(metric(metric_name).key)
        return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _combine(slots: list[Slot], sr: SlotResults, metric_name: str, how: str = "mean") -> OurCell:
    """One printed value from several slots (scenes, or seeds): all must be ok."""
    if not slots:
        return OurCell(None, "n/a")
    bad = [(s, *sr.status(s)) for s in slots]
    not_ok = [(s, st, d) for s, st, d in bad if st != "ok"]
    if not_ok:
        s, st, d = not_ok[0]
        return OurCell(None, st, detail=d)
    vals = [sr.value(s, metric_name) for s in slots]
    if any(v is None for v in vals):
        return OurCell(None, "n/a", detail=f"{metric_name} not reported by this cell kind")
    comparable = all(s.scene is not None and s.scene.real for s in slots)
    value = {"mean": _mean, "min": min, "max": max}[how](vals)
    return OurCell(value, "ok", comparable)


class SpecValues:
    """Our values of one spec (a ``ValuesView``) plus the paper's (``.paper``)."""

    def __init__(
        self,
        plan: SpecPlan,
        workspace: Workspace,
        noise: dict[str, float] | None = None,
        row_noise: dict[tuple[str, str], float] | None = None,
        pair_noise: dict[tuple[str, str, str], float] | None = None,
    ) -> None:
        self.plan = plan
        self.noise = dict(noise or {})
        """Seed-to-seed spread per metric name (``bench.signals.noise_for``, the largest row's of the
        spec's scenes): claims within it are "within noise"."""
        self.row_noise = dict(row_noise or {})
        """``(row, metric)`` -> the spread a row measured itself (``bench.signals.row_noise_for``): a
        comparison of rows that all have one is judged against theirs (``bench.claims.noise_of``)."""
        self.pair_noise = dict(pair_noise or {})
        """``(a, b, metric)`` with ``a < b`` -> the spread of the two rows' per-seed difference
        (``bench.signals.pair_noise_for``): a comparison of the two is judged against it."""
        self.spec = plan.spec
        self.results = SlotResults(plan, workspace)
        self.paper_table: PaperTable | None = load_paper_numbers(self.spec.paper) if self.spec.paper else None
        self.paper = PaperValues(self.paper_table, self._paper_scene_columns())
        self.display_columns = self._display_columns()
        self.cells: dict[tuple[str, str, str], OurCell] = {}
        for row in self.spec.rows:
            for col in self.display_columns:
                for m in self.metrics_of(col):
                    self.cells[(row.name, col, m)] = self._compute(row.name, col, m)

    # ------------------------------------------------------------------ layout
    def _paper_scene_columns(self) -> list[str]:
        if self.spec.axis != "scenes":
            return []
        if self.paper_table is not None:
            return [c for c in self.paper_table.columns if c != AVERAGE]
        ds = get_dataset(self.spec.dataset)
        names = [s for s in ds.scene_names() if not self.spec.scenes or s in self.spec.scenes]
        return [ds.column_of(s) for s in names]

    def _display_columns(self) -> list[str]:
        spec = self.spec
        if spec.axis == "scenes":
            cols = list(self._paper_scene_columns())
            if self.plan.uses_stand_in:
                cols.append(STAND_IN)
            if self.paper_table is not None and AVERAGE in self.paper_table.columns:
                cols.append(AVERAGE)
            return cols
        if spec.columns:
            return list(spec.columns)
        if self.paper_table is not None:
            return list(self.paper_table.columns)
        return list(spec.metrics)

    def metrics_of(self, column: str) -> list[str]:
        """Metrics printed under a column (scenes axis: all of the spec's; otherwise the column's)."""
        if self.spec.axis in ("scenes",):
            return list(self.spec.metrics)
        if self.spec.axis == "metrics":
            return [self.spec.metric_of_column(column)]
        if self.spec.axis == "none":
            return []
        return [self.spec.metrics[0]]

    # ------------------------------------------------------------------ values
    def _row_slots(self, row: str) -> list[Slot]:
        return self.plan.slots_of(row)

    def _compute(self, row: str, column: str, metric_name: str) -> OurCell:
        slots = self._row_slots(row)
        if len(slots) == 1 and slots[0].task is None and slots[0].scene is None:
            return OurCell(None, slots[0].status)
        if slots and slots[0].task is None:
            return OurCell(None, slots[0].status)
        axis = self.spec.axis
        if axis == "scenes":
            if column == AVERAGE:
                return self._average(row, metric_name)
            picked = [
                s
                for s in slots
                if s.scene is not None and (s.scene.column == column if s.scene.real else column == STAND_IN)
            ]
            if not picked:
                return OurCell(None, "no data", detail="scene not present under MOEGS_DATA")
            return _combine(picked, self.results, metric_name)
        if axis == "metrics":
            return self._dataset_mean(slots, metric_name)
        if axis == "budgets":
            return self._dataset_mean([s for s in slots if s.budget_column == column], metric_name)
        if axis == "seeds":
            per_seed = []
            for seed in self.plan.seeds:
                cell = self._dataset_mean([s for s in slots if s.seed == seed], metric_name)
                if cell.status != "ok":
                    return cell
                per_seed.append(cell)
            how = {"Min": "min", "Max": "max"}.get(column, "mean")
            vals = [c.value for c in per_seed]
            value = {"mean": _mean, "min": min, "max": max}[how](vals)
            return OurCell(value, "ok", all(c.comparable for c in per_seed))
        return OurCell(None, "n/a")

    def _dataset_mean(self, slots: list[Slot], metric_name: str) -> OurCell:
        cell = _combine(slots, self.results, metric_name)
        if cell.status == "ok" and cell.comparable and not self._all_paper_scenes(slots):
            return OurCell(cell.value, "ok", False, detail="mean over a subset of the paper's scenes")
        return cell

    def _all_paper_scenes(self, slots: list[Slot]) -> bool:
        wanted = set(get_dataset(self.spec.dataset).scene_names())
        if self.spec.scenes:
            wanted &= set(self.spec.scenes)
        got = {s.scene.name.split(":", 1)[1] for s in slots if s.scene is not None and s.scene.real}
        return wanted <= got

    def _average(self, row: str, metric_name: str) -> OurCell:
        cols = self._paper_scene_columns()
        cells = [self.cells.get((row, c, metric_name)) or self._compute(row, c, metric_name) for c in cols]
        done = [c for c in cells if c.status == "ok"]
        if len(done) == len(cols) and all(c.comparable for c in done):
            return OurCell(_mean([c.value for c in done]), "ok", True)
        if not done:
            stand_in = self._compute(row, STAND_IN, metric_name) if self.plan.uses_stand_in else None
            status = stand_in.status if stand_in is not None and stand_in.status != "ok" else "partial"
            return OurCell(None, status, detail="computed on a stand-in scene only")
        return OurCell(None, "partial", detail=f"{len(done)} of {len(cols)} scenes computed")

    # ------------------------------------------------------------------ ValuesView
    def get(self, row: str, column: str, metric_name: str) -> float | None:
        if column == MEAN:
            vals = [self.get(row, c, metric_name) for c in self.columns("@scenes")]
            vals = [v for v in vals if v is not None]
            return _mean(vals)
        cell = self.cells.get((row, column, metric_name))
        if cell is None:
            cell = self._compute(row, column, metric_name) if column in self.display_columns else None
        return None if cell is None else cell.value

    def columns(self, selector: str | Sequence[str]) -> list[str]:
        if selector == "@mean":
            return [MEAN] if self.spec.axis == "scenes" else []
        if selector == "@scenes":
            return [
                c
                for c in self.display_columns
                if c != AVERAGE
                and any(
                    self.cells.get((r.name, c, m), OurCell(None, "")).value is not None
                    for r in self.spec.rows
                    for m in self.spec.metrics
                )
            ]
        return list(selector)

    # ------------------------------------------------------------------ summaries
    def measured(self) -> list[dict[str, Any]]:
        """Every cell we computed: ``{"row", "column", "metric", "ours", "paper"}`` (``paper``: its value in
        the same cell, ``None`` where the paper prints none or ours ran on a stand-in), table order."""
        return [
            {
                "row": row,
                "column": col,
                "metric": m,
                "ours": cell.value,
                "paper": self.paper.get(row, col, m) if cell.comparable else None,
            }
            for (row, col, m), cell in self.cells.items()
            if cell.value is not None
        ]

    def deltas(self) -> list[dict[str, Any]]:
        """Every comparable (ours - paper), largest magnitude first."""
        out = [{**v, "delta": v["ours"] - v["paper"]} for v in self.measured() if v["paper"] is not None]
        return sorted(out, key=lambda d: -abs(d["delta"]))

    def row_statuses(self) -> dict[str, str]:
        """Each row's overall status (first non-ok slot status, else ok)."""
        out = {}
        for row in self.spec.rows:
            statuses = [self.results.status(s)[0] for s in self._row_slots(row.name)]
            bad = [s for s in statuses if s != "ok"]
            out[row.name] = bad[0] if bad else "ok"
        return out

    def missing_pieces(self) -> list[str]:
        """Union of the library pieces the spec's rows lack, in row order."""
        return list(dict.fromkeys(m for s in self.plan.slots for m in s.missing))

    def failures(self) -> list[tuple[Slot, str]]:
        out = []
        for s in self.plan.slots:
            st, detail = self.results.status(s)
            if st == "failed":
                out.append((s, detail))
        return out


class PaperValues:
    """The paper's numbers as a claim view: ``@mean`` is its ``Average`` column."""

    def __init__(self, table: PaperTable | None, scene_columns: list[str]) -> None:
        self.table = table
        self.scene_columns = scene_columns
        self._values: dict[tuple[str, str, str], float] = {}
        if table is not None:
            for v in table.values:
                if isinstance(v["value"], int | float):
                    self._values[(v["row"], v["column"], v["metric"])] = float(v["value"])

    def get(self, row: str, column: str, metric_name: str) -> float | None:
        if column == MEAN:
            column = AVERAGE
        return self._values.get((row, column, metric_name))

    def columns(self, selector: str | Sequence[str]) -> list[str]:
        if self.table is None:
            return []
        if selector == "@mean":
            return [AVERAGE] if AVERAGE in self.table.columns else []
        if selector == "@scenes":
            return list(self.scene_columns)
        return list(selector)

    def metrics_of(self, column: str) -> list[str]:
        """Metrics the paper prints under a column."""
        return list(dict.fromkeys(m for _, c, m in self._values if c == column))

    def printed(self, row: str, column: str, metric_name: str) -> str | None:
        if self.table is None:
            return None
        for v in self.table.values:
            if v["row"] == row and v["column"] == column and v["metric"] == metric_name:
                return v["printed"]
        return None
