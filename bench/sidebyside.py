r"""Paper | standard | quick, side by side, for the tables that run on real scenes.

The ``standard`` preset (``bench.presets``) trains the real scenes far longer than ``quick``; this module
puts both runs next to the paper's value of every row and real scene, with the resolution and run
lengths of each column, as markdown (the reports) and as a LaTeX table (``tables/standard/``). Values
are read from the workspace's results of each preset; a preset that has not run shows ``?``.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from bench.latex import MACROS, POSTAMBLE, PREAMBLE, fmt, fmt_delta, tex
from bench.plan import plan_spec
from bench.presets import BenchPreset, get_preset
from bench.results import write_text_atomic
from bench.spec import Spec
from bench.store import Workspace
from bench.values import SpecValues

COMPARED = ("standard", "quick")
"""The bench presets shown beside the paper, in column order."""
DYNAMIC = "PSNR dynamic"
NATIVE = "PSNR native"


@dataclass(frozen=True)
class Cell:
    """Our value of one row and scene under one preset (``None``: not run yet), its dynamic-region PSNR
    and, below native resolution, the PSNR of the render upsampled to it (when the preset scores it)."""

    value: float | None
    dynamic: float | None
    native: float | None = None


def run_lengths(preset: BenchPreset, dataset: str) -> tuple[int, int]:
    """``(expert iterations, router iterations)`` of ``preset`` on a real scene of ``dataset``."""
    from bench.schedules import QUICK_ITERATIONS
    from moegs.moe import RouterConfig, router_preset

    experts = preset.stretched(dataset, True) or preset.train_steps or QUICK_ITERATIONS
    router = (
        preset.router_steps
        or RouterConfig.from_preset(router_preset(preset.router_scale or preset.expert_preset)).iterations
    )
    return experts, router


def column_label(preset: BenchPreset, dataset: str) -> str:
    """``standard (1/8 res., 6000 / 5000 it.)``: the preset, its resolution, expert / router iterations
    (and ``, mean of 3 seeds`` where it trains several)."""
    scale = Fraction(preset.real_kwargs(dataset).get("resolution_scale", 1.0)).limit_denominator(64)
    experts, router = run_lengths(preset, dataset)
    seeds = f", mean of {preset.scene_seeds} seeds" if preset.scene_seeds > 1 else ""
    return f"{preset.name} ({scale} res., {experts} / {router} it.{seeds})"


@dataclass
class Comparison:
    """One spec's rows x real scenes: the paper's value and each preset's :class:`Cell`."""

    spec: Spec
    metric: str
    scenes: list[str]
    labels: dict[str, str]
    paper: dict[tuple[str, str], float | None]
    ours: dict[tuple[str, str, str], Cell]

    @property
    def has_values(self) -> bool:
        return any(c.value is not None for c in self.ours.values())


def compare(
    spec: Spec, workspace: Workspace, presets: tuple[str, ...] | None = None, device: str = "cpu"
) -> Comparison | None:
    """The comparison of ``spec`` under ``presets`` (default ``COMPARED``), each with its cells on
    ``device``; ``None`` unless it runs on real scenes only, under every preset."""
    presets = presets or COMPARED
    if spec.axis != "scenes" or spec.figure:
        return None
    values = {name: SpecValues(plan_spec(spec, get_preset(name), device), workspace) for name in presets}
    first = values[presets[0]]
    if not first.plan.scenes or any(v.plan.uses_stand_in for v in values.values()):
        return None
    metric = spec.metrics[0]
    scenes = [s.column for s in first.plan.scenes]
    ours, paper = {}, {}
    for row in spec.rows:
        for col in scenes:
            paper[(row.name, col)] = first.paper.get(row.name, col, metric)
            for name, v in values.items():
                psnr = metric == "PSNR"
                dynamic = v.get(row.name, col, DYNAMIC) if psnr else None
                native = v.get(row.name, col, NATIVE) if psnr else None
                ours[(row.name, col, name)] = Cell(v.get(row.name, col, metric), dynamic, native)
    labels = {name: column_label(get_preset(name), spec.dataset) for name in presets}
    return Comparison(spec, metric, scenes, labels, paper, ours)


def _value(cell: Cell, metric: str) -> str:
    if cell.value is None:
        return "?"
    text = fmt(cell.value, metric)
    if cell.dynamic is not None:
        text += f" [{fmt(cell.dynamic, DYNAMIC)}]"
    return text


def _delta(cell: Cell, paper: float | None, metric: str) -> str:
    if cell.value is None or paper is None:
        return ""
    return f" ({fmt_delta(cell.value - paper, metric)})"


def _markdown_cell(cell: Cell, paper: float | None, metric: str) -> str:
    text = _value(cell, metric) + _delta(cell, paper, metric)
    if cell.native is not None:
        text += f"; upsampled to native {fmt(cell.native, NATIVE)}"
    return text


