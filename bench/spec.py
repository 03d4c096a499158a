"""What a table or figure spec is: rows (methods) x columns (scenes / metrics / seeds / budgets).

A spec is plain data (stdlib only), so ``bench.registry.list_specs()`` never imports torch. Each row
names a cell *kind* (``bench.cells``) and its parameters; the planner (``bench.plan``) expands a spec
into cells ``(kind, params, scene, preset, seed)`` and the table builder reads their results back.

Axes:

* ``"scenes"``: columns are the dataset's printed scenes plus ``Average`` (Tables II-IV, XII-XVII).
* ``"metrics"``: columns are metrics averaged over the dataset's scenes (Tables V-VIII, X, XI, XIX).
* ``"seeds"``: columns ``Min`` / ``Max`` / ``Average`` over repeated trainings (Table IX).
* ``"budgets"``: columns are expert training budgets, e.g. ``50%`` (Table XVIII).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, TypeVar

T = TypeVar("T")

AXES = ("scenes", "metrics", "seeds", "budgets", "none")
#: the paper's image-quality columns, and its efficiency columns
QUALITY = ("PSNR", "SSIM", "LPIPS")
EFFICIENCY = ("PSNR", "FPS", "Memory")

#: The paper's expert names -> ``moegs.experts`` registry names.
EXPERTS: dict[str, str] = {
    "3DGS": "static",
    "3DGS-MCMC": "mcmc",
    "4DGaussians": "fourdgs",
    "E-D3DGS": "ed3dgs",
    "Grid4D": "grid4d",
    "DeformableGS": "deformable",
    "STG": "stg",
    "Ex4DGS": "ex4dgs",
}
#: MoE-GS expert sets used throughout the paper (Section V-B "fixed combinations").
MOE_SETS: dict[int, tuple[str, ...]] = {
    2: ("ex4dgs", "stg"),
    3: ("ex4dgs", "stg", "ed3dgs"),
    4: ("ex4dgs", "stg", "ed3dgs", "fourdgs"),
}


def by_name(items: Iterable[T], what: str) -> dict[str, T]:
    """``{item.name: item}`` in the given order; a repeated name is an error (a dict display would keep
    the last one silently). ``what`` names the items in that error."""
    named: dict[str, T] = {}
    for item in items:
        if item.name in named:
            raise ValueError(f"two {what} are named {item.name!r}")
        named[item.name] = item
    return named


@dataclass(frozen=True)
class Metric:
    """A reported quantity: printed name, key in a result's ``metrics``, direction, decimals; and
    ``deterministic`` for a quantity the trained model fixes exactly (its size in memory), which claims
    compare without a seed spread (``bench.claims.noise_of``)."""

    name: str
    key: str
    higher_is_better: bool
    digits: int
    unit: str = ""
    deterministic: bool = False


METRICS: dict[str, Metric] = by_name(
    (
        Metric("PSNR", "psnr", True, 2, "dB"),
        Metric("SSIM", "ssim", True, 3),
        Metric("LPIPS", "lpips", False, 3),
        Metric("FPS", "fps", True, 1),
        Metric("Memory", "memory_mb", False, 1, "MB", deterministic=True),
        Metric("Time", "train_time_h", False, 3, "h"),
        # region metrics (static / dynamic masks) for the ROI and MoDE trade-off figures
        Metric("PSNR static", "psnr_static", True, 2, "dB"),
        Metric("SSIM static", "ssim_static", True, 3),
        Metric("LPIPS static", "lpips_static", False, 3),
        Metric("PSNR dynamic", "psnr_dynamic", True, 2, "dB"),
        # below the native resolution: the render upsampled (bicubic) against the native ground truth
        Metric("PSNR native", "psnr_native", True, 2, "dB"),
        Metric("SSIM dynamic", "ssim_dynamic", True, 3),
        Metric("LPIPS dynamic", "lpips_dynamic", False, 3),
        # geometry and motion analyses (figures)
        Metric("MDC", "mdc", False, 4),
        Metric("Coherence", "coherence", True, 3),
        Metric("Curvature", "curvature", False, 3, "rad"),
        Metric("Speed", "speed", True, 3),
        Metric("Winners", "winners", True, 0),
        Metric("Switches", "switches", True, 0),
        Metric("Gate experts", "gate_experts", True, 0),
    ),
    "metrics",
)


def metric(name: str) -> Metric:
    """A metric by printed name; ``KeyError`` lists the valid names."""
    if name not in METRICS:
        raise KeyError(f"unknown metric {name!r}; valid: {', '.join(METRICS)}")
    return METRICS[name]


def _frozen(params: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(dict(params or {}))


@dataclass(frozen=True)
class Row:
    """One row of a table: a method computed by the cell kind ``kind`` with ``params``.

    ``name`` is the row name exactly as in ``tables/paper/<id>.json`` (or a new name for rows the
    paper does not print); ``label`` is the LaTeX text (defaults to ``name``). ``variant`` marks a row
    the paper does not have (a named variant of one of its rows, e.g. the router with the paper's
    wording instead of the authors' code conventions); it follows the paper's rows.
    """

    name: str
    kind: str
    params: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    variant: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", _frozen(self.params))

    @property
    def display(self) -> str:
        return self.label or self.name


@dataclass(frozen=True)
class Claim:
    """A qualitative claim of the paper, checked on our values (and on the paper's, as a sanity check).

    ``check`` names a function of ``bench.claims``; ``args`` are its keyword arguments.
    ``source`` says where the paper makes the claim: the section whose text states it (``Sec. IV-C
    (ii)``, in the numbering of ``paper/moe-gs-mode.tex``), or the table alone (``Table III``) where
    only the table's numbers show it. ``twin``: whether a spec about motion also checks the claim on
    the dynamic region; False where the paper says otherwise about motion, or nothing. ``kind``
    (``CLAIM_KINDS``): ``paper``, a statement of the paper; ``sanity``, true by construction or a check of
    the implementation (pruning lowers memory, two experts cost more than one, single pass leaves the image
    as it is): reported as a check that passed or failed, never as reproducing the paper; ``suite``, ours
    (the dynamic-region twins).
    """

    id: str
    text: str
    check: str
    args: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""
    twin: bool = field(default=True, kw_only=True)
    kind: str = field(default="paper", kw_only=True)

    def __post_init__(self) -> None:
        object.__setattr__(self, "args", _frozen(self.args))
        if self.kind not in CLAIM_KINDS:
            raise ValueError(f"claim {self.id}: kind must be one of {CLAIM_KINDS}, got {self.kind!r}")

    def on_dynamic_region(self) -> Claim | None:
        """The same claim on the dynamic region's PSNR, for claims about PSNR that have a twin (None
        otherwise)."""
        if not self.twin or self.check not in DYNAMIC_TWINS or self.args.get("metric", "PSNR") != "PSNR":
            return None
        args = {**self.args, "metric": "PSNR dynamic"}
        text = f"{self.text} [dynamic region]"
        return Claim(f"{self.id}-dynamic", text, self.check, args, self.source, kind="suite")


CLAIM_KINDS = ("paper", "sanity", "suite")
"""What a claim is (``Claim.kind``); reports count each kind apart."""

DYNAMIC_TWINS = ("better", "best", "order", "exceeds", "within", "monotone", "differs_across")
"""Checks that compare one metric across rows, so that they also apply to the dynamic region's PSNR."""


@dataclass(frozen=True)
class Spec:
    """A paper table or a figure drawn from data.

    Attributes:
        id: ``tab01`` .. ``tab19`` or ``fig_*``.
        title: short description.
        dataset: ``bench.datasets`` name whose scenes the cells run on ("" for none).
        rows: the methods.
        axis: see the module docstring (default ``"scenes"``).
        metrics: printed metric names shown (``METRICS`` keys).
        columns: printed column names; empty -> the paper table's columns (tables) or the metrics.
        column_metric: ``"metrics"`` axis: printed column -> metric name (default: identity).
        budgets: ``"budgets"`` axis: printed column -> fraction of the expert's training.
        seeds: seeds run for every cell; the ``"seeds"`` axis uses ``preset.seeds`` instead.
        claims: the paper's claims about this table.
        paper: id of the transcribed paper numbers (``tables/paper/<paper>.json`` or
            ``tables/paper/text/<paper>.json``); "" when the paper prints none; default: the table's
            own id (a figure's: none).
        plot: name of a plot function in ``bench.plots`` (figures; tables get the generic bar plot).
        figure: True for figure specs (no LaTeX table).
        scenes: restrict to these loader scene names (figures about named scenes); empty = all.
        notes: assumptions made by the spec (what the paper leaves unsaid).
        motion: the paper's claims here are about motion: each PSNR claim is also checked on the
            dynamic region ("PSNR dynamic").
        candidates: the spec's extension by candidate experts (``bench.all --candidate NAME``):
            ``candidates(spec, names) -> Spec`` with their rows and claims added; None when it takes none.
        unpruned: the row whose memory the pruned rows' is compared with (the report's pruning section).
    """

    id: str
    title: str
    dataset: str
    rows: tuple[Row, ...]
    axis: str = "scenes"
    metrics: tuple[str, ...] = ("PSNR",)
    columns: tuple[str, ...] = ()
    column_metric: Mapping[str, str] = field(default_factory=dict)
    budgets: Mapping[str, float] = field(default_factory=dict)
    seeds: tuple[int, ...] = (0,)
    claims: tuple[Claim, ...] = ()
    paper: str | None = None
    plot: str = "paper_vs_ours"
    figure: bool = False
    scenes: tuple[str, ...] = ()
    notes: str = ""
    motion: bool = False
    candidates: Callable[[Spec, tuple[str, ...]], Spec] | None = field(default=None, compare=False)
    unpruned: str | None = None

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise ValueError(f"{self.id}: axis must be one of {AXES}, got {self.axis!r}")
        for m in self.metrics:
            metric(m)
        names = [r.name for r in self.rows]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.id}: duplicate row names {names}")
        if self.paper is None:
            object.__setattr__(self, "paper", "" if self.figure else self.id)
        object.__setattr__(self, "column_metric", _frozen(self.column_metric))
        object.__setattr__(self, "budgets", _frozen(self.budgets))

    def checked_claims(self) -> list[Claim]:
        """The claims the report checks: the paper's, and with ``motion`` their dynamic-region twins."""
        twins = [c.on_dynamic_region() for c in self.claims] if self.motion else []
        return [*self.claims, *(t for t in twins if t is not None)]

    def row(self, name: str) -> Row:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(f"{self.id}: unknown row {name!r}; rows: {[r.name for r in self.rows]}")

    def metric_of_column(self, column: str) -> str:
        """``"metrics"`` axis: the metric a printed column reports."""
        return self.column_metric.get(column, column)


