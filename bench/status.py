"""The README's status at a glance, from the committed summaries: ``python -m bench.status [--readme R]``.

Reads ``reports/summary.json`` (the quick run) and ``reports/standard/summary.json`` and answers, with their
numbers only, the questions the suite exists for: how the paper's claims fare on our numbers, how much of
the motion the experts reproduce at ``quick`` (against issue 12's floors), whether routing follows the
motion, and how close the real scenes come to the paper at ``standard``. The README's ``results:status``
section is this module's output, so it changes exactly when the committed outputs do
(``tests/bench/test_status.py`` checks that it matches them).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import Any

from bench.claims import AGAINST_PAPER, NOISE
from bench.readme import paper_name, update_readme
from bench.runlog import last_computing, took
from moegs.io import read_json

QUICK = Path("reports") / "summary.json"
STANDARD = Path("reports") / "standard" / "summary.json"
"""Defaults, relative to the working directory (where ``bench.all`` writes its outputs)."""

VERDICTS = ("held", "failed", "within noise", "not judged", "n/a")
MOTION_SCENE, MOTION_RECIPE = "synthetic:n3v_like", "n3v"
"""Issue 12's floors are stated on the N3V stand-in, trained with the N3V recipes."""
FLOOR_EXPERTS = ("fourdgs", "ed3dgs", "ex4dgs", "stg")
FLOOR, BEST_FLOOR = 25.0, 28.0
"""Dynamic-region PSNR (dB) each of ``FLOOR_EXPERTS`` should reach at quick, and the best expert."""
ROUTING_ROW = ("tab03", "MoE-GS (N=3)")
COHERENCE_TARGET = 0.6


def _met(ok: bool) -> str:
    return "met" if ok else "missed"


def _claims(summary: dict[str, Any], kind: str | None) -> list[dict[str, Any]]:
    """The summary's claims of ``kind`` (``bench.spec.CLAIM_KINDS``; None: all)."""
    every = [claim for spec in summary["specs"] for claim in spec["claims"]]
    return [c for c in every if kind is None or c.get("kind", "paper") == kind]


def claim_counts(summary: dict[str, Any], kind: str | None = None) -> Counter:
    """How many of the summary's claims (of ``kind``) each verdict got (``VERDICTS``)."""
    return Counter(claim["ours"] for claim in _claims(summary, kind))


def claims_cell(summary: dict[str, Any], kind: str | None = "paper") -> str:
    """The verdicts of the claims of ``kind``: ``18 held, 15 failed, 43 within noise (32 against the
    paper), 3 n/a (of 79)``; ``none`` when the run has no such claim."""
    counts = claim_counts(summary, kind)
    against = sum(claim.get("ours_leans") == AGAINST_PAPER for claim in _claims(summary, kind))
    parts = [
        f"{counts[v]} {v}" + (f" ({against} {AGAINST_PAPER})" if v == NOISE else "")
        for v in VERDICTS
        if counts[v]
    ]
    return f"{', '.join(parts)} (of {sum(counts.values())})" if parts else "none"


def regimes_cell(regimes: dict[str, float] | None) -> str:
    """The motion regimes' PSNR (dB), best to worst: ``nonrigid 34.3, articulated 27.7, ...``."""
    if not regimes:
        return "–"
    return ", ".join(f"{name} {psnr:.1f}" for name, psnr in sorted(regimes.items(), key=lambda kv: -kv[1]))


def motion_rows(summary: dict[str, Any]) -> list[str]:
    """One markdown row per expert on the N3V stand-in with its own recipe: dynamic-region PSNR, motion R²,
    the floor and each motion regime's PSNR, best first; then the best expert against ``BEST_FLOOR``."""
    rows = [r for r in summary["experts"] if r["scene"] == MOTION_SCENE and r.get("dataset") == MOTION_RECIPE]
    rows.sort(key=lambda r: -r["psnr"]["dynamic"])
    out = []
    for r in rows:
        dynamic, r2 = r["psnr"]["dynamic"], r.get("motion_r2")
        floor = f"≥ {FLOOR:g}: {_met(dynamic >= FLOOR)}" if r["expert"] in FLOOR_EXPERTS else "–"
        r2_text = "–" if r2 is None else f"{r2:.2f}"
        regimes = regimes_cell(r.get("psnr_regimes"))
        out.append(f"| {paper_name(r['expert'])} | {dynamic:.2f} | {r2_text} | {floor} | {regimes} |")
    if rows:
        best = rows[0]["psnr"]["dynamic"]
        out.append(f"| best | {best:.2f} | | ≥ {BEST_FLOOR:g}: {_met(best >= BEST_FLOOR)} | |")
    return out


