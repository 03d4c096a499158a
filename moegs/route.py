"""``moegs route``: train the experts (stage 1), train a router over them (stage 2), evaluate, draw gates.

    moegs route --experts deformable,grid4d --scene dnerf:mutant --preset quick
    moegs route --experts ex4dgs,stg,ed3dgs --scene panoptic:basketball --router pixel --out runs/moe

Layout of ``--out`` (default ``runs/route_<scene>_<preset>_s<seed>``)::

    <expert>/            each expert's training run (``moegs compare`` layout: reused, resumed)
    router_<variant>/    router.safetensors, config.json, metrics.json (MoE and per-expert metrics)
        gates/           one PNG per test view: GT | MoE | experts | winner map | per-expert gate maps
        gates/winner_*.png, gate_<expert>_*.png   the colour-coded maps alone
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from moegs.cli_types import (
    add_device_argument,
    add_resume_arguments,
    non_negative_int,
    positive_int,
    scene_name,
    seed,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--experts", required=True, help="comma-separated registry names, e.g. deformable,grid4d")
    p.add_argument("--scene", required=True, type=scene_name, help="<dataset>:<scene>, e.g. dnerf:mutant")
    p.add_argument(
        "--preset", default="quick", choices=["quick", "paper"], help="experts' and router's preset"
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


def _experts(names: list[str], scene_name: str, preset: str, out: Path, progress: bool, device):
    """Train (or reuse) each expert with its recipe on ``device``; returns ``(experts, scene)``: the experts
    on ``device``, the scene loaded as the first expert's recipe loads it (experts on RGBA datasets must
    agree on the background) and placed on ``device``."""
    from moegs.compare import preset_frames, run_expert, scene_kwargs
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import load_trained
    from moegs.train.reuse import describe_changes, reusable_run

    recipes = [config_for(n, scene_name, preset) for n in names]
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
            "composited on the background; route experts that agree"
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


def main(args: argparse.Namespace) -> int:
    from moegs.experts import get_spec
    from moegs.moe import load_moe, router_config_for, train_router
    from moegs.moe.model import ROUTER_CHECKPOINT

    names = [n.strip() for n in args.experts.split(",") if n.strip()]
    for name in names:
        get_spec(name)  # unknown names fail before any training
    if len(names) < 2 or len(set(names)) != len(names):
        raise ValueError(f"--experts needs at least two different experts to route between, got {names}")
    out = Path(args.out or Path("runs") / f"route_{args.scene.replace(':', '_')}_{args.preset}_s{args.seed}")
    experts, scene = _experts(names, args.scene, args.preset, out, not args.quiet, args.device)
    config = router_config_for(args.preset, args.convention, scene=args.scene)
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
        result = train_router(experts, scene, config, folder, progress=not args.quiet)
    model = load_moe(folder, experts)
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
