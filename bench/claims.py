"""Checks for the paper's qualitative claims, run on our values and on the paper's own numbers.

Every check takes a *values view* ``v`` (``bench.values.ValuesView``: ``get(row, column, metric)``,
``columns(selector)``) and keyword arguments from ``Claim.args``; it returns a ``ClaimResult``.
Column selectors: ``"@mean"`` (the dataset average: the paper's ``Average`` column, our mean over
computed scenes), ``"@scenes"`` (every scene column that has values), or a list of printed columns.
``better`` respects each metric's direction (LPIPS, MDC: lower is better).

Noise: a view may carry ``noise`` (metric name -> the seed-to-seed spread measured in this run: the largest
row's on the table's scenes), ``row_noise`` ((row, metric) -> a row's own spread) and ``pair_noise`` ((a, b,
metric) -> the spread of the per-seed difference of two rows trained with the same seeds). A comparison of
two such rows is judged against their paired spread, else against the larger of its rows' own spreads when
every row has one, else against the scene-wide one (``noise_of``). A comparison whose margin is within it
decides nothing: the claim is "within noise" unless another comparison fails beyond the noise. An undecided
claim still says which way it leans (``leans``): "with the paper" when the same comparisons hold at zero
noise, "against the paper" when they fail. The paper's own numbers carry no noise, nor does a deterministic
quantity (``Metric.deterministic``: a model's memory is its size, exact at every seed). A run with no
spread at all (one seed and none borrowed) judges nothing but deterministic quantities: its other claims
are "not judged" (``bench.report``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

from bench.spec import Claim, metric

HELD, FAILED, NA, NOISE, NOT_JUDGED = "held", "failed", "n/a", "within noise", "not judged"
WITH_PAPER, AGAINST_PAPER = "with the paper", "against the paper"


class ValuesView(Protocol):
    def get(self, row: str, column: str, metric: str) -> float | None: ...

    def columns(self, selector: str | Sequence[str]) -> list[str]: ...

    def metrics_of(self, column: str) -> list[str]: ...


@dataclass(frozen=True)
class ClaimResult:
    status: str  # HELD | FAILED | NOISE | NA | NOT_JUDGED
    detail: str
    leans: str | None = None  # a NOISE verdict's direction: WITH_PAPER or AGAINST_PAPER
    seeds: int | None = None  # a NOISE verdict: seeds per row that would decide it (``seeds_to_decide``)

    @property
    def held(self) -> bool:
        return self.status == HELD

    @property
    def verdict(self) -> str:
        """The status, with the direction of an undecided one: ``within noise, against the paper``."""
        return f"{self.status}, {self.leans}" if self.leans else self.status


class _WithoutNoise:
    """A values view without its seed spread (what an undecided claim leans to)."""

    noise: dict[str, float] = {}
    row_noise: dict[tuple[str, str], float] = {}
    pair_noise: dict[tuple[str, str, str], float] = {}

    def __init__(self, view: ValuesView) -> None:
        self._view = view

    def __getattr__(self, name: str) -> Any:
        return getattr(self._view, name)


def _fmt(x: float | None) -> str:
    return "—" if x is None else f"{x:.4g}"


def _is_better(x: float, y: float, metric_name: str, strict: bool, margin: float) -> bool:
    if not metric(metric_name).higher_is_better:
        x, y = -x, -y
    return x - y > margin if strict else x - y >= -margin


def _at(v: ValuesView, column: str, metric_name: str) -> str:
    """A value's place in a detail: the column, and the metric where the column prints other ones (a
    dynamic-region twin compares "PSNR dynamic" under a table's PSNR columns)."""
    return column if metric_name in v.metrics_of(column) else f"{column} [{metric_name}]"


def is_exact(metric_name: str) -> bool:
    """Whether ``metric_name`` is a deterministic quantity, compared without noise."""
    return metric(metric_name).deterministic