def routing_cell(summary: dict[str, Any]) -> str:
    """Coherence of the N=3 winner map and what each expert wins, dynamic against static pixels."""
    table, row = ROUTING_ROW
    entry = next((r for r in summary["routing"] if r["table"] == table and r["row"] == row), None)
    if entry is None:
        return "not in this run"
    coherence = entry["coherence"]
    shares = "; ".join(
        f"{paper_name(e)} {d:.0%} / {s:.0%}"
        for e, d, s in zip(entry["experts"], entry["dynamic_share"], entry["static_share"], strict=True)
    )
    return (
        f"{table} {row}: winner-map coherence {coherence:.2f} (≥ {COHERENCE_TARGET:g}: "
        f"{_met(coherence >= COHERENCE_TARGET)}); dynamic / static pixels won: {shares}"
    )


def real_scene_rows(standard: dict[str, Any], quick: dict[str, Any]) -> list[str]:
    """PSNR of every row of the standard run that has a paper value, with its quick value beside it."""
    quick_values = {
        (spec["id"], v["row"], v["column"], v["metric"]): v["ours"]
        for spec in quick["specs"]
        for v in spec.get("values", [])
    }
    out = []
    for spec in standard["specs"]:
        for v in spec.get("values", []):
            if v["metric"] != "PSNR" or v["paper"] is None:
                continue
            q = quick_values.get((spec["id"], v["row"], v["column"], v["metric"]))
            quick_text = "–" if q is None else f"{q:.2f} ({q - v['paper']:+.2f})"
            out.append(
                f"| {spec['id']} | {v['row']} | {v['column']} | {v['paper']:.2f} | "
                f"{v['ours']:.2f} ({v['ours'] - v['paper']:+.2f}) | {quick_text} |"
            )
    return out


def wall_clock_cell(summary: dict[str, Any]) -> str:
    """The recorded wall clock of the run that computed the cells (``bench.runlog``), or why there is none."""
    run = last_computing(summary["header"].get("history", []))
    if run is None:  # rendered before bench.runlog existed, or the workspace recorded only warm runs
        return "not recorded"
    failed = f", {run['failures']} cells failed" if run["failures"] else ""
    return took(run, machine=False) + failed


def section(quick: dict[str, Any], standard: dict[str, Any]) -> str:
    """The README section (markdown) from the two summaries."""
    lines = [
        "| | quick | standard |",
        "|---|---|---|",
        f"| the paper's claims on our numbers | {claims_cell(quick)} | {claims_cell(standard)} |",
        f"| sanity checks (true by construction: not reproductions) | {claims_cell(quick, 'sanity')} | "
        f"{claims_cell(standard, 'sanity')} |",
        f"| the paper's PSNR claims on the dynamic region (ours) | {claims_cell(quick, 'suite')} | "
        f"{claims_cell(standard, 'suite')} |",
        f"| cells (single-process minutes) | {quick['compute']['minutes']:.1f} | "
        f"{standard['compute']['minutes']:.1f} |",
        f"| wall clock of the run that computed them | {wall_clock_cell(quick)} | "
        f"{wall_clock_cell(standard)} |",
        "",
        f"Motion at quick ({MOTION_SCENE}, {MOTION_RECIPE} recipes; the suite's motion floors, dynamic "
        "region):",
        "",
        "| expert | PSNR dynamic | motion R² | floor | motion regimes, best to worst (dB) |",
        "|---|---|---|---|---|",
        *motion_rows(quick),
        "",
        f"Routing at quick: {routing_cell(quick)}.",
        "",
        "Real scenes, PSNR (Δ = ours - paper):",
        "",
        "| table | row | scene | paper | standard | quick |",
        "|---|---|---|---|---|---|",
        *real_scene_rows(standard, quick),
        "",
        "Written by `python -m bench.status --readme README.md` from `reports/summary.json` and "
        "`reports/standard/summary.json`; their headers name the code and the machine of every number.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.status", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", type=Path, default=QUICK, help="the quick run's summary.json")
    p.add_argument("--standard", type=Path, default=STANDARD, help="the standard run's summary.json")
    p.add_argument("--readme", type=Path, help="rewrite this file's results:status section")
    args = p.parse_args(argv)
    try:
        text = section(read_json(args.quick, "quick summary"), read_json(args.standard, "standard summary"))
        if args.readme:
            update_readme(args.readme, "status", text)
    except (OSError, ValueError) as err:
        print(f"bench.status: {err}", file=sys.stderr)
        return 2
    except KeyError as err:
        print(
            f"bench.status: {args.quick} or {args.standard} lacks the field {err}: written by an older "
            "harness? Rewrite them with `python -m bench.all --no-run` (and `--preset standard`).",
            file=sys.stderr,
        )
        return 2
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
