"""``moegs compare``: train and evaluate several experts on one scene at one preset, one table.

    moegs compare --experts all --scene panoptic:basketball --preset quick
    moegs compare --experts static,stg,ex4dgs --scene dnerf:mutant --out runs/compare-mutant

Each expert is built from its recipe for the scene (``moegs.recipes.config_for``: the original's
preset for the dataset, its per-scene values, the preset's reductions) and trained with the shared
training loop into ``<out>/<expert>/``; the loop's ``metrics.json`` there is the expert's result, so a
finished expert is skipped on the next call (a run of another config than the recipe's is reused too, but
marked in the table with the fields that differ: ``moegs.train.reuse``) and an interrupted one resumes
from its checkpoint. The
table (PSNR / SSIM / LPIPS on the scene's test views, training seconds, final number of Gaussians) is
written as ``<out>/table.md`` and ``<out>/table.json``.

``--experts`` naming one expert twice is refused; ``<out>`` is locked while compare runs (a second
command on it gets one line, ``moegs.guards.folder_lock``).

Scene loading: each recipe's background and resolution; ``--frames`` picks a frame window on datasets
that have one (the ``quick`` preset defaults to the first ``QUICK_FRAMES`` frames there).
"""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from moegs.cli_types import add_device_argument, frame_window, scene_name

if TYPE_CHECKING:
    from moegs.recipes import Recipe

QUICK_FRAMES = (0, 5)
"""Frame window of the quick preset on multi-frame video datasets (CPU minutes for all experts)."""
WINDOWED_DATASETS = ("panoptic", "n3v", "technicolor")
"""Datasets whose loader takes ``frames=(start, stop)``."""
COLUMNS = ("expert", "psnr", "ssim", "lpips", "train_seconds", "num_gaussians", "iterations")


def preset_frames(scene: str, preset: str, frames: tuple[int, int] | None) -> tuple[int, int] | None:
    """The frame window of a run: ``frames`` (only on datasets that have windows), else the quick preset's
    ``QUICK_FRAMES`` on those datasets, else None (the loader's default)."""
    dataset = scene.split(":", 1)[0].lower()
    if frames is not None and dataset not in WINDOWED_DATASETS:
        raise ValueError(f"--frames applies to {', '.join(WINDOWED_DATASETS)} scenes, not {scene!r}")
    if frames is None and preset == "quick" and dataset in WINDOWED_DATASETS:
        return QUICK_FRAMES
    return frames


def scene_kwargs(recipe, frames: tuple[int, int] | None) -> dict[str, Any]:
    """``load_scene`` arguments of a run: the recipe's (background, resolution) and the frame window."""
    kwargs = dict(recipe.load_kwargs)
    if frames is not None:
        kwargs["frames"] = frames
    return kwargs


SCALE_FIELD = "train.resolution_scale="
"""How a recipe's scale is named when its images are too small for the metrics (``moegs.guards``): the field
``moegs train --set`` changes."""


