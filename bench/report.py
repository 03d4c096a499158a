"""``reports/REPORT.md``, ``reports/REPORT.html`` (figures embedded) and ``reports/summary.json``.

Per table and figure: status (reproduced at which scale / stand-in data / missing library piece),
the scenes used, the paper's claims that held and failed on our numbers (and, as a check of the
claim's encoding, on the paper's own numbers), the largest deltas where ours is comparable, rows not
implemented yet with the missing pieces, and failed cells with their log paths.
"""

from __future__ import annotations

import html
import json
import os
import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bench.claims import AGAINST_PAPER, FAILED, HELD, NA, NOISE, NOT_JUDGED, ClaimResult, evaluate, is_exact
from bench.keys import code_version, git_commit
from bench.presets import BenchPreset, preset_flag
from bench.results import write_text_atomic
from bench.runlog import FILE as RUNS_FILE
from bench.runlog import by_kind, describe, recent
from bench.signals import NOISE_PROXY
from bench.values import SpecValues


@dataclass
class SpecReport:
    id: str
    title: str
    kind: str
    status: str
    scenes: list[str]
    rows: dict[str, str]
    values: list[dict[str, Any]]
    claims: list[dict[str, Any]]
    deltas: list[dict[str, Any]]
    missing: list[str]
    failures: list[dict[str, Any]]
    notes: str
    latex: str | None = None
    figures: list[str] = field(default_factory=list)
    invalid_results: list[str] = field(default_factory=list)
    seeds: int = 1  # seeds each row trains (averaged) on its scenes, at most


CONVENTIONS = (
    "## Conventions",
    "",
    "- **Experts** train with `moegs.recipes.config_for(expert, scene, preset)`: the original code's recipe "
    "for the scene's dataset (an adaptation of its closest recipe where the original has none, marked in "
    "each run's `config.json`), the values it sets for that scene, and at `quick` only the named CPU "
    "reductions of each expert's `quick_fields`. Scenes load on the background each original trains and "
    "evaluates on (DeformableGS / Grid4D / STG black; 4DGaussians / E-D3DGS / Ex4DGS / MoDE white).",
    "- **Routers and MoDE** follow the authors' code, which produced the paper's numbers (router: 1x1 Phi, "
    "w_dir initialised to 0.9, logits / 0.01 in training; MoDE: position and rotation mixed with one gate "
    "each, std-normalised scores, raw quaternions mixed then normalised). The paper's wording is a named "
    "variant: Table VI has it as an extra row.",
    "- **Regions**: every cell is scored on the full image, the dynamic region and the static region "
    "(stand-ins: ground-truth dynamic masks; D-NeRF: object alpha; Panoptic: foreground masks).",
)
"""Which conventions every table uses (the README says the same)."""


def _status(values: SpecValues, preset: BenchPreset) -> str:
    spec = values.spec
    if spec.axis == "none":
        return "qualitative: the paper's symbols, nothing to compute"
    statuses = values.row_statuses()
    computable = {r: s for r, s in statuses.items() if s not in ("external", "qualitative")}
    ok = [r for r, s in computable.items() if s == "ok"]
    ni = [r for r, s in computable.items() if s.startswith("not implemented")]
    failed = [r for r, s in computable.items() if s == "failed"]
    pending = [r for r, s in computable.items() if s == "pending"]
    if computable and len(ni) == len(computable):
        return "missing piece: " + ", ".join(values.missing_pieces())
    scale = f"{preset.name} preset" + (" (reduced scale)" if preset.reduced else "")
    stand = [s.name for s in values.plan.scenes if not s.real]
    data = (
        ("stand-in data (" + ", ".join(stand) + ")")
        if stand
        else "real data (" + ", ".join(s.name for s in values.plan.scenes) + ")"
    )
    if not ok and pending and not failed:
        return f"not run yet ({len(pending)} row(s) pending)"
    parts = [f"reproduced at {scale} on {data}: {len(ok)}/{len(computable)} rows"]
    averaged = values.plan.averaged_seeds()
    if averaged:
        parts += [f"{name}: mean of {len(seeds)} seeds" for name, seeds in sorted(averaged.items())]
    if ni:
        parts.append(f"{len(ni)} row(s) missing pieces")
    if failed:
        parts.append(f"{len(failed)} row(s) with failed cells")
    if pending:
        parts.append(f"{len(pending)} row(s) not run")
    return "; ".join(parts)


