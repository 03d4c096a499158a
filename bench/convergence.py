"""Convergence study: test PSNR of experts against training length and CPU time, per resolution.

    python -m bench.convergence --scene dnerf:mutant --experts deformable,grid4d \\
        --iterations 600,1500,3000,6000 --resolutions 0.125,0.25 [--limit 0.25=3000]

Each cell trains one expert on the scene with the **quick recipe's schedules scaled to N iterations**
(``scaled_overrides``; N = 600 is exactly the quick preset) at one resolution, then scores it on every
test view: full image, dynamic and static regions and, below full resolution, the render upsampled
(bicubic) to the dataset's native resolution against the native ground truth, as a paper-resolution
figure. Cells are cached as JSON under ``--workspace`` (atomic writes): an interrupted study resumes
and a finished cell is never recomputed unless ``--force``, or unless the library code the cell runs
changed (``cell_code_version``, the bench's rule for its own cells): a study's table is always of one
library version, which its README footer names. The figure (PSNR against iterations and against
each cell's wall minutes) and a markdown table go to ``--out``.

``--num-points N`` loads a scene that stores no initial cloud with N random points instead of its
loader's default (the originals' 100k on D-NeRF; the bench presets load 5k), and ``--seed S`` trains
with another seed than the recipe's 0 (``Variant``): those cells and outputs carry a ``-pN`` / ``-sS``
suffix.

The scaling rule is ``bench.schedules``'s (the ``standard`` bench preset trains with the same).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from bench.results import write_text_atomic
from bench.schedules import QUICK_ITERATIONS, scaled_overrides


@dataclass(frozen=True)
class Variant:
    """What a study may change besides expert, resolution and length: the initial cloud of a scene that
    stores none (``num_points``; None: the loader's default) and the training seed (the recipe's is 0)."""

    num_points: int | None = None
    seed: int = 0

    @property
    def suffix(self) -> str:
        """``-pN`` and ``-sS`` where they differ from the defaults: cell files and outputs carry it."""
        return ("" if self.num_points is None else f"-p{self.num_points}") + (
            f"-s{self.seed}" if self.seed else ""
        )

    @classmethod
    def of(cls, record: dict) -> Variant:
        """The variant a cell record was trained with (records from before these fields: the defaults)."""
        return cls(record.get("num_points"), record.get("seed") or 0)

    @property
    def words(self) -> str:
        """``, N random initial points, seed S`` where they differ from the defaults."""
        points = "" if self.num_points is None else f", {self.num_points} random initial points"
        return points + (f", seed {self.seed}" if self.seed else "")


def cell_code_version(expert: str, scene_name: str) -> str:
    """Hash of the library modules a cell training ``expert`` on ``scene_name`` can import (the bench's
    expert cells run the same training and evaluation code)."""
    from bench.codedeps import task_code_version

    return task_code_version("expert", frozenset({expert}), scene_name.partition(":")[0])


def run_cell(
    expert: str,
    scene_name: str,
    resolution: float,
    iterations: int,
    progress: bool,
    variant: Variant = Variant(),
) -> dict:
    """Train and score one cell (see the module docstring) of ``variant``; a JSON-ready record."""
    import torch

    from bench.cells._eval import psnr_upsampled
    from bench.cells._lib import expert_renderer
    from bench.keys import git_commit
    from bench.readme import machine_line
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import train_recipe

    overrides = scaled_overrides(expert, scene_name, iterations)
    overrides.update(
        {"train.resolution_scale": resolution, "train.max_eval_views": None, "train.eval_every": 0}
        | ({"train.seed": variant.seed} if variant.seed else {})
    )
    recipe = config_for(expert, scene_name, "quick", overrides=overrides)
    points = variant.num_points
    load = recipe.load_kwargs | ({"num_points": points} if points is not None else {})
    scene = load_scene(scene_name, **load)
    start = time.perf_counter()
    model, result = train_recipe(recipe, scene, progress=progress)
    seconds = time.perf_counter() - start
    test = result["test"]
    record = {
        "expert": expert,
        "scene": scene_name,
        "resolution_scale": resolution,
        "iterations": iterations,
        "image_size": [scene.test[0].camera.width, scene.test[0].camera.height],
        "train_minutes": result["train_seconds"] / 60.0,
        "minutes": seconds / 60.0,
        "num_gaussians": result["num_gaussians"],
        "num_points": points,
        "seed": variant.seed,
        "test_views": test["num_views"],
        "psnr": test["psnr"],
        "psnr_dynamic": test.get("psnr_dynamic"),
        "psnr_static": test.get("psnr_static"),
        "motion_r2": test.get("motion_r2"),
        "ssim": test["ssim"],
        "lpips": test["lpips"],
        "psnr_native": None,
        "recipe": recipe.provenance(),
        "code_version": cell_code_version(expert, scene_name),
        "git": git_commit().get("commit"),
        "machine": machine_line(),
        "threads": torch.get_num_threads(),
    }
    if resolution < 1.0:
        native = load_scene(scene_name, background=recipe.background, resolution_scale=1.0)
        record["native_size"] = [native.test[0].camera.width, native.test[0].camera.height]
        render = expert_renderer(model, scene.background)
        record["psnr_native"] = psnr_upsampled(render, scene.test, native.test)
    return record


def cell_path(
    workspace: Path,
    expert: str,
    scene: str,
    resolution: float,
    iterations: int,
    variant: Variant = Variant(),
) -> Path:
    return (
        workspace / scene.replace(":", "_") / f"{expert}-r{resolution:g}-n{iterations}{variant.suffix}.json"
    )


def run_study(
    scene: str,
    experts: list[str],
    iterations: list[int],
    resolutions: list[float],
    workspace: Path,
    limits: dict[float, int] | None = None,
    force: bool = False,
    progress: bool = True,
    run: bool = True,
    variant: Variant = Variant(),
) -> tuple[list[dict], list[str]]:
    """Every (expert, resolution, N) cell not beyond ``limits[resolution]``, cached under ``workspace``;
    a cached cell of other library code is recomputed. With ``run=False`` nothing is trained: the
    cells not yet computed by this library are left out and named in the second list."""
    from moegs.io import read_json, write_json

    records, missing = [], []
    for resolution in resolutions:
        for expert in experts:
            version = cell_code_version(expert, scene)
            for n in iterations:
                if n > (limits or {}).get(resolution, math.inf):
                    continue
                path = cell_path(workspace, expert, scene, resolution, n, variant)
                why = "computing"
                if path.is_file() and not force:
                    cached = read_json(path, "convergence cell")
                    if cached.get("code_version") == version:
                        records.append(cached)
                        continue
                    why = f"recomputing (cached cell of library {cached.get('code_version', 'unknown')})"
                if not run:
                    missing.append(f"{expert} at {resolution:g}x, N = {n}")
                    continue
                print(f"[convergence] {why}: {expert} on {scene} at {resolution:g}x, N = {n}", flush=True)
                records.append(run_cell(expert, scene, resolution, n, progress, variant))
                write_json(path, records[-1])
    return records, missing


def markdown(records: list[dict], paper: dict[str, float]) -> str:
    """One row per cell, with the paper's value of the expert when known."""
    lines = [
        "| expert | resolution | iterations | minutes | Gaussians | PSNR | PSNR dynamic | motion R² | PSNR "
        "upsampled to native | paper |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(records, key=lambda r: (r["expert"], r["resolution_scale"], r["iterations"])):
        size = "x".join(map(str, r["image_size"]))
        native = f"{r['psnr_native']:.2f}" if r.get("psnr_native") is not None else "-"
        dyn = f"{r['psnr_dynamic']:.2f}" if r.get("psnr_dynamic") is not None else "-"
        r2 = f"{r['motion_r2']:.2f}" if r.get("motion_r2") is not None else "-"
        ref = f"{paper[r['expert']]:.2f}" if r["expert"] in paper else "-"
        lines.append(
            f"| {r['expert']} | {r['resolution_scale']:g} ({size}) | {r['iterations']} | "
            f"{r['minutes']:.1f} | {r['num_gaussians']} | {r['psnr']:.2f} | {dyn} | {r2} | {native} | {ref} |"
        )
    return "\n".join(lines)


def plot(records: list[dict], paper: dict[str, float], title: str, path: Path) -> Path:
    """PSNR against iterations (left) and against minutes (middle), one line per expert and resolution;
    where the scene has dynamic masks, also the dynamic region's PSNR against iterations (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dynamic = any(r.get("psnr_dynamic") is not None for r in records)
    fig, axes = plt.subplots(1, 3 if dynamic else 2, figsize=(16 if dynamic else 11, 4))
    groups: dict[tuple[str, float], list[dict]] = {}
    for r in records:
        groups.setdefault((r["expert"], r["resolution_scale"]), []).append(r)
    colors = {e: f"C{i}" for i, e in enumerate(sorted({r["expert"] for r in records}))}
    for (expert, res), rows in sorted(groups.items()):
        rows = sorted(rows, key=lambda r: r["iterations"])
        style = "-" if res == max(r["resolution_scale"] for r in records) else "--"
        label = f"{expert} @ {res:g}x ({'x'.join(map(str, rows[0]['image_size']))})"
        psnrs = [r["psnr"] for r in rows]
        axes[0].plot(
            [r["iterations"] for r in rows], psnrs, style, marker="o", color=colors[expert], label=label
        )
        axes[1].plot(
            [r["minutes"] for r in rows], psnrs, style, marker="o", color=colors[expert], label=label
        )
        if dynamic:
            axes[2].plot(
                [r["iterations"] for r in rows],
                [r.get("psnr_dynamic") for r in rows],
                style,
                marker="o",
                color=colors[expert],
                label=label,
            )
    for expert, value in paper.items():
        if expert in colors:
            for ax in axes:
                ax.axhline(value, color=colors[expert], lw=0.8, ls=":")
    axes[0].set_xlabel("training iterations (quick schedules scaled)")
    axes[1].set_xlabel("wall minutes of the cell (train + load + evaluation)")
    for ax in axes:
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
    if dynamic:
        axes[2].set_xlabel("training iterations (quick schedules scaled)")
        axes[2].set_ylabel("test PSNR of the dynamic region (dB)")
        axes[2].set_xscale("log")
    axes[0].set_xscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle(title + (" (dotted: paper, full resolution and schedule)" if paper else ""), fontsize=9)
    fig.tight_layout()
    from bench.plots import save_figure

    return save_figure(fig, path, tight=False)


def paper_values(scene: str, experts: list[str]) -> dict[str, float]:
    """The MoE-GS paper's PSNR of each expert on ``scene`` (``bench.readme.PUBLISHED``), where it has one."""
    from bench.readme import paper_name, published_numbers

    out = {}
    for table in published_numbers(scene):
        if table["kind"] != "moegs":
            continue
        for expert in experts:
            record = table["rows"].get(paper_name(expert), {}).get("PSNR")
            if record is not None:
                out[expert] = float(record["value"])
    return out


def provenance(records: list[dict], variant: Variant = Variant()) -> str:
    """The machines, library versions, commits and thread counts the cells of one study (``variant``)
    ran with, in words (a study may gather cells computed on several machines: each records its own)."""

    def distinct(key: str, sep: str = ", ") -> str:
        values = sorted({str(r.get(key) or "unrecorded") for r in records})
        return sep.join(v[:10] if key == "git" else v for v in values)

    return (
        f"cells run on {distinct('machine', '; ')}; library code version {distinct('code_version')} "
        f"(git {distinct('git')}), {distinct('threads')} torch thread(s) per cell{variant.words}"
    )


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.convergence", description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="dnerf:mutant")
    p.add_argument("--experts", default="deformable,grid4d")
    p.add_argument("--iterations", default="600,1500,3000,6000", help="comma-separated run lengths")
    p.add_argument("--resolutions", default="0.125,0.25", help="comma-separated resolution scales")
    p.add_argument("--limit", action="append", default=[], help="RES=N: no run longer than N at RES")
    p.add_argument("--workspace", type=Path, default=Path("runs") / "convergence")
    p.add_argument("--out", type=Path, default=Path("reports") / "convergence")
    p.add_argument("--force", action="store_true", help="recompute finished cells")
    p.add_argument("--readme", type=Path, help="also rewrite this README's results:<section> section")
    p.add_argument("--section", default="convergence", help="README section (one per scene studied)")
    p.add_argument("--threads", type=int, help="torch threads (default: torch's)")
    p.add_argument(
        "--num-points", type=int, help="initial points where the scene stores none (default: the loader's)"
    )
    p.add_argument("--seed", type=int, default=0, help="training seed (default: the recipe's, 0)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-run", action="store_true", help="train nothing: draw the cells already computed")
    args = p.parse_args(argv)
    try:
        experts = [e.strip() for e in args.experts.split(",") if e.strip()]
        iterations = [int(x) for x in _floats(args.iterations)]
        resolutions = _floats(args.resolutions)
        limits = {float(k): int(v) for k, v in (item.split("=", 1) for item in args.limit)}
        for expert in experts:
            scaled_overrides(expert, args.scene, QUICK_ITERATIONS)  # unknown experts fail before any work
        if args.threads is not None and args.threads < 1:
            raise ValueError(f"--threads must be >= 1, got {args.threads}")
        if args.num_points is not None and args.num_points < 1:
            raise ValueError(f"--num-points must be >= 1, got {args.num_points}")
        if args.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {args.seed}")
    except ValueError as err:
        p.exit(2, f"bench.convergence: {err}\n")
    variant = Variant(args.num_points, args.seed)
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads or threads)
    try:
        records, missing = run_study(
            args.scene, experts, iterations, resolutions, args.workspace, limits, args.force,
            not args.no_progress, run=not args.no_run, variant=variant,
        )  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    if not records:
        p.exit(2, "bench.convergence: no cell of this library computed yet (run without --no-run)\n")
    paper = paper_values(args.scene, experts)
    stem = args.scene.replace(":", "_") + variant.suffix
    plot(records, paper, f"Convergence on {args.scene}{variant.words}", args.out / f"{stem}.png")
    table = markdown(records, paper)
    write_text_atomic(args.out / f"{stem}.md", table + "\n")
    from moegs.io import write_json

    write_json(args.out / f"{stem}.json", {"scene": args.scene, "paper": paper, "cells": records})
    print(table)
    if args.readme:
        from bench.readme import update_readme

        figure = (args.out / f"{stem}.png").resolve().relative_to(args.readme.resolve().parent)
        command = "python -m bench.convergence " + " ".join(argv if argv is not None else sys.argv[1:])
        body = (
            f"![convergence on {args.scene}]({figure})\n\n{table}\n\nGenerated by `{command}`; "
            f"{provenance(records, variant)}; minutes are wall-clock on the machine that ran the cell "
            "(training, loading and evaluation); 'paper' is the MoE-GS paper's value at full resolution and "
            "schedule."
        )
        if missing:
            body += f" Not run yet: {'; '.join(missing)}."
        update_readme(args.readme, args.section, body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
