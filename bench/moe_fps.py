"""End-to-end render speed on one device: every expert's render, and MoE-GS over K experts rendered in
one pass against K passes (the paper's 36 -> 60 FPS, 1.67x, compares these two on trained N3V experts).

    python -m bench.moe_fps --device cuda --json reports/gpu/moe_fps.json --readme docs/speed.md

Unlike ``bench.rasterizer`` (the rasterizer alone), each time here covers the expert's field at the
view's time, its decoding, the rasterizer and, for MoE-GS, the router. The experts are built untrained
from the stand-in scene at the quick preset, so they hold their initial clouds (a few thousand
Gaussians) and the router is untrained: its cost does not depend on its weights, a trained expert's does
on its size. An expert that fails on the device is reported with its error, and the exit code is 1.
Times follow the suite's protocol (``moegs.metrics.speed.measure_render``: warm-up, synchronised,
median over repeats per view, median over views).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import torch

from bench.results import write_json_atomic
from moegs.cli_types import non_negative_int, positive_float, positive_int
from moegs.data import load_scene
from moegs.data.scene import PointCloud, Scene
from moegs.experts import get_expert_class, list_experts
from moegs.metrics.speed import measure_render
from moegs.moe import RouterConfig
from moegs.moe.model import MoEGS

DEFAULT_MOE = ("fourdgs", "ed3dgs", "ex4dgs")


def with_points(scene: Scene, n: int, seed: int = 0) -> Scene:
    """``scene`` whose initial cloud is resampled to ``n`` points: drawn with replacement from its own
    points, each moved by a Gaussian step of 1% of the scene's extent, so no two coincide."""
    if scene.points is None or len(scene.points) == 0:
        raise ValueError(f"--gaussians needs a scene with initial points; {scene.name!r} has none")
    if n < 1:
        raise ValueError(f"--gaussians must be >= 1, got {n}")
    g = torch.Generator().manual_seed(seed)
    pick = torch.randint(len(scene.points), (n,), generator=g)
    jitter = 0.01 * scene.extent * torch.randn(n, 3, generator=g)
    times = None if scene.points.times is None else scene.points.times[pick]
    cloud = PointCloud(
        scene.points.xyz[pick] + jitter,
        scene.points.rgb[pick],
        f"{scene.points.source}, resampled to {n}",
        times,
    )
    return dataclasses.replace(scene, points=cloud)


def quick_config(cls, uncapped: bool):
    """The expert's quick preset; ``uncapped`` lifts its cap on initial points (``max_init_points``)."""
    config = cls.config_class.from_preset("quick")
    if uncapped and any(f.name == "max_init_points" for f in dataclasses.fields(config)):
        config = dataclasses.replace(config, max_init_points=None)
    return config


def build_experts(
    scene, names: Sequence[str], device: torch.device, uncapped: bool = False
) -> tuple[dict, list[dict]]:
    """``({name: expert on device}, rows)``; a row per name with its error where building or one render
    on ``device`` failed. ``uncapped``: every expert starts from all of the scene's points."""
    experts, rows = {}, []
    camera = scene.test[0].camera.to(device)
    background = scene.background.to(device)
    for name in names:
        cls = get_expert_class(name)  # an unknown name raises, naming the registered experts
        try:
            expert = cls.from_scene(scene, quick_config(cls, uncapped)).to(device).eval()
            with torch.no_grad():
                rgb, _, frame = expert.render(camera, background)
            if rgb.device.type != device.type:
                raise RuntimeError(f"rendered on {rgb.device}, asked for {device}")
        except Exception as exc:  # a portability check: report and go on
            rows.append({"expert": name, "ok": False, "error": f"{type(exc).__name__}: {exc}"})
            continue
        experts[name] = expert
        rows.append({"expert": name, "ok": True, "gaussians": int(frame.means.shape[0])})
    return experts, rows


def measure(
    scene,
    names,
    moe_names,
    device,
    views: int,
    warmup: int,
    repeats: int,
    uncapped: bool = False,
    scale: float = 1.0,
) -> dict:
    """Build the experts, time each one's render and MoE-GS single-pass against separate passes; the
    test cameras are scaled by ``scale`` (image size and focal length)."""
    cameras = [view.camera.scaled(scale).to(device) for view in scene.test[:views]]
    background = scene.background.to(device)
    experts, rows = build_experts(scene, names, device, uncapped)

    def timing(fn) -> dict:
        with torch.no_grad():
            result = measure_render(fn, cameras, warmup=warmup, repeats=repeats, device=device)
        return {"ms": result.ms_per_view_median, "device": result.device}

    for row in rows:
        if row["ok"]:
            row.update(timing(lambda cam, e=experts[row["expert"]]: e.render(cam, background)[0]))
    result = {
        "scene": scene.name,
        "views": len(cameras),
        "resolution": f"{cameras[0].width}x{cameras[0].height}",
        "repeats": repeats,
        "experts": rows,
        "moe": None,
    }
    if missing := [n for n in moe_names if n not in experts]:
        result["moe"] = {
            "experts": list(moe_names),
            "ok": False,
            "error": f"experts not available: {missing}",
        }
        return result
    model = MoEGS([experts[n] for n in moe_names], RouterConfig.from_preset("quick")).to(device)
    separate = timing(lambda cam: model.render(cam, background, single_pass=False).image)
    single = timing(lambda cam: model.render(cam, background, single_pass=True).image)
    result["moe"] = {
        "experts": list(moe_names),
        "router": model.config.variant,
        "ok": True,
        "separate_ms": separate["ms"],
        "single_pass_ms": single["ms"],
        "speedup": separate["ms"] / single["ms"],
    }
    return result