TIMINGS = ("FPS", "Time")
"""Metrics that are timings: a paper claim on them is not judged from separate cells (``UNPAIRED``)."""
UNPAIRED = (
    "a timing of separate cells, not a ratio measured in paired rounds, on another device than the paper's "
    "GPU (python -m bench.single_pass times single pass against separate renders in paired rounds)"
)
NO_BASIS = (
    "no seed spread was measured or borrowed for these scenes (each row trained once): a difference "
    "cannot be told from noise"
)


def verdict(claim: dict[str, Any]) -> str:
    """A report's claim verdict as a reader sees it: ``within noise, against the paper (about 9 seeds
    per row would decide it)``."""
    if not claim.get("ours_leans"):
        return claim["ours"]
    need = ""
    if "ours_seeds_to_decide" in claim:
        seeds = claim["ours_seeds_to_decide"]
        need = f" (about {seeds} seeds per row would decide it)" if seeds else " (it sits on the boundary)"
    return f"{claim['ours']}, {claim['ours_leans']}{need}"


KIND_LABELS = {"paper": "paper", "sanity": "sanity checks", "suite": "dynamic-region twins"}
"""How reports name each claim kind (``bench.spec.CLAIM_KINDS``)."""


def claim_counts(claims: list[dict[str, Any]]) -> str:
    """``3 held / 2 failed / 5 within noise (4 against the paper) / 1 n/a`` (zero counts of the last two
    kinds and of "not judged" left out)."""
    count = {s: sum(c["ours"] == s for c in claims) for s in (HELD, FAILED, NOISE, NOT_JUDGED, NA)}
    against = sum(c.get("ours_leans") == AGAINST_PAPER for c in claims)
    parts = [f"{count[HELD]} held", f"{count[FAILED]} failed", f"{count[NOISE]} within noise"]
    if count[NOISE]:
        parts[-1] += f" ({against} {AGAINST_PAPER})"
    parts += [f"{count[s]} {s}" for s in (NOT_JUDGED, NA) if count[s]]
    return " / ".join(parts)


def claims_by_kind(claims: list[dict[str, Any]]) -> str:
    """``claim_counts`` of each kind present, the paper's first: ``paper: 3 held / ...; sanity checks: 2
    held / 0 failed / 0 within noise``."""
    kinds = [k for k in KIND_LABELS if any(c.get("kind", "paper") == k for c in claims)]
    return "; ".join(
        f"{KIND_LABELS[k]}: {claim_counts([c for c in claims if c.get('kind', 'paper') == k])}" for k in kinds
    )


def spec_report(
    values: SpecValues, preset: BenchPreset, latex: Path | None = None, figures: list[Path] | None = None
) -> SpecReport:
    """Everything the report says about one spec."""
    spec = values.spec
    claims = []
    for claim in spec.checked_claims():
        if claim.kind == "paper" and claim.args.get("metric") in TIMINGS:
            ours = ClaimResult(NOT_JUDGED, UNPAIRED)
        else:
            judged = values.noise or is_exact(claim.args.get("metric", "PSNR"))
            ours = evaluate(claim, values) if judged else ClaimResult(NOT_JUDGED, NO_BASIS)
        paper = evaluate(claim, values.paper) if values.paper_table is not None else None
        claims.append(
            {
                "id": claim.id,
                "kind": claim.kind,
                "text": claim.text,
                "source": claim.source,
                "ours": ours.status,
                "ours_leans": ours.leans,
                "ours_seeds_to_decide": ours.seeds,
                "ours_detail": ours.detail,
                "paper": paper.status if paper else NA,
                "paper_detail": paper.detail if paper else "the paper prints no numbers for this",
            }
        )
    failures = [
        {
            "row": s.row,
            "scene": s.scene.name if s.scene else None,
            "seed": s.seed,
            "detail": d,
            "key": s.task.key if s.task else None,
        }
        for s, d in values.failures()
    ]
    return SpecReport(
        id=spec.id,
        title=spec.title,
        kind="figure" if spec.figure else "table",
        status=_status(values, preset),
        scenes=[s.label for s in values.plan.scenes],
        rows=values.row_statuses(),
        values=values.measured(),
        claims=claims,
        deltas=values.deltas()[:5],
        missing=values.missing_pieces(),
        failures=failures,
        notes=spec.notes,
        latex=str(latex) if latex else None,
        figures=[str(f) for f in figures or []],
        invalid_results=list(values.results.errors),
        seeds=max((len(s) for s in values.plan.averaged_seeds().values()), default=1),
    )