# ------------------------------------------------------------------ row constructors (keep specs short)
def expert(name: str, paper_name: str | None = None, **params: Any) -> Row:
    """A single expert trained with the GT loss: ``expert("STG†", "STG")``."""
    key = EXPERTS[paper_name or name]
    return Row(name, "expert", {"expert": key, **params})


def moe(
    name: str, experts: tuple[str, ...] | int, router: str = "vapr", variant: bool = False, **params: Any
) -> Row:
    """MoE-GS over ``experts`` (registry names or ``N`` for the paper's fixed set)."""
    chosen = MOE_SETS[experts] if isinstance(experts, int) else tuple(experts)
    return Row(name, "moe", {"experts": list(chosen), "router": router, **params}, variant=variant)


def mode(name: str, base: str, added: str, **params: Any) -> Row:
    """MoDE: ``base`` canonical deformation plus the ``added`` deformation expert (paper names)."""
    return Row(name, "mode", {"base": EXPERTS[base], "experts": [EXPERTS[base], EXPERTS[added]], **params})


def mode_family(base: str, *added: str) -> tuple[Row, ...]:
    """The single-deformation baseline ``base`` and its MoDE variants ``"<base> w/ <added>"``."""
    return (expert(base), *(mode(f"{base} w/ {a}", base, a) for a in added))


