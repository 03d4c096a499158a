"""``moegs route``: train the experts (stage 1), train a router over them (stage 2), evaluate, draw gates.

    moegs route --experts deformable,grid4d --scene dnerf:mutant --preset quick
    moegs route --experts ex4dgs,stg,ed3dgs --scene panoptic:basketball --router pixel --out runs/moe
    moegs route --runs runs/linear runs/grid4d --out runs/moe    # trained runs: only the router trains

``--experts`` trains each expert with its recipe into ``<out>/<expert>/`` (a finished run there is
reused); ``--runs`` takes finished run folders (``moegs train``'s, or ``<out>/<expert>/`` of an earlier
route) as they are, on the scene, preset and background they trained with (``load_runs``), and
trains nothing but the router.

``--out`` is locked while route runs (a second command on it gets one line, ``moegs.guards.folder_lock``).

Layout of ``--out`` (default ``runs/route_<scene>_<preset>_s<seed>``)::

    <expert>/            each expert's training run with --experts (``moegs compare`` layout: reused, resumed)
    router_<variant>/    router.safetensors, config.json, metrics.json (MoE and per-expert metrics),
                         runs.json (the expert run folders it routes)
        gates/           one PNG per test view: GT | MoE | experts | winner map | per-expert gate maps
        gates/winner_*.png, gate_<expert>_*.png   the colour-coded maps alone
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from moegs.cli_types import (
    add_device_argument,
    add_resume_arguments,
    non_negative_int,
    positive_int,
    scene_name,
    seed,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--experts", help="comma-separated registry names to train and route, e.g. deformable,grid4d"
    )
    which.add_argument(
        "--runs",
        nargs="+",
        metavar="RUN",
        help="finished run folders (written by `moegs train`) to route as they are: no expert is trained; "
        "the scene, preset and background are theirs",
    )
    p.add_argument(
        "--scene", type=scene_name, help="<dataset>:<scene>, e.g. dnerf:mutant (needed with --experts)"
    )
    p.add_argument(
        "--preset",
        choices=["quick", "paper"],
        help="experts' and router's preset (default quick; with --runs the runs' preset)",
    )
    p.add_argument(
        "--expert-iterations",
        type=positive_int,
        help="with --experts: override the experts' training iterations (the router's: --iterations)",
    )
    p.add_argument(
        "--router",
        default="vapr",
        choices=["vapr", "pixel", "volume"],
        help="vapr (volume-aware pixel), pixel or volume",
    )
    p.add_argument(
        "--convention",
        default="code",
        choices=["code", "paper"],
        help="router conventions: code (the authors' code, which produced the paper's numbers) or paper "
        "(the paper's wording)",
    )
    p.add_argument("--iterations", type=positive_int, help="override the router's iterations")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--out", help="output folder")
    p.add_argument(
        "--gate-views", type=non_negative_int, default=4, help="test views drawn as gate figures (0: none)"
    )
    add_resume_arguments(p, "router")
    add_device_argument(p, "train the experts and the router")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


# ---------------------------------------------------------------------- trained run folders (--runs)
ROUTED_RUN_FIELDS = {"expert": str, "scene": str, "train": dict, "recipe": dict}
"""Fields of a run's ``config.json`` ``--runs`` reads, with their JSON types."""


@dataclass(frozen=True)
class TrainedRun:
    """A finished training run folder."""

    path: Path
    meta: dict[str, Any]
    """Its ``config.json``."""
    result: dict[str, Any]
    """Its ``metrics.json`` (completed and evaluated)."""

    @property
    def expert(self) -> str:
        return self.meta["expert"]

    @property
    def scene(self) -> str:
        return self.meta["scene"]

    @property
    def preset(self) -> str | None:
        return self.meta["recipe"].get("preset")

    @property
    def background(self) -> str | None:
        return self.meta["recipe"].get("background")

    @property
    def load_kwargs(self) -> dict[str, Any]:
        """``load_scene`` arguments its training used (``moegs.recipes.scene_load_kwargs``), frames aside."""
        from moegs.recipes import scene_load_kwargs

        recipe = self.meta["recipe"]
        return scene_load_kwargs(
            self.scene,
            recipe.get("background"),
            self.meta["train"].get("resolution_scale"),
            user_scale="train.resolution_scale" in (recipe.get("overrides") or {}),
            loader_args=recipe.get("loader_args"),
        )

    def describe(self) -> str:
        """``runs/linear (linear, 40 iterations, test PSNR 13.30)``."""
        psnr = self.result["test"].get("psnr")
        score = f", test PSNR {psnr:.2f}" if isinstance(psnr, float) else ""
        return f"{self.path} ({self.expert}, {self.result.get('iterations')} iterations{score})"


