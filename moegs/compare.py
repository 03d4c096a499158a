"""``moegs compare``: train and evaluate several experts on one scene at one preset, one table.

    moegs compare --experts all --scene panoptic:basketball --preset quick
    moegs compare --experts static,stg,ex4dgs --scene dnerf:mutant --out runs/compare-mutant
    moegs compare --experts all --scene dnerf:mutant --readme README.md   # + the README results section

Each expert is built from its recipe for the scene (``moegs.recipes.config_for``: the original's
preset for the dataset, its per-scene values, the preset's reductions) and trained with the shared
training loop into ``<out>/<expert>/``; the loop's ``metrics.json`` there is the expert's result, so a
finished expert is skipped on the next call and an interrupted one resumes from its checkpoint. The
table (PSNR / SSIM / LPIPS on the scene's test views, training seconds, final number of Gaussians) is
written as ``<out>/table.md`` and ``<out>/table.json``.

``--readme README.md`` also rewrites the section between ``<!-- results:<scene> -->`` and
``<!-- /results:<scene> -->`` of that markdown file (``<scene>`` is the part after the colon, e.g.
``mutant``; ``--readme-section`` overrides it) with the measured table next to the published
full-scale numbers of the same scene: the experts' own papers (``tables/paper/originals/``) and the
MoE-GS paper (``tables/paper/tabNN.json``), each with its source. Nothing in that section is typed by
hand: measured numbers come from the runs, published ones from ``tables/paper/`` (``PUBLISHED``).

Scene loading: each recipe's background and resolution; ``--frames`` picks a frame window on datasets
that have one (the ``quick`` preset defaults to the first ``QUICK_FRAMES`` frames there).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
from pathlib import Path
from typing import Any

QUICK_FRAMES = (0, 5)
"""Frame window of the quick preset on multi-frame video datasets (CPU minutes for all experts)."""
WINDOWED_DATASETS = ("panoptic", "n3v", "technicolor")
"""Datasets whose loader takes ``frames=(start, stop)``."""
COLUMNS = ("expert", "psnr", "ssim", "lpips", "train_seconds", "num_gaussians", "iterations")
PAPER_NAMES = {
    "static": "3D-GS",
    "deformable": "DeformableGS",
    "grid4d": "Grid4D",
    "fourdgs": "4DGaussians",
    "ed3dgs": "E-D3DGS",
    "stg": "STG",
    "ex4dgs": "Ex4DGS",
    "mcmc": "3DGS-MCMC",
}
"""Registry name -> the row name the published tables use for that method."""
PUBLISHED = {"dnerf:mutant": {"column": "Mutant", "originals": ["dnerf_mutant"], "moegs": ["tab17"]}}
"""Published full-scale numbers per scene: the column name in the tables, the experts' own papers
(``tables/paper/originals/<id>.json``) and the MoE-GS paper's tables (``tables/paper/<id>.json``)."""


def _frames(scene: str, preset: str, frames: tuple[int, int] | None) -> tuple[int, int] | None:
    dataset = scene.split(":", 1)[0].lower()
    if frames is not None and dataset not in WINDOWED_DATASETS:
        raise ValueError(f"--frames applies to {', '.join(WINDOWED_DATASETS)} scenes, not {scene!r}")
    if frames is None and preset == "quick" and dataset in WINDOWED_DATASETS:
        return QUICK_FRAMES
    return frames


def _finished(path: Path) -> dict | None:
    """The loop's ``metrics.json`` of a completed run, or None."""
    if not path.is_file():
        return None
    result = json.loads(path.read_text())
    return result if result.get("completed") and result.get("test") else None


def scene_kwargs(recipe, frames: tuple[int, int] | None) -> dict[str, Any]:
    """``load_scene`` arguments of a run: the recipe's (background, resolution) and the frame window."""
    kwargs = dict(recipe.load_kwargs)
    if frames is not None:
        kwargs["frames"] = frames
    return kwargs


def run_expert(
    name: str,
    scene_name: str,
    preset: str,
    out: Path,
    frames: tuple[int, int] | None,
    scenes: dict,
    progress: bool,
) -> dict:
    """Train (or resume) one expert with its recipe (``moegs.recipes.config_for``); returns the loop's
    result. ``scenes`` caches loaded scenes by their loader arguments."""
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import train_recipe

    recipe = config_for(name, scene_name, preset)
    kwargs = scene_kwargs(recipe, frames)
    key = json.dumps(kwargs, sort_keys=True, default=str)
    if key not in scenes:
        scenes[key] = load_scene(scene_name, **kwargs)
    return train_recipe(recipe, scenes[key], out, progress=progress)[1]


def _image_size(test: dict) -> str | None:
    """``"100x100"`` from the per-view keys (``<scene>/<split>/<i>@WxH``), or None."""
    sizes = {m.group(1) for v in test.get("per_view", []) if (m := re.search(r"@(\d+x\d+)$", v["key"]))}
    return sizes.pop() if len(sizes) == 1 else None


def _row(name: str, result: dict, run_dir: Path) -> dict:
    test = result["test"]
    return {
        "expert": name,
        "psnr": test["psnr"],
        "ssim": test["ssim"],
        "lpips": test["lpips"],
        "train_seconds": result["train_seconds"],
        "num_gaussians": result["num_gaussians"],
        "iterations": result["iterations"],
        "stand_in": result.get("stand_in", ""),
        "run": str(run_dir),
        "image_size": _image_size(test),
        "metric_profile": (test.get("profile") or {}).get("id"),
    }