def run_expert(
    recipe: Recipe, out: Path, frames: tuple[int, int] | None, scenes: dict, progress: bool, device=None
) -> dict:
    """Train (or resume) the expert of ``recipe`` (``moegs.recipes.config_for``) into ``out`` on ``device``
    (None: the CPU); returns the loop's result. ``scenes`` caches loaded scenes by their loader
    arguments; a scene whose images are too small for the metrics is refused before training
    (``moegs.guards.load_checked``)."""
    from moegs.data import load_scene
    from moegs.guards import load_checked
    from moegs.train.entry import train_recipe

    kwargs = scene_kwargs(recipe, frames)
    key = json.dumps(kwargs, sort_keys=True, default=str)
    if key not in scenes:
        try:
            scenes[key] = load_checked(
                lambda: load_scene(recipe.scene, **kwargs), kwargs.get("resolution_scale"), SCALE_FIELD
            )
        except ValueError as err:
            raise ValueError(f"{recipe.expert}'s {recipe.preset} recipe: {err}") from err
    return train_recipe(recipe, scenes[key], out, device=device, progress=progress)[1]


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
    """The table as GitHub markdown (LPIPS "n/a" when its weights are unavailable; ``*`` marks a reused
    run of another config than the preset's, with its changed fields below the table)."""
    from moegs.train.reuse import describe_changes

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

    def cells(row: dict) -> list[str]:
        marked = {**row, "expert": row["expert"] + ("*" if row.get("config_changes") else "")}
        return [fmt(k, marked[k]) for k in COLUMNS]

    lines = [f"# {title}", "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cells(r)) + " |" for r in rows]
    lines += [
        f"\n{r['expert']}*: a finished run of another config than the preset's, reused (changed: "
        f"{describe_changes(r['config_changes'])})"
        for r in rows
        if r.get("config_changes")
    ]
    return "\n".join(lines) + "\n"


def compare(
    experts: list[str],
    scene: str,
    preset: str = "quick",
    out: str | Path | None = None,
    frames: tuple[int, int] | None = None,
    progress: bool = True,
    device=None,
) -> dict:
    """Train and evaluate ``experts`` on ``scene`` at ``preset`` on ``device`` (None: the CPU); write and
    return the table.

    Returns:
        ``{"scene", "preset", "frames", "rows": [{"expert", "psnr", "ssim", "lpips", "train_seconds",
        "num_gaussians", "iterations", "stand_in", "run", "config_changes"}], "skipped": [experts whose
        result existed], "table": path of table.md}``; ``config_changes``: the fields in which a reused
        run's config differs from the preset's (``moegs.train.reuse``), empty for a run of the preset.
    """
    from moegs.experts import get_spec, list_experts
    from moegs.guards import check_distinct, folder_lock

    names = [s.name for s in list_experts() if not s.composite] if experts == ["all"] else experts
    if not names:
        raise ValueError("--experts: expected comma-separated registry names or 'all', got none")
    for name in names:
        get_spec(name)  # unknown names fail before any training
    check_distinct(names, "--experts")
    window = preset_frames(scene, preset, frames)
    out = Path(out) if out is not None else Path("runs") / f"compare_{scene.replace(':', '_')}_{preset}"
    with folder_lock(out):
        return _compare(names, scene, preset, out, window, progress, device)


def _compare(names: list[str], scene: str, preset: str, out: Path, window, progress: bool, device) -> dict:
    """``compare`` of ``names`` into ``out``, whose lock the caller holds."""
    from moegs.io import write_json
    from moegs.recipes import config_for
    from moegs.train.reuse import reusable_run

    rows, skipped, scenes = [], [], {}
    for name in names:
        run_dir = out / name
        recipe = config_for(name, scene, preset)
        result, changed = reusable_run(recipe, run_dir)
        if result is None:
            result = run_expert(recipe, run_dir, window, scenes, progress, device)
        else:
            skipped.append(name)
        rows.append({**_row(name, result, run_dir), "config_changes": changed})
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
    parser.add_argument(
        "--scene", required=True, type=scene_name, help="<dataset>:<scene>, e.g. panoptic:basketball"
    )
    parser.add_argument(
        "--preset", default="quick", choices=["quick", "paper"], help="config preset of every expert"
    )
    parser.add_argument("--out", help="output folder (default runs/compare_<scene>_<preset>)")
    parser.add_argument(
        "--frames", type=frame_window, help="frame window START:STOP on video datasets (quick default 0:5)"
    )
    add_device_argument(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def main(args: argparse.Namespace) -> int:
    from moegs.train.reuse import describe_changes

    experts = [e.strip() for e in args.experts.split(",") if e.strip()]
    table = compare(
        experts, args.scene, args.preset, args.out, args.frames, progress=not args.quiet, device=args.device
    )
    for row in table["rows"]:
        lpips = "n/a" if row["lpips"] is None or math.isnan(row["lpips"]) else f"{row['lpips']:.4f}"
        print(
            f"{row['expert']:<10} PSNR {row['psnr']:6.2f}  SSIM {row['ssim']:.4f}  LPIPS {lpips}  "
            f"{row['train_seconds']:7.1f} s  {row['num_gaussians']:>7} Gaussians"
        )
        if row["config_changes"]:
            print(
                f"{'':<10} (reused {row['run']}: another config than the preset's, changed: "
                f"{describe_changes(row['config_changes'])})"
            )
    print(f"table -> {table['table']} (and table.json beside it)")
    return 0