def read_run(path: str | Path) -> TrainedRun:
    """The finished run in ``path``; ``FileNotFoundError`` / ``ValueError`` naming the folder and what is
    missing (no ``config.json``, a field of the wrong type, an unfinished run, an expert not registered)."""
    from moegs.experts import get_spec
    from moegs.train.entry import finished_run
    from moegs.train.reuse import read_run_config

    run, meta = read_run_config(path, ROUTED_RUN_FIELDS)
    result = finished_run(run)
    if result is None:
        raise ValueError(
            f"{run} holds no finished run (metrics.json of a completed, evaluated run); run the same "
            f"`moegs train ... --out {run}` again to finish it"
        )
    get_spec(meta["expert"])  # an expert of a plugin that is not installed fails here, by name
    return TrainedRun(run, meta, result)


def _disagree(runs: list[TrainedRun], what: str, value) -> str | None:
    """``"runs/a: white, runs/b: black"`` when the runs' ``value(run)`` differ, else None."""
    values = [value(r) for r in runs]
    if len({repr(v) for v in values}) == 1:
        return None
    return ", ".join(f"{r.path}: {v}" for r, v in zip(runs, values, strict=True))


def recorded_views(run: TrainedRun) -> list[tuple[str, float]] | None:
    """``(key, time)`` of the test views ``metrics.json`` scored, in order (None: not recorded)."""
    per_view = run.result["test"].get("per_view")
    if not per_view:
        return None
    return [(v["key"], round(float(v["time"]), 6)) for v in per_view]


def views_match(run: TrainedRun, scene) -> bool:
    """Whether ``scene``'s test views are those ``run`` was evaluated on (same keys and times), so that it
    is the scene the run trained on (a frame window that ``config.json`` does not record shows here)."""
    from moegs.train.evaluate import eval_views

    recorded = recorded_views(run)
    if recorded is None:
        return True
    views = eval_views(scene.test, run.meta["train"].get("max_eval_views"))
    return [(v.key, round(float(v.camera.time), 6)) for v in views] == recorded


def load_runs(paths: list[str | Path], scene: str | None = None, preset: str | None = None):
    """``(runs, scene)``: the finished runs of ``paths`` (:func:`read_run`) and the scene they trained on.

    The runs must be at least two different folders of one scene (``scene``, when given, must be it)
    trained at one preset (``preset``, when given) on one background at one image size: a router blends
    their images. The scene is loaded as ``moegs train`` loads it, or with the preset's frame window
    (``moegs route --experts`` and ``moegs compare`` runs on video datasets), whichever gives the test
    views the runs were evaluated on.
    """
    from moegs.compare import preset_frames
    from moegs.data import load_scene
    from moegs.guards import check_distinct

    folders = [Path(p) for p in paths]
    check_distinct(folders, "--runs", key=Path.resolve)
    if len(folders) < 2:
        raise ValueError(f"--runs needs at least two different run folders to route between, got {paths}")
    runs = [read_run(p) for p in folders]
    checks = (
        ("scenes", lambda r: r.scene, "route runs of one scene"),
        ("presets", lambda r: r.preset, "route runs of one preset"),
        ("backgrounds", lambda r: r.background, "a router blends images composited on one background"),
        (
            "image scales",
            lambda r: r.load_kwargs.get("resolution_scale"),
            "a router blends images of one size",
        ),
    )
    for what, value, why in checks:
        which = _disagree(runs, what, value)
        if which:
            raise ValueError(f"the runs trained on different {what} ({which}); {why}")
    first = runs[0]
    if scene is not None and scene != first.scene:
        raise ValueError(
            f"--scene {scene} but the runs trained on {first.scene}; leave --scene out with --runs"
        )
    if preset is not None and preset != first.preset:
        raise ValueError(
            f"--preset {preset} but the runs trained at {first.preset}; leave --preset out with --runs "
            "(the router takes the runs' preset)"
        )
    windows = [None]
    window = preset_frames(first.scene, first.preset or "", None)
    if window is not None:
        windows.append(window)
    for frames in windows:
        kwargs = first.load_kwargs | ({"frames": frames} if frames is not None else {})
        loaded = load_scene(first.scene, **kwargs)
        if all(views_match(r, loaded) for r in runs):
            return runs, loaded
    raise ValueError(
        f"{first.scene} loaded from the runs' config.json has other test views than the runs were evaluated "
        "on (trained on a frame window or an older scene); route them with the command that trained them"
    )