# ------------------------------------------------------------------------------------ rendering
def _header(
    preset: BenchPreset,
    run: dict[str, Any] | None,
    cells: dict[str, Any] | None,
    history: list[dict[str, Any]] | None,
    device: str = "cpu",
) -> dict[str, Any]:
    return {
        "created": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "preset": preset.name,
        "preset_description": preset.description,
        "reduced_scale": preset.reduced,
        "device": device,
        "machine": f"{platform.node()} ({platform.machine()}, {platform.system()})",
        "moegs_code_version": code_version(),
        "git": git_commit(),
        "cells": cells or {},
        "run": run or {},
        "history": history or [],
    }


def _recent_runs(history: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """``(title, lines)``: the recorded runs of the report's plan that it shows (``bench.runlog.recent``),
    under a title that says how many others it leaves out."""
    shown = recent(history)
    left = f" ({len(history) - len(shown)} more not shown)" if len(history) > len(shown) else ""
    return f"runs of these cells recorded in the workspace ({RUNS_FILE}){left}", [describe(r) for r in shown]


def history_markdown(history: list[dict[str, Any]]) -> list[str]:
    """Header bullets of ``_recent_runs`` (none without a recorded run)."""
    if not history:
        return []
    title, lines = _recent_runs(history)
    return [f"- {title}:", *(f"  - {line}" for line in lines)]


def _claim_counts(rep: SpecReport) -> str:
    return claims_by_kind(rep.claims)


def _rel(path: str, base: Path) -> str:
    """``path`` relative to ``base`` (``../tables/tab03.tex`` from ``reports/``), so links survive a move."""
    return os.path.relpath(Path(path).resolve(), base.resolve())


def _num(x: float | None, digits: int = 2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def motion_lines(experts: list[dict[str, Any]]) -> list[str]:
    """One bullet per scene whose expert cells report a motion R²: its range and the best expert."""
    by_scene: dict[str, list[tuple[float, str]]] = {}
    for r in experts:
        if r.get("motion_r2") is not None:
            by_scene.setdefault(r["scene"], []).append((r["motion_r2"], r["expert"]))
    lines = []
    for scene, values in sorted(by_scene.items()):
        low, high = min(values), max(values)
        lines.append(
            f"- **Motion on {scene}**: the experts reproduce {low[0]:.2f} ({low[1]}) to {high[0]:.2f} "
            f"({high[1]}) of the dynamic region's change over time (motion R², 1 = all of it). Claims "
            "about motion on this scene compare models of that much of the motion."
        )
    return lines


def regime_markdown(experts: list[dict[str, Any]]) -> list[str]:
    """The expert cells' PSNR per motion regime (stand-ins), one row per cell, as markdown lines."""
    rows = [r for r in experts if r.get("psnr_regimes")]
    if not rows:
        return []
    names = sorted({k for r in rows for k in r["psnr_regimes"]})
    lines = [
        "",
        "PSNR per motion regime (stand-ins; the pixels of the objects of each regime, squared error pooled "
        "over the test views; `moegs.data.synthetic`'s categories), beside the dynamic region as a whole:",
        "",
        "| scene | dataset recipe | expert | PSNR dynamic | " + " | ".join(names) + " |",
        "|---|---|---|---|" + "---|" * len(names),
    ]
    for r in rows:
        values = " | ".join(_num(r["psnr_regimes"].get(n)) for n in names)
        lines.append(
            f"| {r['scene']} | {r['dataset']} | {r['expert']} | {_num(r['psnr']['dynamic'])} | {values} |"
        )
    return lines


def camera_markdown(experts: list[dict[str, Any]]) -> list[str]:
    """The expert cells' PSNR per held-out camera on real multi-camera scenes, a table per scene."""
    lines = []
    for scene in sorted({r["scene"] for r in experts if r.get("psnr_cameras")}):
        rows = [r for r in experts if r["scene"] == scene and r.get("psnr_cameras")]
        cameras = sorted({c for r in rows for c in r["psnr_cameras"]}, key=lambda c: (len(c), c))
        lines += [
            "",
            f"PSNR per held-out camera on {scene} (mean over each camera's test views): a mean over few "
            "cameras can be one camera's failure.",
            "",
            "| expert | PSNR | " + " | ".join(f"camera {c}" for c in cameras) + " |",
            "|---|---|" + "---|" * len(cameras),
        ]
        for r in rows:
            values = " | ".join(_num(r["psnr_cameras"].get(c)) for c in cameras)
            lines.append(f"| {r['expert']} | {_num(r['psnr']['full'])} | {values} |")
    return lines


def noise_markdown(noise: dict[str, Any]) -> list[str]:
    """The seed spreads claims are judged against (``bench.signals.seed_noise``), a row per scene."""
    fallback = noise.get("metrics") or {}
    scenes = noise.get("scenes") or {}
    if not scenes:
        return ["- **Noise**: no row finished two seeds and none was borrowed: claims are not judged."]
    lines = [
        "- **Noise**: a comparison of two rows that trained with the same seeds is judged against the "
        "spread of their per-seed difference (paired spread: shared experts or seeds make it smaller than "
        "either row's own); of rows that trained with several seeds otherwise, against the larger of "
        "their own seed-to-seed spreads (max - min over seeds); any other against the largest spread of its "
        "table's scenes: a scene's own where its cells were trained with several seeds, else the "
        "largest spread measured on a stand-in; a scene this run trains once borrows the "
        f"{NOISE_PROXY} run's spread on it where there is one (marked)"
        + (
            f" ({', '.join(noise.get('source') or [])}: PSNR {_num(fallback.get('PSNR'))} dB, dynamic-region "
            f"PSNR {_num(fallback.get('PSNR dynamic'))} dB)"
            if fallback
            else " (none measured)"
        )
        + ". A claim whose margin is inside it is reported as 'within noise', not as held or failed, with "
        "the way it leans: 'with the paper' when its comparisons hold at zero noise, 'against the paper' "
        "when they fail.",
        "",
        "| scene | seeds | from | PSNR spread per row (dB) | paired PSNR spread (dB) | largest "
        "| largest, dynamic region |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, entry in sorted(scenes.items()):
        rows = ", ".join(f"{row} {_num(v.get('PSNR'))}" for row, v in entry["rows"].items())
        metrics, label = entry["metrics"], name + ("" if entry["real"] else " (stand-in)")
        borrowed = entry.get("preset") not in (None, noise.get("preset")) or "committed" in entry
        run = f"{entry['preset']} run" + (f", {entry['committed']}" if entry.get("committed") else "")
        source = ", ".join(entry["source"]) + (f" ({run})" if borrowed else "")
        if entry.get("pooled_with"):
            own = (entry.get("own_metrics") or {}).get("PSNR")
            source += f"; pooled with {entry['pooled_with']} (this run's own largest: {_num(own)})"
        pairs = ", ".join(
            f"{a} - {b} {_num(p['metrics'].get('PSNR'))}"
            for p in entry.get("pairs") or []
            for a, b in [p["rows"]]
        )
        lines.append(
            f"| {label} | {entry['seeds']} | {source} | {rows} | {pairs or '–'} "
            f"| {_num(metrics.get('PSNR'))} | {_num(metrics.get('PSNR dynamic'))} |"
        )
    return [*lines, ""]


def signals_markdown(signals: dict[str, Any]) -> list[str]:
    """The run's motion, routing and noise evidence (``bench.signals``) as markdown lines."""
    lines = ["## Motion, routing and noise", ""]
    lines += noise_markdown(signals.get("noise") or {})
    experts = signals.get("experts") or []
    lines += motion_lines(experts)
    if experts:
        lines += [
            "",
            "Every expert cell (seed 0), PSNR on the full image, the dynamic region and the static region "
            "(stand-ins: ground-truth dynamic masks; D-NeRF: object alpha; Panoptic: foreground masks). "
            "Motion R² = the share of the dynamic region's change over time that the renders reproduce, "
            "at the test cameras seen at several times (0: a render that does not move, 1: the ground "
            "truth's motion exactly; `moegs.metrics.motion`; – where no test camera repeats with masks):",
            "",
            "| scene | dataset recipe | expert | PSNR full | PSNR dynamic | PSNR static | LPIPS dynamic "
            "| motion R² |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in experts:
            p, lp = r["psnr"], r["lpips"]
            lines.append(
                f"| {r['scene']} | {r['dataset']} | {r['expert']} | {_num(p['full'])} | {_num(p['dynamic'])} "
                f"| {_num(p['static'])} | {_num(lp['dynamic'], 3)} | {_num(r.get('motion_r2'))} |"
            )
    lines += regime_markdown(experts)
    lines += camera_markdown(experts)
    routing = signals.get("routing") or []
    if routing:
        lines += [
            "",
            "Routing (MoE-GS cells, seed 0): coherence = share of pixels whose winning expert is the "
            "majority of its 5x5 neighbourhood (about 0.5 for noise with 3 experts); shares = fraction "
            "of the dynamic / static pixels each expert wins:",
            "",
            "| table | row | scene | experts | coherence | dynamic share | static share |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in routing:
            share = lambda xs: " / ".join(f"{x:.2f}" for x in xs)  # noqa: E731
            lines.append(
                f"| {r['table']} | {r['row']} | {r['scene']} | {', '.join(r['experts'])} | "
                f"{_num(r['coherence'], 3)} | {share(r['dynamic_share'])} | {share(r['static_share'])} |"
            )
    return lines + pruning_markdown(signals.get("pruning") or []) + [""]


def pruning_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The pruned MoE-GS cells: Gaussians before and after, the share removed, and the paper's memory
    reduction of the same row (against its table's unpruned row)."""
    if not rows:
        return []
    lines = [
        "",
        "Pruning (gate-aware, `moegs.moe.prune`): the share of the experts' Gaussians each pruned MoE-GS "
        "cell removed, while the router trained or once after; the paper reports memory, whose share "
        "removed is given against its table's unpruned row:",
        "",
        "| table | row | scene | seed | when | Gaussians | removed | paper: memory removed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        paper = r["paper_memory_removed"]
        lines.append(
            f"| {r['table']} | {r['row']} | {r['scene']} | {r['seed']} | {r['when']} | "
            f"{r['before']} -> {r['after']} | {100 * r['removed']:.1f}% | "
            f"{'-' if paper is None else f'{100 * paper:.0f}%'} |"
        )
    return lines


def convergence_studies(base: Path) -> list[tuple[Path, Path]]:
    """``(figure, table)`` of each ``python -m bench.convergence`` study under ``base/convergence``."""
    folder = base / "convergence"
    return [
        (md.with_suffix(".png"), md) for md in sorted(folder.glob("*.md")) if md.with_suffix(".png").is_file()
    ]


CONVERGENCE_NOTE = (
    "Scenes trained beyond the quick preset (`python -m bench.convergence`): quick schedules scaled "
    "to N iterations, every test view; 'upsampled to native' renders at the training resolution and "
    "upsamples (bicubic) to the dataset's resolution; motion R² as in the section above. Not part of the "
    "tables above."
)


def convergence_markdown(base: Path) -> list[str]:
    studies = convergence_studies(base)
    if not studies:
        return []
    lines = ["## Convergence beyond the quick preset", "", CONVERGENCE_NOTE, ""]
    for figure, table in studies:
        lines += [f"### {_study_title(table.with_suffix('.json'), figure.stem)}", ""]
        lines += [f"![{figure.stem}](convergence/{figure.name})", "", table.read_text().strip(), ""]
    return lines


def _study_title(summary: Path, stem: str) -> str:
    """``scene`` of a study's JSON and the variant its cells share (initial points, seed)."""
    from bench.convergence import Variant

    if not summary.is_file():
        return stem
    data = json.loads(summary.read_text())
    cells = data.get("cells") or [{}]
    return f"{data.get('scene', stem)}{Variant.of(cells[0]).words}"


def presets_markdown(comparisons: list[Any]) -> list[str]:
    """The paper | standard | quick section (``bench.sidebyside.Comparison`` list; empty: no section)."""
    from bench.sidebyside import LEGEND, markdown

    if not comparisons:
        return []
    lines = ["## Real scenes: paper | standard | quick", "", LEGEND, ""]
    for cmp in comparisons:
        lines += [f"### {cmp.spec.id}: {cmp.spec.title}", "", markdown(cmp), ""]
    return lines


def compute_markdown(compute: dict[str, Any]) -> list[str]:
    """What the cells cost (``bench.signals.compute_rows``): builds by what they made, evaluations by kind."""
    if not compute.get("builds") and not compute.get("evaluations"):
        return []
    lines = [
        "## What the cells cost",
        "",
        f"The report's cells took **{compute['minutes']:.1f} minutes** of single-process wall clock, as each "
        "recorded it when it was computed (a build once, however many cells share it; a run with `--jobs N` "
        "divides the wall clock by up to N; timings of cells reused from earlier runs are theirs):",
        "",
        "| build | made | count | minutes |",
        "|---|---|---|---|",
        *(f"| {r['kind']} | {r['what']} | {r['count']} | {r['minutes']:.1f} |" for r in compute["builds"]),
        "",
        "| evaluation | count | minutes |",
        "|---|---|---|",
        *(f"| {r['kind']} | {r['count']} | {r['minutes']:.1f} |" for r in compute["evaluations"]),
        "",
    ]
    return lines


def values_markdown(values: list[dict[str, Any]]) -> list[str]:
    """Our value of every computed cell of a table, one markdown row per table row: ``ours`` and, where
    ours ran on the paper's real scene, ``paper P (Δ D)`` beside it."""
    if not values:
        return []
    rows = list(dict.fromkeys(v["row"] for v in values))
    cells = list(dict.fromkeys((v["column"], v["metric"]) for v in values))
    at = {(v["row"], v["column"], v["metric"]): v for v in values}

    def text(v: dict[str, Any] | None) -> str:
        if v is None:
            return "–"
        if v["paper"] is None:
            return f"{v['ours']:.4g}"
        return f"{v['ours']:.4g} · paper {v['paper']:.4g} (Δ {v['ours'] - v['paper']:+.3g})"

    heads = [c if c == m else f"{c} {m}" for c, m in cells]
    return [
        "| row | " + " | ".join(heads) + " |",
        "|---|" + "---|" * len(heads),
        *(f"| {r} | " + " | ".join(text(at.get((r, c, m))) for c, m in cells) + " |" for r in rows),
        "",
    ]


MAX_SUGGESTED_SEEDS = 10
"""More seeds than this per row are not suggested: such a claim sits too close to its boundary."""


def more_seeds(reports: list[SpecReport], preset: str) -> list[dict[str, Any]]:
    """Per table with undecided paper claims: ``{"spec", "trained", "undecided", "decidable", "seeds",
    "command"}``: the seeds its rows trained, and the seeds per row that would decide its ``decidable``
    claims (each estimated by ``seeds_to_decide``, more than it trained and at most
    ``MAX_SUGGESTED_SEEDS``) with the command that trains them (``--seeds``)."""
    out = []
    for rep in reports:
        undecided = [c for c in rep.claims if c.get("kind", "paper") == "paper" and c["ours"] == NOISE]
        needs = [c.get("ours_seeds_to_decide") for c in undecided]
        decidable = [n for n in needs if n is not None and rep.seeds < n <= MAX_SUGGESTED_SEEDS]
        if not undecided or rep.kind == "figure":  # a figure draws one seed whatever --seeds asks
            continue
        seeds = max(decidable, default=None)
        command = f"python -m bench.all {preset_flag(preset)} --tables {rep.id} --seeds {seeds}"
        out.append(
            {
                "spec": rep.id,
                "trained": rep.seeds,
                "undecided": len(undecided),
                "decidable": len(decidable),
                "seeds": seeds,
                "command": command if seeds else None,
            }
        )
    return out


def more_seeds_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The report's "More seeds" section: which tables' undecided paper claims more seeds would decide."""
    if not rows:
        return []
    lines = [
        "## More seeds",
        "",
        "Undecided paper claims per table, and the seeds per row that would decide those that more seeds "
        f"than the table trained, and at most {MAX_SUGGESTED_SEEDS}, would decide (a spread shrinking as "
        "1/sqrt(seeds)); the others sit too close to their boundary, or stay undecided because each is "
        "judged against the spread of single seeds. Seeds a stability run trained are reused.",
        "",
        "| table | seeds trained | undecided | decided by more seeds | seeds per row | command |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        command = f"`{r['command']}`" if r["command"] else "–"
        lines.append(
            f"| {r['spec']} | {r['trained']} | {r['undecided']} | {r['decidable']} | {r['seeds'] or '–'} "
            f"| {command} |"
        )
    return [*lines, ""]


def _kinds(kind_seconds: dict[str, float]) -> str:
    """``build expert 40.1 min, build moe 12.0 min, ...``, the largest first."""
    return ", ".join(f"{k} {m:.1f} min" for k, m in by_kind(kind_seconds).items())


def render_markdown(
    reports: list[SpecReport], header: dict[str, Any], base: Path, signals: dict[str, Any] | None = None
) -> str:
    h = header
    lines = [
        "# moegs reproduction report",
        "",
        f"- created: {h['created']} on {h['machine']}",
        f"- preset: **{h['preset']}** ({h['preset_description']})"
        + (" - **reduced scale: numbers are not the paper's protocol**" if h["reduced_scale"] else ""),
        f"- device: **{h.get('device', 'cpu')}** (part of every cell's key: CPU and GPU numbers never mix)",
        f"- library code version: `{h['moegs_code_version']}`, git: `{h['git'].get('commit')}`"
        + (" (moegs has uncommitted changes)" if h["git"].get("dirty") else ""),
        *(
            [
                f"- cells: {c['tasks']} builds and evaluations of {len(c['specs'])} specs, keys digest "
                f"`{c['keys_digest']}` (each key holds the version of the code its cell runs: these outputs "
                "are those of the current code while a new plan gives the same digest, "
                "`tests/bench/test_committed_outputs.py`)"
            ]
            if (c := h.get("cells"))
            else []
        ),
        *history_markdown(h.get("history", [])),
        "- Numbers come only from local result JSONs (ours) and `tables/paper` (the paper). "
        "Δ = ours - paper, shown only where ours ran on the paper's real scene(s); "
        "outputs from synthetic stand-in scenes say so.",
        "",
        *CONVENTIONS,
        "",
    ]
    if h["run"]:
        r = h["run"]
        lines += [
            f"- this run: {r.get('builds_run', 0)} builds + {r.get('evals_run', 0)} evaluations run, "
            f"{r.get('builds_reused', 0)} builds + {r.get('evals_reused', 0)} evaluations reused, "
            f"{len(r.get('failures', []))} failed, {r.get('seconds', 0):.0f} s"
            + (f"; cell time by kind: {_kinds(r['kind_seconds'])}" if r.get("kind_seconds") else ""),
            "",
        ]
    lines += signals_markdown(signals or {})
    lines += presets_markdown((signals or {}).get("presets", []))
    lines += convergence_markdown(base)
    lines += compute_markdown((signals or {}).get("compute", {}))
    lines += [
        "## Summary",
        "",
        "| id | title | status | claims (ours) | largest Δ |",
        "|---|---|---|---|---|",
    ]
    for rep in reports:
        d = rep.deltas[0] if rep.deltas else None
        delta = f"{d['row']} / {d['column']} {d['metric']}: {d['delta']:+.3f}" if d else "–"
        lines.append(f"| {rep.id} | {rep.title} | {rep.status} | {_claim_counts(rep)} | {delta} |")
    lines += ["", *more_seeds_markdown(more_seeds(reports, h["preset"]))]
    for rep in reports:
        lines += ["", f"## {rep.id}: {rep.title}", "", f"**Status:** {rep.status}", ""]
        if rep.scenes:
            lines.append("**Scenes:** " + "; ".join(rep.scenes))
        if rep.latex:
            lines.append(f"**LaTeX:** `{_rel(rep.latex, base)}`")
        if rep.notes:
            lines.append(f"**Notes:** {rep.notes}")
        lines.append("")
        lines += values_markdown(rep.values)
        if rep.claims:
            lines += ["| claim | kind | ours | paper's numbers | detail (ours) |", "|---|---|---|---|---|"]
            for c in rep.claims:
                lines.append(
                    f"| {c['text']} ({c['source']}) | {c.get('kind', 'paper')} | {verdict(c)} | "
                    f"{c['paper']} | {c['ours_detail'].replace('|', '/')} |"
                )
            lines.append("")
        if rep.deltas:
            lines += ["Largest deltas (comparable cells):", ""]
            lines += [
                f"- {d['row']} / {d['column']} / {d['metric']}: ours {d['ours']:.4g} vs paper "
                f"{d['paper']:.4g} (Δ {d['delta']:+.3f})"
                for d in rep.deltas
            ]
            lines.append("")
        ni = {r: s for r, s in rep.rows.items() if s.startswith("not implemented")}
        if ni:
            lines += ["Rows not implemented yet:", ""] + [f"- {r}: {s}" for r, s in ni.items()] + [""]
        if rep.failures:
            lines += (
                ["Failed cells:", ""]
                + [f"- {f['row']} on {f['scene']} (seed {f['seed']}): {f['detail']}" for f in rep.failures]
                + [""]
            )
        for err in rep.invalid_results:
            lines.append(f"- invalid result file: {err}")
        for fig in rep.figures:
            lines.append(f"![{rep.id}]({_rel(fig, base)})")
    return "\n".join(lines) + "\n"


HTML_STYLE = (
    "body{font-family:sans-serif;max-width:1200px;margin:auto;padding:0 1em;line-height:1.4}"
    "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 6px;"
    "font-size:13px;vertical-align:top}th{background:#f4f4f4}img{max-width:100%}"
    "nav{columns:2;font-size:14px}code{background:#f4f4f4;padding:0 3px}"
)


def _slug(text: str) -> str:
    """An anchor for a heading: ``tab03: MoE-GS ...`` -> ``tab03-moe-gs-...``."""
    words = "".join(ch if ch.isalnum() else " " for ch in text.lower()).split()
    return "-".join(words)


def render_html(markdown_text: str) -> str:
    """``REPORT.html``: the markdown report rendered as it is (every section, the same numbers), with a
    table of contents of its sections; figures stay beside it in ``figures/`` and are linked."""
    from markdown_it import MarkdownIt

    parser = MarkdownIt("commonmark", {"html": False}).enable("table")
    tokens = parser.parse(markdown_text)
    toc: list[tuple[str, str, str]] = []
    for heading, inline in zip(tokens, tokens[1:], strict=False):
        if heading.type == "heading_open" and heading.tag in ("h2", "h3"):
            anchor = base = _slug(inline.content)
            while any(anchor == a for _, a, _ in toc):  # a title used twice gets its own anchor
                anchor = f"{base}-{sum(a.startswith(base) for _, a, _ in toc) + 1}"
            heading.attrSet("id", anchor)
            toc.append((heading.tag, anchor, inline.content))
    title = "moegs reproduction report"
    links = "".join(
        f"<li{' style=margin-left:1em' if tag == 'h3' else ''}><a href='#{a}'>{html.escape(t)}</a></li>"
        for tag, a, t in toc
    )
    body = parser.renderer.render(tokens, parser.options, {})
    head, sep, rest = body.partition("</h1>\n")  # the contents go under the title
    nav = f"<nav><b>Contents</b><ul>{links}</ul></nav>\n"
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{title}</title>"
        f"<style>{HTML_STYLE}</style></head><body>\n"
        + (head + sep + nav + rest if sep else nav + body)
        + "</body></html>\n"
    )


def _relative(spec: dict[str, Any], base: Path) -> dict[str, Any]:
    """A spec report with its LaTeX and figure paths relative to ``base`` (no machine's absolute paths)."""
    latex = spec.get("latex")
    return {
        **spec,
        "latex": _rel(latex, base) if latex else None,
        "figures": [_rel(f, base) for f in spec.get("figures", [])],
    }


def write_report(
    reports: list[SpecReport],
    preset: BenchPreset,
    out_dir: Path,
    run: dict[str, Any] | None = None,
    signals: dict[str, Any] | None = None,
    cells: dict[str, Any] | None = None,
    history: list[dict[str, Any]] | None = None,
    device: str = "cpu",
) -> dict[str, Path]:
    """Write REPORT.md, REPORT.html and summary.json into ``out_dir``; ``signals`` (``bench.signals``:
    ``noise``, ``experts``, ``routing``, ``pruning``, ``compute``) go into the report and into summary.json
    as top-level keys; ``cells``: the plan's ``identity()``, in the header; ``history``: the workspace's
    earlier runs of that plan (``bench.runlog``), in the header; ``device``: the run's device
    (``bench.all``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    header = _header(preset, run, cells, history, device)
    signals = signals or {}
    paths = {"md": out_dir / "REPORT.md", "html": out_dir / "REPORT.html", "json": out_dir / "summary.json"}
    markdown_text = render_markdown(reports, header, out_dir, signals)
    write_text_atomic(paths["md"], markdown_text)
    write_text_atomic(paths["html"], render_html(markdown_text))
    summary = {
        "header": header,
        "noise": signals.get("noise", {}),
        "experts": signals.get("experts", []),
        "routing": signals.get("routing", []),
        "pruning": signals.get("pruning", []),
        "compute": signals.get("compute", {}),
        "more_seeds": more_seeds(reports, preset.name),
        "specs": [_relative(asdict(r), out_dir) for r in reports],
    }
    write_text_atomic(paths["json"], json.dumps(summary, indent=1, default=str) + "\n")
    return paths