def distill(name: str, student: str, weighted: bool = True, teacher: int = 3, **params: Any) -> Row:
    """An expert distilled from MoE-GS (``teacher``-expert set), with or without routing weights."""
    return Row(
        name,
        "distill",
        {
            "student": EXPERTS[student],
            "teacher": list(MOE_SETS[teacher]),
            "router": "vapr",
            "weighted": weighted,
            **params,
        },
    )


def external(name: str, why: str = "method outside the suite") -> Row:
    """A baseline the suite does not implement (NeRF methods, other papers): paper value only."""
    return Row(name, "external", {"why": why})


def moe_label(n: int) -> str:
    """Caption text for the fixed set of size ``n``, e.g. ``N=3: {ex4dgs, stg, ed3dgs}``."""
    return f"N={n}: {{{', '.join(MOE_SETS[n])}}}"


# ------------------------------------------------------------------ claim constructors (the common forms)
def _listing(names: Sequence[str]) -> str:
    """``A``, ``A and B``, ``A, B and C``."""
    return " and ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else list(names))


def beats_every_scene(claim_id: str, row: str, others: Sequence[str], source: str) -> Claim:
    """``row`` beats each of ``others`` on every scene of the table (PSNR)."""
    text = f"{row} beats {_listing(others)} on every scene"
    return Claim(claim_id, text, "better", {"a": row, "b": list(others), "columns": "@scenes"}, source)


def beats_on_average(claim_id: str, row: str, others: Sequence[str], source: str) -> Claim:
    """``row`` beats each of ``others`` on the average (PSNR)."""
    text = f"{row} has a better average than {_listing(others)}"
    return Claim(claim_id, text, "better", {"a": row, "b": list(others)}, source)


# ------------------------------------------------------------------ spec constructors (the common designs)
def moe_pair_spec(
    spec_id: str,
    title: str,
    dataset: str,
    experts: tuple[str, str],
    sources: tuple[str, str],
    *,
    claims: Sequence[Claim] = (),
    notes: str = "",
) -> Spec:
    """Tables XIV, XVI and XVII: MoE-GS (N=2) over two experts (paper names) against each of them, with
    the paper's claims that it beats both on every scene (cited to ``sources[0]``) and on average
    (``sources[1]``), plus any table-specific ``claims``; the claims are about motion."""
    pair = "MoE-GS (N=2)"
    return Spec(
        id=spec_id,
        title=title,
        dataset=dataset,
        rows=(*(expert(e) for e in experts), moe(pair, tuple(EXPERTS[e] for e in experts))),
        claims=(
            beats_every_scene("n2-every-scene", pair, list(experts), sources[0]),
            beats_on_average("n2-best-average", pair, list(experts), sources[1]),
            *claims,
        ),
        motion=True,
        notes=notes,
    )