def _experts(
    names: list[str],
    scene_name: str,
    preset: str,
    out: Path,
    progress: bool,
    device,
    iterations: int | None = None,
):
    """Train (or reuse) each expert with its recipe on ``device`` (``iterations``: the experts' training
    iterations instead of the preset's) into ``<out>/<expert>``; returns ``(experts, scene)``: the experts
    on ``device``, the scene loaded as the first expert's recipe loads it (experts on RGBA datasets must
    agree on the background) and placed on ``device``."""
    from moegs.compare import preset_frames, run_expert, scene_kwargs
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import load_trained
    from moegs.train.reuse import describe_changes, reusable_run

    overrides = {"train.iterations": iterations} if iterations is not None else None
    recipes = [config_for(n, scene_name, preset, overrides=overrides) for n in names]
    scales = {r.config.train.resolution_scale for r in recipes}
    if len(scales) != 1:
        raise ValueError(
            f"experts {names} train at different resolution scales {sorted(map(str, scales))} with preset "
            f"{preset!r}; a router blends images of one size"
        )
    backgrounds = {r.background for r in recipes}
    if len(backgrounds) > 1 and composites_background(scene_name):
        which = ", ".join(f"{r.expert}: {r.background}" for r in recipes)
        raise ValueError(
            f"experts {names} train on different backgrounds ({which}) and {scene_name}'s RGBA images are "
            "composited on the background; route experts that agree (a plugin sets its config's BACKGROUNDS)"
        )
    frames = preset_frames(scene_name, preset, None)
    scenes: dict = {}
    for recipe in recipes:  # a finished expert run is reused as it is, one of another config with a notice
        run_dir = out / recipe.expert
        result, changed = reusable_run(recipe, run_dir)
        if result is None:
            run_expert(recipe, run_dir, frames, scenes, progress, device)
        elif changed:
            print(
                f"moegs route: reusing {run_dir}, a finished run of another config than the {preset} "
                f"preset's (changed: {describe_changes(changed)})",
                file=sys.stderr,
            )
    scene = load_scene(scene_name, **scene_kwargs(recipes[0], frames))
    experts = [load_trained(out / name, scene, device=device)[0] for name in names]
    return experts, scene.to(device)


def _trained_runs(paths: list[str], scene_name: str | None, preset: str | None, device):
    """The finished runs of ``paths`` loaded as they are (``load_runs``: nothing trains);
    returns ``(experts, scene, preset, run folders)``, the experts on ``device``, the scene they trained on
    placed there, and the preset they trained at."""
    from moegs.train.entry import load_trained

    runs, scene = load_runs(paths, scene_name, preset)
    experts = [load_trained(r.path, scene, expect=r.expert, device=device)[0] for r in runs]
    for run in runs:
        print(f"expert {run.expert}: reusing the trained run {run.describe()}")
    return experts, scene.to(device), runs[0].preset or "quick", [r.path for r in runs]


def composites_background(scene_name: str) -> bool:
    """Whether the scene's images have alpha composited on the background (D-NeRF and its stand-in)."""
    from moegs.recipes import dataset_of

    return dataset_of(scene_name) == "dnerf"


def write_gate_figures(model, scene, folder: Path, count: int) -> list[Path]:
    """Gate figures and maps for ``count`` evenly spaced test views; returns the figure paths."""
    import imageio.v3 as iio
    import torch

    from moegs.moe.visualize import save_gate_figure, weight_map, winner_map
    from moegs.train.evaluate import eval_views

    names = [e.name for e in model.experts]
    paths = []
    with torch.no_grad():
        for i, view in enumerate(eval_views(scene.test, count)):
            out = model.render(view.camera, scene.background)
            title = f"{model.config.variant} router, {view.key} (t={view.camera.time:.2f})"
            paths.append(save_gate_figure(folder / f"view_{i:03d}.png", out, view.image(), names, title))
            iio.imwrite(folder / f"winner_{i:03d}.png", winner_map(out.gates))
            for k, name in enumerate(names):
                iio.imwrite(folder / f"gate_{k}_{name}_{i:03d}.png", weight_map(out.gates[k]))
    return paths


RUNS_RECORD = "runs.json"
"""File of a router folder naming the expert run folders it routes, in order."""


def _runs_record(folder: Path, runs: list[Path]) -> list[str]:
    """``runs`` as ``RUNS_RECORD`` holds them: relative to ``folder``, so that a route folder moved as a
    whole keeps its record."""
    import os

    return [Path(os.path.relpath(Path(r).resolve(), folder.resolve())).as_posix() for r in runs]


def check_router_runs(folder: Path, runs: list[Path], force: bool) -> None:
    """Refuse ``folder`` when it holds a router over other expert runs than ``runs`` (``RUNS_RECORD``;
    ``force`` trains it again instead)."""
    from moegs.io import read_json

    record = folder / RUNS_RECORD
    if force or not record.is_file():
        return
    recorded = read_json(record, "router runs").get("runs")
    if recorded != _runs_record(folder, runs):
        raise ValueError(
            f"{folder} holds a router over other expert runs ({', '.join(map(str, recorded or []))}); "
            "--force trains it again over these, or choose another --out"
        )


