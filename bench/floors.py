"""Measure the real-data test floors over seeds and thread counts (``python -m bench.floors``).

The real-data tests (``tests/experts/test_mutant_quick.py``, ``tests/moe/test_mutant_moe.py``) assert
floors on runs of D-NeRF ``mutant`` at the quick preset. A floor set at one machine's value is a coin flip
on the next one, so each floor sits below the lowest value this tool measures over several seeds and over
1 and 2 CPU threads, and the measured spread is written beside it.

Each ``(seed, threads)`` cell runs in its own process (the thread count is fixed before torch starts)
and is stored as ``<out>/s<seed>_t<threads>.json``, written atomically: a re-run computes only the missing
cells. The summary prints, per quantity, the minimum and maximum over cells.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

SCENE = "dnerf:mutant"
EXPERTS = ("static", "deformable", "grid4d", "fourdgs", "mcmc", "ed3dgs", "stg", "ex4dgs")
MOE_EXPERTS = ("deformable", "grid4d")
"""The pair ``tests/moe/test_mutant_moe.py`` routes (the volume-aware pixel router, code conventions)."""


def cell_name(seed: int, threads: int) -> str:
    """``s<seed>_t<threads>``: the cell's JSON under ``out`` and, prefixed ``router_``, its router folder."""
    return f"s{seed}_t{threads}"


def measure_cell(seed: int, threads: int, out: Path) -> dict:
    """Train every expert and the router on ``SCENE`` at the quick preset with ``seed`` (in a process with
    ``threads`` torch threads); the quantities the real-data tests assert on. Each cell trains its own
    router: the experts of one seed differ between thread counts, so a router folder shared by them would
    be resumed over other experts."""
    import torch

    from moegs.data import load_scene
    from moegs.moe import RouterConfig, load_moe, router_preset, train_router
    from moegs.recipes import config_for
    from moegs.train.entry import train_recipe

    values: dict[str, float] = {}
    trained = {}
    for name in EXPERTS:
        recipe = config_for(name, SCENE, "quick", overrides={"train.seed": seed})
        scene = load_scene(SCENE, **recipe.load_kwargs)
        expert, result = train_recipe(recipe, scene, progress=False)
        values[f"psnr/{name}"] = result["test"]["psnr"]
        trained[name] = (expert, scene)
    experts = [trained[n][0] for n in MOE_EXPERTS]
    scene = trained[MOE_EXPERTS[0]][1]
    config = RouterConfig.from_preset(router_preset("quick", "code"))
    config = dataclasses.replace(config, seed=seed)
    router_dir = out / f"router_{cell_name(seed, threads)}"
    result = train_router(experts, scene, config, router_dir, progress=False)
    test = result["test"]
    values["moe/psnr"] = test["psnr"]
    values["moe/margin_to_better_expert"] = test["psnr"] - max(e["psnr"] for e in test["experts"])
    values["moe/min_winner_share"] = min(test["winner_share"])
    model = load_moe(router_dir, experts)
    with torch.no_grad():
        gates = model.render(scene.test[0].camera, scene.background).gates
    values["moe/gate_spread_view0"] = float((gates[0] - 0.5).abs().mean())
    return values


def run_cells(seeds: list[int], threads: list[int], out: Path) -> dict[str, dict]:
    """Every missing ``(seed, threads)`` cell in a fresh process; returns all cells by name."""
    from moegs.io import write_json

    cells = {}
    for t in threads:
        for s in seeds:
            path = out / f"{cell_name(s, t)}.json"
            if not path.is_file():
                env = {**os.environ, "OMP_NUM_THREADS": str(t), "MKL_NUM_THREADS": str(t)}
                cmd = [sys.executable, "-m", "bench.floors", "--cell", str(s), "--out", str(out)]
                print(f"[floors] seed {s}, {t} thread(s) ...", flush=True)
                subprocess.run(cmd, env=env, check=True)
            cells[path.stem] = json.loads(path.read_text())
    write_json(out / "summary.json", summarize(cells))
    return cells


def summarize(cells: dict[str, dict]) -> dict[str, dict]:
    """Per quantity: ``{"min", "max", "cells": {cell: value}}``."""
    names = sorted({k for c in cells.values() for k in c})
    return {
        n: {
            "min": min(c[n] for c in cells.values()),
            "max": max(c[n] for c in cells.values()),
            "cells": {k: c[n] for k, c in cells.items()},
        }
        for n in names
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.floors", description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated training seeds")
    parser.add_argument("--threads", default="1,2", help="comma-separated torch thread counts")
    parser.add_argument("--out", default="runs/floors", help="cell folder")
    parser.add_argument("--cell", type=int, help=argparse.SUPPRESS)  # internal: one seed, this process
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.cell is not None:
        import torch

        from moegs.io import write_json

        threads = int(os.environ.get("OMP_NUM_THREADS", torch.get_num_threads()))
        torch.set_num_threads(threads)
        write_json(out / f"{cell_name(args.cell, threads)}.json", measure_cell(args.cell, threads, out))
        return 0
    seeds = [int(s) for s in args.seeds.split(",")]
    threads = [int(t) for t in args.threads.split(",")]
    summary = summarize(run_cells(seeds, threads, out))
    width = max(map(len, summary))
    for name, row in summary.items():
        spread = row["max"] - row["min"]
        print(f"{name:<{width}}  min {row['min']:.4f}  max {row['max']:.4f}  spread {spread:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