def noise_of(v: ValuesView, metric_name: str, rows: Sequence[str] = ()) -> float:
    """The seed-to-seed spread a comparison of ``rows`` on ``metric_name`` is judged against: for two
    rows trained with the same seeds, the spread of their per-seed difference (``pair_noise``); else the
    largest of the rows' own spreads when each has one (``row_noise``); else the view's scene-wide spread
    (0 when it has none). A deterministic metric has none."""
    if is_exact(metric_name):
        return 0.0
    if len(rows) == 2:
        paired = getattr(v, "pair_noise", {}).get((*sorted(rows), metric_name))
        if paired is not None:
            return float(paired)
    own = [getattr(v, "row_noise", {}).get((row, metric_name)) for row in rows]
    if own and all(x is not None for x in own):
        return float(max(own))
    return float(getattr(v, "noise", {}).get(metric_name, 0.0))


def noise_name(v: ValuesView, metric_name: str, rows: Sequence[str]) -> str:
    """What ``noise_of`` used, for a claim's detail: ``paired spread`` or ``seed spread``."""
    paired = len(rows) == 2 and (*sorted(rows), metric_name) in getattr(v, "pair_noise", {})
    return "paired spread" if paired else "seed spread"


def _compare(
    x: float, y: float, metric_name: str, strict: bool, margin: float, noise: float
) -> tuple[str, float]:
    """``(HELD / FAILED, or NOISE when x - y is within noise of the decision boundary; the distance from
    the boundary)``."""
    gain = (x - y) if metric(metric_name).higher_is_better else (y - x)
    boundary = margin if strict else -margin
    distance = abs(gain - boundary)
    if noise > 0 and distance <= noise:
        return NOISE, distance
    return (HELD if (gain > boundary if strict else gain >= boundary) else FAILED), distance


def seeds_to_decide(undecided: Sequence[tuple[float, float]]) -> int | None:
    """Seeds per row that would decide every undecided comparison ``(distance from its boundary, seed
    spread)`` if the spread of a mean over n seeds shrinks as 1/sqrt(n): the largest
    ``ceil((spread / distance)^2)``; None when one sits on its boundary (no number of seeds decides it)."""
    if not undecided or any(d <= 0 for d, _ in undecided):
        return None
    return max(math.ceil(round((s / d) ** 2, 6)) for d, s in undecided)  # 9.000000001 is 9


def _verdict(statuses: list[str]) -> str:
    """FAILED if any comparison failed, else NOISE if any is within noise, else HELD."""
    return FAILED if FAILED in statuses else NOISE if NOISE in statuses else HELD


def better(
    v: ValuesView,
    a: str,
    b: str | Sequence[str],
    metric: str = "PSNR",
    columns: str | Sequence[str] = "@mean",
    strict: bool = True,
    margin: float = 0.0,
) -> ClaimResult:
    """Row ``a`` is better than row ``b`` (or every row of a list) on every selected column."""
    others = [b] if isinstance(b, str) else list(b)
    checked, statuses, undecided = [], [], []
    for col in v.columns(columns):
        x = v.get(a, col, metric)
        for o in others:
            y = v.get(o, col, metric)
            if x is None or y is None:
                continue
            noise = noise_of(v, metric, (a, o))
            spread = f", {noise_name(v, metric, (a, o))} {noise:.3g}" if noise > 0 else ""
            spread = ", exact: no noise" if is_exact(metric) else spread
            checked.append(f"{_at(v, col, metric)}: {_fmt(x)} vs {o} {_fmt(y)} (Δ {x - y:+.3g}{spread})")
            status, distance = _compare(x, y, metric, strict, margin, noise)
            statuses.append(status)
            if status == NOISE:
                undecided.append((distance, noise))
    if not checked:
        return ClaimResult(NA, f"no column where {a} and {others} both have {metric}")
    verdict = _verdict(statuses)
    if verdict == FAILED:
        lost = [c for c, s in zip(checked, statuses, strict=True) if s == FAILED]
        return ClaimResult(FAILED, f"{a} not better on " + "; ".join(lost))
    if verdict == NOISE:
        close = [c for c, s in zip(checked, statuses, strict=True) if s == NOISE]
        detail = "margin within the seed spread on " + "; ".join(close)
        return ClaimResult(NOISE, detail, seeds=seeds_to_decide(undecided))
    return ClaimResult(
        HELD,
        f"{a} better on {len(checked)} comparison(s): "
        + "; ".join(checked[:4])
        + (" ..." if len(checked) > 4 else ""),
    )


def best(
    v: ValuesView,
    row: str,
    among: Sequence[str],
    metric: str = "PSNR",
    columns: str | Sequence[str] = "@mean",
    strict: bool = False,
) -> ClaimResult:
    """Row ``row`` is the best (ties allowed unless ``strict``) among ``among``."""
    return better(v, row, [r for r in among if r != row], metric, columns, strict=strict)