def markdown(result: dict) -> str:
    """The README table of one ``measure`` result."""
    lines = [
        "| expert (untrained, quick preset) | Gaussians | render (ms) | renders/s |",
        "|---|---|---|---|",
    ]
    for row in result["experts"]:
        if row["ok"]:
            lines.append(
                f"| {row['expert']} | {row['gaussians']} | {row['ms']:.2f} | {1000 / row['ms']:.0f} |"
            )
        else:
            lines.append(f"| {row['expert']} | failed: {row['error'].splitlines()[0][:120]} | – | – |")
    moe = result["moe"]
    lines += ["", "| MoE-GS, K experts | router | K passes (ms) | one pass (ms) | FPS (K → one) | speed-up |"]
    lines.append("|---|---|---|---|---|---|")
    if moe["ok"]:
        k_ms, one_ms = moe["separate_ms"], moe["single_pass_ms"]
        lines.append(
            f"| {' + '.join(moe['experts'])} | {moe['router']} | {k_ms:.2f} | {one_ms:.2f} | "
            f"{1000 / k_ms:.0f} → {1000 / one_ms:.0f} | {moe['speedup']:.2f}× |"
        )
    else:
        lines.append(f"| {' + '.join(moe['experts'])} | failed: {moe['error']} | – | – | – | – |")
    device = next((row["device"] for row in result["experts"] if row["ok"]), "?")
    resampled = result.get("gaussians")
    command = "python -m bench.moe_fps" + (f" --gaussians {resampled}" if resampled else "")
    command += f" --scale {result['scale']:g}" if result.get("scale", 1.0) != 1.0 else ""
    size = (
        f"the initial cloud resampled to {resampled} points, every expert starting from all of them"
        if resampled
        else "the initial clouds' size"
    )
    lines += [
        "",
        f"`{command}` on `{result['scene']}`, {result['views']} test views at "
        f"{result.get('resolution', 'the scene resolution')}, median of "
        f"{result['repeats']} synchronised renders per view; {device}; {result.get('date', '')}, torch "
        f"{result.get('torch', '?')}. Untrained experts and router: times of the fields, decoding, router "
        f"and rasterizer at {size}, not of trained models.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.moe_fps", description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--scene", default="synthetic:n3v_like")
    p.add_argument("--experts", help="comma-separated expert names (default: every registered expert)")
    p.add_argument("--moe", default=",".join(DEFAULT_MOE), help="the K experts MoE-GS blends")
    p.add_argument("--views", type=positive_int, default=4, help="test views timed (default 4)")
    p.add_argument("--warmup", type=non_negative_int, default=3)
    p.add_argument("--repeats", type=positive_int, default=10)
    p.add_argument(
        "--gaussians",
        type=positive_int,
        help="resample the scene's initial cloud to this many points and start every expert from all of "
        "them (the paper's scenes hold a few hundred thousand Gaussians per expert)",
    )
    p.add_argument(
        "--scale",
        type=positive_float,
        default=1.0,
        help="scale the test cameras (image size and focal length); the N3V stand-in's 128x96 x 10.5 is "
        "about N3V's 1352x1014",
    )
    p.add_argument("--json", type=Path, help="write the result here; with --from-json, read it instead")
    p.add_argument("--from-json", action="store_true", help="only build the table from --json")
    p.add_argument("--readme", type=Path, help="rewrite this README's results:moe-fps section")
    args = p.parse_args(argv)
    if args.from_json:
        if args.json is None or not args.json.is_file():
            p.error(f"--from-json needs an existing --json file, got {args.json}")
        result = json.loads(args.json.read_text())
    else:
        names = args.experts.split(",") if args.experts else [spec.name for spec in list_experts()]
        scene = load_scene(args.scene)
        if args.gaussians is not None:
            try:
                scene = with_points(scene, args.gaussians)
            except ValueError as exc:
                p.error(str(exc))
        result = measure(
            scene,
            names,
            args.moe.split(","),
            torch.device(args.device),
            args.views,
            args.warmup,
            args.repeats,
            uncapped=args.gaussians is not None,
            scale=args.scale,
        )
        result.update(
            date=datetime.now(UTC).strftime("%Y-%m-%d"),
            torch=torch.__version__,
            gaussians=args.gaussians,
            scale=args.scale,
        )
        if args.json:
            write_json_atomic(args.json, result)
    table = markdown(result)
    print(table)
    if args.readme:
        from bench.readme import update_readme

        update_readme(args.readme, "moe-fps", table)
    failed = not result["moe"]["ok"] or not all(row["ok"] for row in result["experts"])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
