"""Measured-vs-published docs sections: ``python -m bench.readme docs/results.md --scene dnerf:mutant``.

Runs (or reuses) ``moegs compare`` for the experts on the scene, then rewrites the section between
``<!-- results:<scene> -->`` and ``<!-- /results:<scene> -->`` of the markdown file (``<scene>`` is the part
after the colon, e.g. ``mutant``; ``--section`` overrides it) with the measured table next to the published
full-scale numbers of the same scene: the experts' own papers (``tables/paper/originals/``) and the MoE-GS
paper (``tables/paper/tabNN.json``), each with its source. Nothing in that section is typed by hand.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
from pathlib import Path
from typing import Any

from bench.paper import load_original_table, load_paper_table
from bench.results import write_text_atomic
from bench.spec import EXPERTS, QUALITY

ROW_ALIASES = {"static": "3D-GS"}
"""Registry names whose published row is spelled otherwise than the MoE-GS paper's (DeformableGS's Table 1
prints "3D-GS", the MoE-GS paper "3DGS")."""
PUBLISHED = {"dnerf:mutant": {"column": "Mutant", "originals": ["dnerf_mutant"], "moegs": ["tab17"]}}
"""Published full-scale numbers per scene: the column name in the tables, the experts' own papers
(``tables/paper/originals/<id>.json``) and the MoE-GS paper's tables (``tables/paper/<id>.json``)."""


def paper_name(expert: str) -> str:
    """The row name the published tables use for a registry name (``bench.spec.EXPERTS`` reversed)."""
    if expert in ROW_ALIASES:
        return ROW_ALIASES[expert]
    return next((paper for paper, key in EXPERTS.items() if key == expert), expert)


def published_numbers(scene: str) -> list[dict]:
    """The published full-scale numbers of ``scene`` (``PUBLISHED``), one entry per source table.

    Returns ``[{"kind": "original" | "moegs", "title", "rows": {row: {metric: value record}}}]``; a
    value record has ``printed`` and, for the experts' own papers, ``source``. Empty when none.
    """
    spec = PUBLISHED.get(scene)
    if spec is None:
        return []
    out = []
    for kind, ids, load in (
        ("original", spec["originals"], load_original_table),
        ("moegs", spec["moegs"], load_paper_table),
    ):
        for table_id in ids:
            table = load(table_id)
            rows: dict[str, dict] = {}
            for v in table.values:
                if v["column"] == spec["column"]:
                    rows.setdefault(v["row"], {})[v["metric"]] = v
            title = (
                f"experts' own papers (`tables/paper/originals/{table_id}.json`)"
                if kind == "original"
                else f"MoE-GS paper, Table {table.numeral} (`tables/paper/{table_id}.json`): {table.caption}"
            )
            out.append({"kind": kind, "id": table_id, "numeral": table.numeral, "title": title, "rows": rows})
    return out


def machine_line() -> str:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} logical CPUs"