def order(
    v: ValuesView,
    rows: Sequence[str],
    metric: str = "PSNR",
    columns: str | Sequence[str] = "@mean",
    strict: bool = True,
) -> ClaimResult:
    """``rows[0]`` better than ``rows[1]`` better than ... on every selected column."""
    parts = [better(v, rows[i], rows[i + 1], metric, columns, strict) for i in range(len(rows) - 1)]
    if any(p.status == NA for p in parts):
        return ClaimResult(NA, "; ".join(p.detail for p in parts if p.status == NA))
    verdict = _verdict([p.status for p in parts])
    undecided = [p for p in parts if p.status == NOISE]
    seeds = (
        None if any(p.seeds is None for p in undecided) else max((p.seeds for p in undecided), default=None)
    )
    return ClaimResult(
        verdict, " | ".join(p.detail for p in parts), seeds=seeds if verdict == NOISE else None
    )


def monotone(
    v: ValuesView, rows: Sequence[str], columns: Sequence[str], metric: str = "PSNR", tolerance: float = 0.0
) -> ClaimResult:
    """Along ``columns`` (in order) each row's value never gets better by more than ``tolerance``."""
    bad, close, seen, undecided = [], [], 0, []
    for row in rows:
        noise = noise_of(v, metric, (row,))
        vals = [(c, v.get(row, c, metric)) for c in columns]
        vals = [(c, x) for c, x in vals if x is not None]
        for (c0, x0), (c1, x1) in zip(vals, vals[1:], strict=False):
            seen += 1
            step = f"{row}: {_at(v, c1, metric)} {_fmt(x1)} > {_at(v, c0, metric)} {_fmt(x0)}"
            if _is_better(x1, x0, metric, strict=True, margin=tolerance + noise):
                bad.append(step)
            elif _is_better(x1, x0, metric, strict=True, margin=tolerance):
                close.append(step)
                undecided.append((abs(x1 - x0) - tolerance, noise))
    if not seen:
        return ClaimResult(NA, f"fewer than two of {list(columns)} computed")
    if bad:
        return ClaimResult(FAILED, "; ".join(bad))
    if close:
        return ClaimResult(
            NOISE, "within the seed spread: " + "; ".join(close), seeds=seeds_to_decide(undecided)
        )
    return ClaimResult(HELD, f"{seen} step(s) non-increasing")


def within(
    v: ValuesView,
    a: str,
    b: str,
    tolerance: float,
    metric: str = "PSNR",
    columns: str | Sequence[str] = "@mean",
) -> ClaimResult:
    """``|a - b| <= tolerance`` on every selected column (e.g. pruning keeps PSNR)."""
    noise = noise_of(v, metric, (a, b))
    checked, bad, close, undecided = 0, [], [], []
    for col in v.columns(columns):
        x, y = v.get(a, col, metric), v.get(b, col, metric)
        if x is None or y is None:
            continue
        checked += 1
        gap = f"{_at(v, col, metric)}: |{_fmt(x)} - {_fmt(y)}| > {tolerance}"
        if abs(x - y) > tolerance + noise:
            bad.append(gap)
        elif abs(x - y) > tolerance:
            close.append(f"{gap} by less than the {noise_name(v, metric, (a, b))} {noise:.3g}")
            undecided.append((abs(x - y) - tolerance, noise))
    if not checked:
        return ClaimResult(NA, f"{a} / {b} have no common {metric}")
    if bad:
        return ClaimResult(FAILED, "; ".join(bad))
    if close:
        return ClaimResult(NOISE, "; ".join(close), seeds=seeds_to_decide(undecided))
    return ClaimResult(HELD, f"{a} within {tolerance} of {b}")