def markdown(cmp: Comparison) -> str:
    """A markdown table: one line per row and scene, ``ours [dynamic] (Δ to paper)`` per preset."""
    names = list(cmp.labels)
    head = ["model", "scene", f"paper {cmp.metric}", *(cmp.labels[n] for n in names)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in cmp.spec.rows:
        for col in cmp.scenes:
            ref = cmp.paper[(row.name, col)]
            cells = [_markdown_cell(cmp.ours[(row.name, col, n)], ref, cmp.metric) for n in names]
            paper = fmt(ref, cmp.metric) if ref is not None else "-"
            lines.append(f"| {row.display} | {col} | {paper} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def render_latex(cmp: Comparison, header: str = "") -> str:
    """The complete ``tables/standard/<id>_presets.tex`` (dual-use like ``bench.latex`` tables)."""
    names = list(cmp.labels)
    lines = [r"\begin{tabular}{ll|c" + "c" * len(names) + "}", r"\toprule"]
    lines.append("Model & Scene & Paper & " + " & ".join(tex(cmp.labels[n]) for n in names) + r" \\")
    lines.append(r"\midrule")
    for row in cmp.spec.rows:
        for col in cmp.scenes:
            ref = cmp.paper[(row.name, col)]
            cells = []
            for n in names:
                cell = cmp.ours[(row.name, col, n)]
                text = r"\ourspending" if cell.value is None else fmt(cell.value, cmp.metric)
                if cell.dynamic is not None:
                    text += f"\\dynregion{{{fmt(cell.dynamic, DYNAMIC)}}}"
                if cell.value is not None and ref is not None:
                    text += f"{{\\scriptsize\\,(${fmt_delta(cell.value - ref, cmp.metric)}$)}}"
                if cell.native is not None:
                    text += f"{{\\scriptsize\\,$\\uparrow${fmt(cell.native, NATIVE)}}}"
                cells.append(text)
            paper = fmt(ref, cmp.metric) if ref is not None else r"\oursmissing"
            lines.append(f"{tex(row.display)} & {tex(col)} & {paper} & " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    caption = tex(
        f"{cmp.spec.title}: the paper and our two CPU presets side by side ({cmp.metric}; our value, "
        "[x] the PSNR of the dynamic region, (Δ = ours - paper), and where scored, after an up-arrow, the "
        "PSNR of our render upsampled (bicubic) to the native resolution). Column heads: preset, "
        "resolution relative to the native one, expert / router training iterations. ?: no result of this "
        "library version (not run yet, or only by an older one)."
    )
    return (
        "\n".join(
            [
                f"% {header}".rstrip(),
                "% Generated by `python -m bench.all --preset standard`; do not edit. Needs booktabs.",
                PREAMBLE.rstrip(),
                MACROS.rstrip(),
                r"\begin{table}[t]",
                r"\centering",
                r"\scriptsize",
                f"\\caption{{{caption}}}",
                f"\\label{{moegs:{cmp.spec.id}-presets}}",
                *lines,
                r"\end{table}",
                POSTAMBLE.rstrip(),
            ]
        )
        + "\n"
    )


def write_latex(cmp: Comparison, out_dir: Path, header: str = "") -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{cmp.spec.id}_presets.tex"
    write_text_atomic(path, render_latex(cmp, header))
    return path


def real_scene_comparisons(workspace: Workspace) -> list[Comparison]:
    """The comparison of every table spec that runs on real scenes and has a value of ours."""
    from bench.registry import get_spec, list_specs

    found = (compare(get_spec(sid), workspace) for sid in list_specs())
    return [c for c in found if c is not None and c.has_values]


LEGEND = (
    "Our value [PSNR of the dynamic region] (Δ = ours - paper) of each preset; column heads give the "
    "resolution relative to the paper's and the expert / router training iterations (`standard`: the "
    "quick schedules stretched, `bench.schedules`). ?: no result of this library version (not run yet, "
    "or only by an older one: a committed `reports/standard/` names the commit it comes from)."
)
"""How to read a comparison table (the reports and the README)."""


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.sidebyside [--workspace W] [--readme docs/standard.md]``: print the comparisons (and
    write them into the README's ``results:standard`` section)."""
    import argparse

    from bench.readme import machine_line, update_readme

    p = argparse.ArgumentParser(prog="python -m bench.sidebyside", description=main.__doc__)
    p.add_argument("--workspace", type=Path, default=None, help="bench workspace (default: runs/bench)")
    p.add_argument("--readme", type=Path, help="rewrite this README's results:standard section")
    args = p.parse_args(argv)
    comparisons = real_scene_comparisons(Workspace(args.workspace))
    if not comparisons:
        p.exit(1, "bench.sidebyside: no real-scene results in the workspace; run bench.all first\n")
    text = "\n\n".join(f"{c.spec.id}: {c.spec.title}\n\n{markdown(c)}" for c in comparisons)
    print(text)
    if args.readme:
        body = (
            f"{LEGEND}\n\n{text}\n\nGenerated by `python -m bench.sidebyside --readme "
            f"{args.readme.as_posix()}` from the results of `python -m bench.all --preset standard` and "
            f"`--quick` on {machine_line()}."
        )
        update_readme(args.readme, "standard", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