def record_router_runs(folder: Path, runs: list[Path]) -> None:
    """Write ``RUNS_RECORD``: the expert run folders the router of ``folder`` routes."""
    from moegs.io import write_json

    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / RUNS_RECORD, {"runs": _runs_record(folder, runs)})


def finished_router(folder: Path, config) -> dict | None:
    """The metrics of a completed router run in ``folder`` trained with ``config`` (None otherwise)."""
    from moegs.io import read_json, to_dict
    from moegs.io.config import config_changes

    if not (folder / "metrics.json").is_file() or not (folder / "config.json").is_file():
        return None
    metrics = read_json(folder / "metrics.json", "router metrics")
    saved = read_json(folder / "config.json", "router config").get("router", {})
    if not metrics.get("completed") or config_changes(saved, to_dict(config), ("checkpoint_every",)):
        return None
    return metrics


def default_out(scene_name: str, preset: str, seed: int) -> Path:
    """``runs/route_<scene>_<preset>_s<seed>``: where a route goes without ``--out``."""
    return Path("runs") / f"route_{scene_name.replace(':', '_')}_{preset}_s{seed}"


def main(args: argparse.Namespace) -> int:
    """``moegs route``; its ``--out`` folder is locked while it trains (``moegs.guards.folder_lock``)."""
    from contextlib import ExitStack

    with ExitStack() as lock:
        return _main(args, lock)


def _main(args: argparse.Namespace, lock) -> int:
    from moegs.experts import get_spec
    from moegs.guards import check_distinct, folder_lock
    from moegs.moe import load_moe, router_config_for, train_router
    from moegs.moe.model import ROUTER_CHECKPOINT

    if args.runs is not None:
        if args.expert_iterations is not None:
            raise ValueError(
                "--expert-iterations trains experts (--experts); --runs routes trained runs as they are"
            )
        experts, scene, preset, runs = _trained_runs(args.runs, args.scene, args.preset, args.device)
        scene_name = scene.name  # the runs' (load_runs checked that they agree)
        out = lock.enter_context(folder_lock(args.out or default_out(scene_name, preset, args.seed)))
        check_router_runs(out / f"router_{args.router}", runs, args.force)
    else:
        if args.scene is None:
            raise ValueError("--experts needs --scene (the runs of --runs name theirs)")
        names = [n.strip() for n in args.experts.split(",") if n.strip()]
        for name in names:
            get_spec(name)  # unknown names fail before any training
        check_distinct(names, "--experts")
        if len(names) < 2:
            raise ValueError(f"--experts needs at least two different experts to route between, got {names}")
        preset, scene_name = args.preset or "quick", args.scene
        out = lock.enter_context(folder_lock(args.out or default_out(scene_name, preset, args.seed)))
        runs = [out / name for name in names]
        check_router_runs(out / f"router_{args.router}", runs, args.force)
        experts, scene = _experts(
            names, scene_name, preset, out, not args.quiet, args.device, args.expert_iterations
        )
    config = router_config_for(preset, args.convention, scene=scene_name)
    config = replace(config, variant=args.router, seed=args.seed)
    if args.iterations is not None:
        config = replace(config, iterations=args.iterations)
    config = replace(config, checkpoint_every=args.checkpoint_every or max(1, config.iterations // 10))
    folder = out / f"router_{args.router}"
    result = finished_router(folder, config) if not args.force else None
    if result is not None:
        print(f"{folder} holds a finished router run (its metrics are kept; --force trains again)")
    else:
        if args.force:
            (folder / ROUTER_CHECKPOINT).unlink(missing_ok=True)
        record_router_runs(folder, runs)
        result = train_router(experts, scene, config, folder, progress=not args.quiet)
    model = load_moe(folder, experts, scene)
    figures = write_gate_figures(model, scene, folder / "gates", args.gate_views) if args.gate_views else []
    test = result["test"]
    label = f" [{scene.stand_in}]" if scene.stand_in else ""
    print(f"MoE-GS ({args.router} router) on {scene.name}{label}:")
    for e, share in zip(test["experts"], test["winner_share"], strict=True):
        scores = f"PSNR {e['psnr']:.2f}  SSIM {e['ssim']:.4f}"
        print(f"  expert {e['name']:<12} {scores}  wins {100 * share:.0f}% of pixels")
    print(f"  MoE-GS              PSNR {test['psnr']:.2f}  SSIM {test['ssim']:.4f}  -> {folder}")
    if figures:
        print(f"  gate figures: {folder / 'gates'} ({len(figures)} views)")
    return 0