def markdown(rows: list[dict], title: str) -> str:
    """The table as GitHub markdown (LPIPS "n/a" when its weights are unavailable)."""

    def fmt(key: str, value: Any) -> str:
        if value is None:
            return "n/a"
        if key in ("psnr",):
            return f"{value:.2f}"
        if key in ("ssim", "lpips"):
            return f"{value:.4f}"
        if key == "train_seconds":
            return f"{value:.1f}"
        return str(value)

    lines = [f"# {title}", "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(fmt(k, r[k]) for k in COLUMNS) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def published_numbers(scene: str) -> list[dict]:
    """The published full-scale numbers of ``scene`` (``PUBLISHED``), one entry per source table.

    Returns ``[{"kind": "original" | "moegs", "title", "rows": {row: {metric: value record}}}]``; a
    value record has ``printed`` and, for the experts' own papers, ``source``. Empty when none.
    """
    from bench.paper import load_original_table, load_paper_table

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


def _machine() -> str:
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
        metrics = [m for m in ("PSNR", "SSIM", "LPIPS") if m in cells]
        text = " / ".join(cells[m]["printed"] for m in metrics)
        refs = sorted({cite(cells[m].get("source") or entry["title"]) for m in metrics})
        label = "" if metrics == ["PSNR", "SSIM", "LPIPS"] else f" ({'/'.join(metrics)})"
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
        name = PAPER_NAMES.get(r["expert"], r["expert"])
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
    command = f"moegs compare --experts {names} --scene {scene} --preset {table['preset']} --readme README.md"
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
        f"machine); generated on {machine or _machine()}.",
        "",
    ]
    notes = ["", "Sources:", ""] + [f"{i}. {s}" for i, s in enumerate(sources, 1)]
    return "\n".join(intro + lines + (notes if sources else [])) + "\n"


def update_readme(path: str | Path, section: str, body: str) -> Path:
    """Replace the text between ``<!-- results:<section> -->`` and ``<!-- /results:<section> -->``."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    start, end = f"<!-- results:{section} -->", f"<!-- /results:{section} -->"
    if text.count(start) != 1 or text.count(end) != 1 or text.index(start) > text.index(end):
        raise ValueError(f"{path}: needs exactly one '{start}' followed by one '{end}' to rewrite")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{body.rstrip()}\n{end}{tail}", encoding="utf-8")
    return path


def compare(
    experts: list[str],
    scene: str,
    preset: str = "quick",
    out: str | Path | None = None,
    frames: tuple[int, int] | None = None,
    progress: bool = True,
) -> dict:
    """Train and evaluate ``experts`` on ``scene`` at ``preset``; write and return the table.

    Returns:
        ``{"scene", "preset", "frames", "rows": [{"expert", "psnr", "ssim", "lpips", "train_seconds",
        "num_gaussians", "iterations", "stand_in", "run"}], "skipped": [experts whose result existed],
        "table": path of table.md}``.
    """
    from moegs.experts import get_spec, list_experts
    from moegs.io import write_json

    names = [s.name for s in list_experts() if not s.composite] if experts == ["all"] else experts
    for name in names:
        get_spec(name)  # unknown names fail before any training
    window = _frames(scene, preset, frames)
    out = Path(out) if out is not None else Path("runs") / f"compare_{scene.replace(':', '_')}_{preset}"
    rows, skipped, scenes = [], [], {}
    for name in names:
        run_dir = out / name
        result = _finished(run_dir / "metrics.json")
        if result is None:
            result = run_expert(name, scene, preset, run_dir, window, scenes, progress)
        else:
            skipped.append(name)
        rows.append(_row(name, result, run_dir))
    table = {
        "scene": scene,
        "preset": preset,
        "frames": list(window) if window else None,
        "rows": rows,
        "skipped": skipped,
        "table": str(out / "table.md"),
    }
    title = f"{scene}, preset {preset}" + (f", frames {window[0]}-{window[1] - 1}" if window else "")
    write_json(out / "table.json", table)
    (out / "table.md").write_text(markdown(rows, title))
    return table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--experts", default="all", help="comma-separated registry names, or all")
    parser.add_argument("--scene", required=True, help="<dataset>:<scene>, e.g. panoptic:basketball")
    parser.add_argument("--preset", default="quick", help="config preset of every expert (quick or paper)")
    parser.add_argument("--out", help="output folder (default runs/compare_<scene>_<preset>)")
    parser.add_argument("--frames", help="frame window START:STOP on video datasets (quick default 0:5)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--readme",
        help="markdown file whose '<!-- results:<scene> -->' section is rewritten with the table "
        "next to the published numbers (e.g. README.md)",
    )
    parser.add_argument(
        "--readme-section", help="section name in --readme (default: the scene name, e.g. mutant)"
    )


def main(args: argparse.Namespace) -> int:
    frames = None
    if args.frames:
        start, _, stop = args.frames.partition(":")
        frames = (int(start), int(stop))
    experts = [e.strip() for e in args.experts.split(",") if e.strip()]
    table = compare(experts, args.scene, args.preset, args.out, frames, progress=not args.quiet)
    for row in table["rows"]:
        lpips = "n/a" if row["lpips"] is None or math.isnan(row["lpips"]) else f"{row['lpips']:.4f}"
        print(
            f"{row['expert']:<10} PSNR {row['psnr']:6.2f}  SSIM {row['ssim']:.4f}  LPIPS {lpips}  "
            f"{row['train_seconds']:7.1f} s  {row['num_gaussians']:>7} Gaussians"
        )
    print(f"table -> {table['table']} (and table.json beside it)")
    if args.readme:
        section = args.readme_section or args.scene.split(":", 1)[-1]
        body = readme_section(table, published_numbers(args.scene))
        print(f"README section '{section}' -> {update_readme(args.readme, section, body)}")
    return 0