def readme_section(table: dict, published: list[dict], machine: str | None = None) -> str:
    """Markdown for the README: measured rows of ``table`` (from :func:`compare`) beside ``published``.

    Measured columns come from each run's result; published ones from ``published`` (see
    :func:`published_numbers`) with a numbered source per cell. Rows of the published tables that no
    expert maps to (e.g. "MoE-GS (N=2)") are appended with empty measured cells.
    """

    def num(value: Any, digits: int) -> str:
        return (
            "n/a"
            if value is None or (isinstance(value, float) and math.isnan(value))
            else f"{value:.{digits}f}"
        )

    sources: list[str] = []

    def cite(text: str) -> int:
        if text not in sources:
            sources.append(text)
        return sources.index(text) + 1

    def published_cell(entry: dict, row: str) -> str:
        cells = entry["rows"].get(row)
        if not cells:
            return "–"
        metrics = [m for m in QUALITY if m in cells]
        text = " / ".join(cells[m]["printed"] for m in metrics)
        refs = sorted({cite(cells[m].get("source") or entry["title"]) for m in metrics})
        label = "" if tuple(metrics) == QUALITY else f" ({'/'.join(metrics)})"
        return f"{text}{label} " + "".join(f"[{r}]" for r in refs)

    rows = table["rows"]
    static = next((r["psnr"] for r in rows if r["expert"] == "static"), None)
    head = [
        "expert",
        "method",
        "PSNR",
        "SSIM",
        "LPIPS",
        "Δ PSNR vs static",
        "train (s)",
        "Gaussians",
        "iterations",
    ]
    head += [
        "published: own paper" if e["kind"] == "original" else f"published: MoE-GS Tab. {e['numeral']}"
        for e in published
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    mapped = set()
    for r in rows:
        name = paper_name(r["expert"])
        mapped.add(name)
        delta = "–" if static is None or r["expert"] == "static" else f"{r['psnr'] - static:+.2f}"
        expert = r["expert"] + (" (stand-in data)" if r.get("stand_in") else "")
        cells = [expert, name, num(r["psnr"], 2), num(r["ssim"], 4), num(r["lpips"], 4), delta]
        cells += [num(r["train_seconds"], 0), str(r["num_gaussians"]), str(r["iterations"])]
        cells += [published_cell(e, name) for e in published]
        lines.append("| " + " | ".join(cells) + " |")
    extra = [row for e in published for row in e["rows"] if row not in mapped]
    for row in dict.fromkeys(extra):
        cells = ["–", row] + ["–"] * 7 + [published_cell(e, row) for e in published]
        lines.append("| " + " | ".join(cells) + " |")

    sizes = sorted({r.get("image_size") or "?" for r in rows})
    profiles = sorted({r.get("metric_profile") or "?" for r in rows})
    scene = table["scene"]
    names = ",".join(r["expert"] for r in rows)
    command = (
        f"python -m bench.readme --experts {names} --scene {scene} --preset {table['preset']} docs/results.md"
    )
    where = Path(rows[0]["run"]).parent if rows else "?"
    intro = [
        f"Measured: `{scene}`, preset `{table['preset']}` (reduced scale: {', '.join(sizes)} images, the "
        f"iterations below, CPU), test split; metric profile {', '.join(f'`{p}`' for p in profiles)}. "
        "Published: the same scene at full scale (the papers' resolution and schedules, GPU), so the "
        "absolute values are not comparable; the measured rows compare the experts with each other "
        "and with the `static` (no-deformation) baseline on one budget.",
        "",
        f"Generated by `{command}` (re-runs reuse the finished runs under `{where}`); "
        f"train (s) is each run's recorded training wall-clock time (it grows with other load on the "
        f"machine); generated on {machine or machine_line()}.",
        "",
    ]
    notes = ["", "Sources:", ""] + [f"{i}. {s}" for i, s in enumerate(sources, 1)]
    return "\n".join(intro + lines + (notes if sources else [])) + "\n"


def split_section(path: str | Path, section: str) -> tuple[str, str]:
    """``(text up to and including <!-- results:<section> -->, text from <!-- /results:<section> -->)``
    of the file at ``path``; ValueError naming the file unless it has exactly one such pair."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    start, end = f"<!-- results:{section} -->", f"<!-- /results:{section} -->"
    if text.count(start) != 1 or text.count(end) != 1 or text.index(start) > text.index(end):
        raise ValueError(f"{path}: needs exactly one '{start}' followed by one '{end}' to rewrite")
    head, rest = text.split(start, 1)
    return head + start, end + rest.split(end, 1)[1]


def update_readme(path: str | Path, section: str, body: str) -> Path:
    """Replace the text between ``<!-- results:<section> -->`` and ``<!-- /results:<section> -->``."""
    head, tail = split_section(path, section)
    write_text_atomic(Path(path), f"{head}\n{body.rstrip()}\n{tail}")
    return Path(path)


def main(argv: list[str] | None = None) -> int:
    from moegs.compare import compare

    p = argparse.ArgumentParser(prog="python -m bench.readme", description=__doc__.split("\n\n")[0])
    p.add_argument("readme", type=Path, help="markdown file with the results markers (e.g. docs/results.md)")
    p.add_argument("--scene", required=True, help="<dataset>:<scene>, e.g. dnerf:mutant")
    p.add_argument("--experts", default="all", help="comma-separated registry names, or all")
    p.add_argument("--preset", default="quick", choices=["quick", "paper"])
    p.add_argument("--out", help="runs folder (default: moegs compare's runs/compare_<scene>_<preset>)")
    p.add_argument("--section", help="section name (default: the scene name, e.g. mutant)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    args = p.parse_args(argv)
    experts = [e.strip() for e in args.experts.split(",") if e.strip()]
    section = args.section or args.scene.split(":", 1)[-1]
    try:
        split_section(args.readme, section)  # before any training
        table = compare(experts, args.scene, args.preset, args.out, progress=not args.quiet)
        body = readme_section(table, published_numbers(args.scene))
        path = update_readme(args.readme, section, body)
    except (ValueError, OSError) as err:  # OSError: a missing file, a run folder in use, a full disk
        print(f"bench.readme: {' '.join(str(err).split())}", file=sys.stderr)
        return 2
    print(f"README section '{section}' -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