def exceeds(
    v: ValuesView, a: str, column_a: str, others: Sequence[str], column_b: str, metric: str = "PSNR"
) -> ClaimResult:
    """``a`` at ``column_a`` is better than each of ``others`` at ``column_b`` (MoE average > best run)."""
    x = v.get(a, column_a, metric)
    if x is None:
        return ClaimResult(NA, f"{a} {column_a} not computed")
    pairs = [(o, v.get(o, column_b, metric)) for o in others]
    pairs = [(o, y) for o, y in pairs if y is not None]
    if not pairs:
        return ClaimResult(NA, f"none of {list(others)} has {column_b}")
    noises = [noise_of(v, metric, (a, o)) for o, _ in pairs]
    compared = [_compare(x, y, metric, True, 0.0, n) for (_, y), n in zip(pairs, noises, strict=True)]
    verdict = _verdict([status for status, _ in compared])
    undecided = [(d, n) for (status, d), n in zip(compared, noises, strict=True) if status == NOISE]
    detail = f"{a} {column_a} {_fmt(x)} vs " + ", ".join(f"{o} {_fmt(y)}" for o, y in pairs)
    return ClaimResult(verdict, detail, seeds=seeds_to_decide(undecided) if verdict == NOISE else None)


def spread(
    v: ValuesView, a: str, others: Sequence[str], low: str = "Min", high: str = "Max", metric: str = "PSNR"
) -> ClaimResult:
    """Row ``a`` has a smaller ``high - low`` range than each of ``others`` (more stable)."""

    def rng(row: str) -> float | None:
        lo, hi = v.get(row, low, metric), v.get(row, high, metric)
        return None if lo is None or hi is None else abs(hi - lo)

    ra = rng(a)
    pairs = [(o, rng(o)) for o in others]
    pairs = [(o, r) for o, r in pairs if r is not None]
    if ra is None or not pairs:
        return ClaimResult(NA, "ranges not computed (needs at least two seeds)")
    bad = [o for o, r in pairs if not ra < r]
    detail = f"{a} range {_fmt(ra)} vs " + ", ".join(f"{o} {_fmt(r)}" for o, r in pairs)
    return ClaimResult(FAILED if bad else HELD, detail)


def at_least(
    v: ValuesView,
    rows: Sequence[str],
    threshold: float,
    metric: str,
    columns: str | Sequence[str] = "@scenes",
) -> ClaimResult:
    """Every selected value of ``rows`` is at least ``threshold`` (e.g. two experts win pixels)."""
    seen, bad = 0, []
    for row in rows:
        for col in v.columns(columns):
            x = v.get(row, col, metric)
            if x is None:
                continue
            seen += 1
            if x < threshold:
                bad.append(f"{row} {_at(v, col, metric)}: {_fmt(x)} < {threshold}")
    if not seen:
        return ClaimResult(NA, f"{metric} not computed")
    return ClaimResult(FAILED if bad else HELD, "; ".join(bad) or f"{seen} value(s) >= {threshold}")


def differs_across(v: ValuesView, rows: Sequence[str], metric: str = "PSNR") -> ClaimResult:
    """The best row is not the same on every scene column (no single method dominates)."""
    winners = {}
    for col in v.columns("@scenes"):
        vals = {r: v.get(r, col, metric) for r in rows}
        vals = {r: x for r, x in vals.items() if x is not None}
        if len(vals) >= 2:
            sign = 1 if metric_direction(metric) else -1
            winners[col] = max(vals, key=lambda r: sign * vals[r])
    if len(winners) < 2:
        return ClaimResult(
            NA, f"needs two or more scenes with {metric} for {list(rows)}; have {len(winners)}"
        )
    distinct = set(winners.values())
    detail = ", ".join(f"{c}: {w}" for c, w in winners.items())
    return ClaimResult(HELD if len(distinct) > 1 else FAILED, detail)


def metric_direction(name: str) -> bool:
    return metric(name).higher_is_better


CHECKS: dict[str, Callable[..., ClaimResult]] = {
    f.__name__: f for f in (better, best, order, monotone, within, exceeds, spread, at_least, differs_across)
}


def evaluate(claim: Claim, values: ValuesView) -> ClaimResult:
    """Run one claim; a malformed claim is a programming error and raises."""
    if claim.check not in CHECKS:
        raise KeyError(f"claim {claim.id}: unknown check {claim.check!r}; valid: {', '.join(CHECKS)}")
    check, args = CHECKS[claim.check], dict(claim.args)
    result = check(values, **args)
    if result.status != NOISE:
        return result
    at_zero_noise = check(_WithoutNoise(values), **args)
    return replace(result, leans=WITH_PAPER if at_zero_noise.held else AGAINST_PAPER)
