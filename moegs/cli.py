"""``moegs`` command line: list, recipe, train, eval, render, export, compare, route.

    moegs list                                  # experts, data root, scenes (synthetic: dnerf_like, n3v_like)
    moegs recipe --expert grid4d --scene n3v:coffee_martini   # the config a run would use, and why
    moegs train --expert static --scene dnerf:mutant --preset quick --out runs/static-mutant
    moegs eval runs/static-mutant --profile clean
    moegs render runs/static-mutant --path orbit   # video along a camera path + test-view strips
    moegs export runs/static-mutant --time 0.5 --out mutant.ply
    moegs compare --experts all --scene panoptic:basketball --preset quick   # one table, all experts
    moegs route --experts deformable,grid4d --scene dnerf:mutant     # MoE-GS router + gate maps
    moegs view runs/route_dnerf_mutant_quick_s0/router_vapr   # web viewer: time, experts, gates

``train`` ends by printing the test views' PSNR, SSIM and LPIPS and the files of its run folder:
``config.json``, ``checkpoint.safetensors``, ``metrics.json``, ``loss.json`` and ``loss.png`` (the training
loss of every step, read back from the final checkpoint; ``moegs.outputs``).

``render`` writes into ``<run>/renders`` (``--out``): ``video.mp4``, H.264 yuv420p (crf 18, frames padded to
even sizes) that browsers play, along ``--path``: ``test`` (the test views in time order), ``orbit`` or
``spiral`` (``--frames`` cameras built from the scene's cameras, time advancing uniformly over the scene's
time range; ``moegs.render_path``), or ``auto`` (default: orbit for cameras around the scene, spiral for a
forward-facing rig); ``test/<i>.png``, ground truth | render | error ``[H, 3W, 3]`` of each test view (error:
mean absolute error x4 through the inferno colour map); ``psnr.csv``, the PSNR of each test view.

Before training, ``train`` checks every ``--set`` value against its config field's type and refuses a flag
and a ``--set`` of one field that disagree (``moegs.overrides``), refuses images too small for SSIM and LPIPS
naming the scale argument (``moegs.guards``), and locks its ``--out`` folder (as ``compare`` and ``route``
do): a second command on the folder gets one line. ``eval`` of an unfinished run says so, with its step.

Heavy modules (experts, rasterizer, loaders) are imported inside the commands, so ``moegs list``
and ``--help`` stay fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from moegs.cli_types import (
    add_device_argument,
    add_resume_arguments,
    non_negative_int,
    positive_int,
    scene_name,
    seed,
    unit_scale,
    unit_time,
)
from moegs.threads import start_cpu_workers


def _cmd_list(args: argparse.Namespace) -> int:
    from moegs.data import list_datasets, list_scenes
    from moegs.experts import list_experts
    from moegs.paths import data_root

    print("experts:")
    for spec in list_experts():
        print(f"  {spec.name:<12} {spec.description}")
    print(f"data root: {_describe_root(data_root())}")
    print("scenes (found under the data root; synthetic:<name> is generated on demand):")
    for dataset in list_datasets():
        found = ", ".join(list_scenes(dataset)) or "-"
        if dataset == "synthetic":
            found = ", ".join(SYNTHETIC_SCENES) + " (generated on demand)"
        print(f"  {dataset:<12} {found}")
    return 0


SYNTHETIC_SCENES = ("dnerf_like", "n3v_like")
"""``moegs.data.synthetic.list_synthetic()``, named here so that ``moegs list`` imports no torch (a test
keeps the two equal)."""


def _describe_root(root: Path | None) -> str:
    """The data root as ``moegs list`` shows it, saying why no real scene can be found there."""
    if root is None:
        return "none (set MOEGS_DATA; the default ../shared/data beside the repository does not exist)"
    if not root.is_dir():
        return f"{root} (MOEGS_DATA) does not exist or is not a folder"
    return str(root)


def _load_kwargs(meta: dict) -> dict:
    """``load_scene`` arguments of a run's ``config.json``: those its training used
    (``moegs.recipes.scene_load_kwargs`` on the recorded recipe and training config)."""
    from moegs.recipes import scene_load_kwargs

    recipe = meta.get("recipe") or {}
    return scene_load_kwargs(
        meta["scene"],
        recipe.get("background"),
        meta["train"].get("resolution_scale"),
        user_scale="train.resolution_scale" in (recipe.get("overrides") or {}),
        loader_args=recipe.get("loader_args"),
    )


def _load_scene(meta: dict):
    """The scene of a run's ``config.json``, loaded as it was for training."""
    from moegs.data import load_scene

    return load_scene(meta["scene"], **_load_kwargs(meta))


def _load_run(path: str, device=None, with_state: bool = False):
    """``(run folder, run config, scene, expert)`` of a finished or interrupted run; the expert on ``device``
    (None: the CPU) and the scene placed beside it; ``with_state`` adds its checkpoint state."""
    from moegs.train.entry import load_trained
    from moegs.train.reuse import read_run_config

    run, meta = read_run_config(path)
    scene = _load_scene(meta)
    expert, state = load_trained(run, scene, expect=meta["expert"], device=device)
    loaded = (run, meta, scene.to(device or "cpu"), expert)
    return (*loaded, state) if with_state else loaded


def unfinished_note(run: Path, meta: dict, state: dict) -> str | None:
    """``None`` for a finished run (``moegs.train.entry.finished_run``), else a line saying at which step its
    checkpoint stopped and how to finish it."""
    from moegs.train.entry import finished_run

    if finished_run(run) is not None:
        return None
    steps = [s.get("step") for s in state.get("segments", [state])]
    at = ", ".join(map(str, steps))
    iterations = meta["train"].get("iterations")
    return (
        f"unfinished run: its checkpoint is at step {at} of {iterations} (no completed metrics.json); the "
        f"scores above are that checkpoint's, and the `moegs train` that wrote {run} finishes it"
    )


def describe_device(device) -> str:
    """``cpu`` or ``cuda:0 (NVIDIA H100 80GB HBM3)``: the device a command computes on."""
    from moegs.device import device_name, gpu_model

    gpu = gpu_model(device)
    return device_name(device) + (f" ({gpu})" if gpu else "")


def _train_recipe(args: argparse.Namespace):
    """The recipe of ``moegs train``: ``--set`` values parsed by their fields' types, a flag and a ``--set``
    of one field that disagree refused (``moegs.overrides``), the config's own checks naming the override."""
    from moegs import overrides as sets
    from moegs.recipes import config_for

    texts = sets.split_items(args.set or [])
    given = sets.typed_overrides(config_for(args.expert, args.scene, args.preset).config, texts)
    flags = {
        "--seed": args.seed,
        "--iterations": args.iterations,
        "--resolution-scale": args.resolution_scale,
        "--checkpoint-every": args.checkpoint_every,
    }
    overrides = sets.with_flags(given, texts, flags)

    def build(changes):
        return config_for(args.expert, args.scene, args.preset, overrides=changes)

    recipe = sets.checked_config(build, overrides, texts)
    if "train.checkpoint_every" not in overrides:  # default: a tenth of the run
        overrides["train.checkpoint_every"] = max(1, recipe.config.train.iterations // 10)
        recipe = build(overrides)
    return recipe


def _scale_flag(args: argparse.Namespace) -> str:
    """The argument that set ``moegs train``'s resolution scale, with its separator, for messages."""
    if args.resolution_scale is None and any(i.startswith("train.resolution_scale=") for i in args.set or []):
        return "--set train.resolution_scale="
    return "--resolution-scale "


def _cmd_train(args: argparse.Namespace) -> int:
    from moegs.data import load_scene
    from moegs.guards import clear_folder, folder_lock, load_checked
    from moegs.outputs import describe_run, format_scores, loss_curves, write_loss_curve
    from moegs.train.entry import train_recipe
    from moegs.train.reuse import finished_run_of

    recipe = _train_recipe(args)
    name = f"{args.expert}_{args.scene.replace(':', '_')}_{args.preset}_s{recipe.config.train.seed}"
    out = Path(args.out or Path("runs") / name)
    with folder_lock(out):
        finished = (
            None
            if args.force
            else finished_run_of(recipe, out, "--force trains it again, or choose another --out")
        )
        if finished is not None:
            print(
                f"{out} holds a finished run (test {format_scores(finished['test'])}); left as it is "
                "(--force trains it again)"
            )
            return 0
        if args.force:
            clear_folder(out)
        scale = recipe.load_kwargs.get("resolution_scale")
        scene = load_checked(lambda: load_scene(args.scene, **recipe.load_kwargs), scale, _scale_flag(args))
        print(scene.summary())
        print("recipe: " + "; ".join(recipe.steps))
        print(f"device: {describe_device(args.device)}")
        _, result = train_recipe(
            recipe, scene, out, device=args.device, resume=not args.no_resume, progress=not args.quiet
        )
        write_loss_curve(loss_curves(out), out, title=f"{args.expert} on {scene.name}")
    test = result["test"]
    print(
        f"{args.expert} on {scene.name}: {result['num_gaussians']} Gaussians, "
        f"{result['train_seconds']:.1f} s training"
    )
    views = f" ({test['num_views']} views)" if test else ""
    print(f"test{views}: {format_scores(test)}")
    _print_files(out, describe_run(out))
    return 0


def _cmd_recipe(args: argparse.Namespace) -> int:
    from moegs.io import to_dict
    from moegs.recipes import config_for

    recipe = config_for(args.expert, args.scene, args.preset, dataset=args.dataset)
    if args.json:
        print(json.dumps({"recipe": recipe.provenance(), "config": to_dict(recipe.config)}, indent=1))
        return 0
    print(f"{args.expert} on {args.scene} at {args.preset}:")
    for step in recipe.steps:
        print(f"  - {step}")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from moegs.guards import check_image_sizes
    from moegs.io import write_json
    from moegs.train.evaluate import evaluate

    run, meta, scene, expert, state = _load_run(args.run, args.device, with_state=True)
    try:
        check_image_sizes(scene, _load_kwargs(meta).get("resolution_scale"))
    except ValueError as err:
        raise ValueError(f"{run} was trained on images too small to score: {err}") from None
    result = evaluate(expert, scene.test, scene.background, args.profile, meta["train"]["backend"])
    note = unfinished_note(run, meta, state)
    write_json(run / f"eval-{args.profile}.json", {**result, "unfinished": note})
    lpips = "n/a" if result["lpips"] is None else f"{result['lpips']:.4f}"
    print(
        f"{meta['expert']} on {scene.name} ({result['num_views']} test views, profile {args.profile}): "
        f"PSNR {result['psnr']:.2f}  SSIM {result['ssim']:.4f}  LPIPS {lpips}"
    )
    if note:
        print(note)
    return 0


RENDER_PATHS = ("auto", "test", "orbit", "spiral")
"""``moegs.render_path.PATHS``, named here so that ``--help`` imports no torch (a test keeps them equal)."""


def _cmd_render(args: argparse.Namespace) -> int:
    import torch

    run, meta, scene, expert = _load_run(args.run, args.device)
    path, cameras = _path_cameras(args, scene)
    out = Path(args.out) if args.out else run / "renders"
    out.mkdir(parents=True, exist_ok=True)
    backend = meta["train"]["backend"]
    with torch.no_grad():
        renders = _write_test_views(expert, scene, backend, out) if scene.test else []
        if path == "test":
            frames = [renders[i] for i in _test_order(scene)]
        else:
            frames = [_render_image(expert, c, scene, backend) for c in cameras]
    fps = args.fps or (10 if path == "test" else 30)
    size = _write_video(frames, out / "video.mp4", fps)
    times = f"time {cameras[0].time:.3f} -> {cameras[-1].time:.3f}"
    _print_files(
        out,
        [("video.mp4", f"{len(frames)} frames along the {path} path, {times}, {size}, {fps} fps")]
        + (_test_view_files(len(renders)) if renders else []),
    )
    return 0


def _test_view_files(n: int) -> list[tuple[str, str]]:
    """``(name, what it holds)`` of the files ``_write_test_views`` writes for ``n`` test views."""
    from moegs.outputs import ERROR_COLORMAP, ERROR_GAIN

    error = f"mean |error| x{ERROR_GAIN:g}, {ERROR_COLORMAP} colour map"
    return [
        (f"test/00000..{n - 1:05d}.png", f"ground truth | render | error of each test view ({error})"),
        ("psnr.csv", "the PSNR of each test view"),
    ]


def _print_files(folder: Path, files: list[tuple[str, str]]) -> None:
    """``wrote <folder>:`` and one line per ``(name, what it holds)``."""
    print(f"wrote {folder}:")
    width = max(len(name) for name, _ in files)
    for name, what in files:
        print(f"  {name:<{width}}  {what}".rstrip())


def _render_image(expert, camera, scene, backend: str):
    """uint8 ``[H, W, 3]`` render of ``expert`` through ``camera`` (placed on the scene's device)."""
    from moegs.train.evaluate import render_view

    rgb, _, _ = render_view(expert, camera.to(scene.background.device), scene.background, backend)
    return _uint8(rgb)


def _write_test_views(expert, scene, backend: str, out: Path) -> list:
    """``out/test/<i>.png`` strips (ground truth | render | error, ``[H, 3W, 3]``) and ``out/psnr.csv`` of
    the scene's test views. Returns their renders (uint8 ``[H, W, 3]``) in the order of ``scene.test``."""
    import csv

    import imageio.v3 as iio

    from moegs.metrics import psnr
    from moegs.outputs import comparison_strip
    from moegs.train.evaluate import render_view

    renders, rows = [], []
    (out / "test").mkdir(exist_ok=True)
    for i, view in enumerate(scene.test):
        rgb, _, _ = render_view(expert, view.camera, scene.background, backend)
        target = view.image()
        image = _uint8(rgb)
        iio.imwrite(out / "test" / f"{i:05d}.png", comparison_strip(image, _uint8(target)))
        renders.append(image)
        rows.append({"index": i, "key": view.key, "time": view.camera.time, "psnr": float(psnr(rgb, target))})
    with open(out / "psnr.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return renders


def _uint8(image):
    """``[H, W, 3]`` float tensor in [0, 1] -> uint8 numpy array."""
    import torch

    return (image.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()


def _path_cameras(args: argparse.Namespace, scene) -> tuple[str, list]:
    """``(path name, cameras)`` of ``--path``: the test cameras by time, or an orbit / spiral of
    ``--frames`` cameras built from all of the scene's cameras, time advancing over the scene's range."""
    from moegs.render_path import camera_path

    if args.path == "test":
        if not scene.test:
            raise ValueError("--path test: the scene has no test views; use --path orbit or spiral")
        return "test", [scene.test[i].camera for i in _test_order(scene)]
    cameras = [v.camera for v in [*scene.train, *scene.test]]
    times = [v.camera.time for v in scene.train]
    reference = (scene.test or scene.train)[0].camera
    return camera_path(args.path, cameras, reference, args.frames, (min(times), max(times)))


def _test_order(scene) -> list[int]:
    """Indices of ``scene.test`` by time, then camera."""
    return sorted(
        range(len(scene.test)), key=lambda i: (scene.test[i].camera.time, scene.test[i].camera.camera_id)
    )


def _write_video(frames: list, path: Path, fps: int) -> str:
    """H.264 yuv420p mp4 (crf 18, plays in browsers) of uint8 ``[H, W, 3]`` frames, each padded to even
    sizes (``moegs.outputs.pad_even``); returns ``"WxH H.264 yuv420p"``."""
    from moegs.io.video import VideoWriter
    from moegs.outputs import pad_even

    frames = [pad_even(f) for f in frames]
    height, width = frames[0].shape[:2]
    with VideoWriter(path, width, height, fps, codec="yuv420") as video:
        for frame in frames:
            video.write(frame)
    return f"{width}x{height} H.264 yuv420p"


EXPORT_FORMATS = ("ply", "splat")
"""``moegs.exports.FORMATS``, named here so that ``--help`` imports no torch (a test keeps them equal)."""


def _cmd_export(args: argparse.Namespace) -> int:
    """One file at ``--time`` (default 0), or one per time of ``--times`` in a folder with ``index.json``
    (``moegs.exports``)."""
    import torch

    from moegs.exports import export_times, parse_times, write_frame

    if args.times is not None:
        parse_times(args.times, [])  # a bad list fails before the run loads
    run, meta, scene, expert = _load_run(args.run)
    if args.times is not None:
        times = parse_times(args.times, scene.times.tolist())
        out = Path(args.out) if args.out else run / f"export_{args.format}"
        about = {"expert": meta["expert"], "scene": meta["scene"], "run": str(run)}
        index = export_times(expert, times, out, args.format, about)
        span = f"t={times[0]:.3f}" + (f" .. {times[-1]:.3f}" if len(times) > 1 else "")
        files = f"{len(times)} .{args.format} files, {index.name}"
        print(f"Gaussians at {len(times)} times ({span}) -> {out}: {files}")
        return 0
    time = 0.0 if args.time is None else args.time
    with torch.no_grad():
        path = write_frame(
            expert.frame(time), args.out or run / f"point_cloud_t{time:.3f}.{args.format}", args.format
        )
    print(f"Gaussians at t={time} -> {path}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    """Open runs or a router folder in the web viewer (``moegs.viewer``) until Ctrl+C."""
    import time

    from moegs.viewer.model import load_model
    from moegs.viewer.render import check_choice
    from moegs.viewer.server import Viewer, check_port

    check_port(args.host, args.port)
    start = time.perf_counter()
    model = load_model(args.runs, args.device)
    check_choice(args.mode, model.modes, "mode")
    viewer = Viewer(model, args.host, args.port, size=args.size, mode=args.mode, source=args.source)
    print(
        f"{model.label}: {', '.join(model.names)}, {model.num_gaussians:,} Gaussians on "
        f"{describe_device(args.device)}, opened in {time.perf_counter() - start:.1f} s"
    )
    print(f"viewer at {viewer.url} (Ctrl+C stops it)", flush=True)
    try:
        viewer.wait()
    except KeyboardInterrupt:
        pass
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from moegs import compare

    return compare.main(args)


def _cmd_route(args: argparse.Namespace) -> int:
    from moegs import route

    return route.main(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="moegs", description="Mixture-of-Experts dynamic Gaussian Splatting"
    )
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)

    sub.add_parser("list", help="registered experts and the scenes found under the data root")

    p = sub.add_parser("train", help="train one expert on one scene")
    p.add_argument("--expert", required=True, help="registry name (see `moegs list`)")
    p.add_argument("--scene", required=True, type=scene_name, help="<dataset>:<scene>, e.g. dnerf:mutant")
    p.add_argument(
        "--preset",
        default="quick",
        choices=["quick", "paper"],
        help="recipe preset: quick (CPU minutes) or paper (the original's recipe for the scene's dataset)",
    )
    p.add_argument("--out", help="run folder (default runs/<expert>_<scene>_<preset>_s<seed>)")
    p.add_argument("--seed", type=seed, help="training seed (default 0, the preset's)")
    p.add_argument("--iterations", type=positive_int, help="override the preset's number of iterations")
    p.add_argument("--resolution-scale", type=unit_scale, help="override the preset's image scale in (0, 1]")
    p.add_argument(
        "--set",
        nargs="*",
        metavar="FIELD=VALUE",
        help="override config fields by dotted name, e.g. --set strategy.densify_every=50 train.batch_size=1 "
        "(each value is checked against its field's type; a flag of the same field must agree)",
    )
    p.add_argument(
        "--no-resume", action="store_true", help="start over even if the run folder has a checkpoint"
    )
    add_resume_arguments(p, "expert")
    add_device_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("recipe", help="the config a run uses: dataset preset, scene values, reductions")
    p.add_argument("--expert", required=True, help="registry name (see `moegs list`)")
    p.add_argument(
        "--scene", required=True, type=scene_name, help="<dataset>:<scene>, e.g. n3v:coffee_martini"
    )
    p.add_argument("--preset", default="paper", choices=["quick", "paper"])
    p.add_argument("--dataset", help="the dataset whose recipe applies (default: the scene's)")
    p.add_argument("--json", action="store_true", help="the provenance and the full config as JSON")

    p = sub.add_parser("eval", help="evaluate a trained run on its test views")
    p.add_argument("run", help="run folder written by `moegs train`")
    p.add_argument(
        "--profile",
        default="moegs",
        choices=["moegs", "clean"],
        help="metric profile: moegs (paper conventions) or clean",
    )
    add_device_argument(p, "render and score")

    p = sub.add_parser(
        "render",
        help="a video along a camera path, and ground truth | render | error strips of the test views",
        description="Writes <out>/video.mp4 (H.264 yuv420p, plays in browsers), <out>/test/<i>.png (ground "
        "truth | render | error of each test view) and <out>/psnr.csv (PSNR of each test view).",
    )
    p.add_argument("run", help="run folder written by `moegs train`")
    p.add_argument("--out", help="output folder (default <run>/renders)")
    p.add_argument(
        "--path",
        default="auto",
        choices=RENDER_PATHS,
        help="camera path of the video: test (the test views in time order), orbit (a circle around the "
        "cameras' look-at centre), spiral (NeRF's spiral around the mean camera, for forward-facing rigs), "
        "auto (default: orbit when the cameras surround the scene, spiral when they face one way); orbit "
        "and spiral advance time uniformly over the scene's time range",
    )
    p.add_argument(
        "--frames", type=positive_int, default=120, help="frames of an orbit or spiral video (default 120)"
    )
    p.add_argument(
        "--fps", type=positive_int, help="frames per second of the video (default 30; 10 with --path test)"
    )
    add_device_argument(p, "render")

    p = sub.add_parser(
        "export",
        help="write the Gaussians at one or more times as 3DGS PLY or .splat files",
        description="ply: the standard 3DGS PLY; splat: the 32-byte-per-Gaussian layout of "
        "antimatter15/splat and the web viewers that read it (moegs.exports).",
    )
    p.add_argument("run")
    when = p.add_mutually_exclusive_group()
    when.add_argument("--time", type=unit_time, help="normalised time in [0, 1] of one file (default 0)")
    when.add_argument(
        "--times",
        help="'all' (the scene's frame times) or t0,t1,...: one file per time in a folder, with index.json",
    )
    p.add_argument("--format", default="ply", choices=EXPORT_FORMATS, help="ply (default) or splat")
    p.add_argument(
        "--out",
        help="file with --time (default <run>/point_cloud_t<time>.<format>); folder with --times "
        "(default <run>/export_<format>)",
    )

    p = sub.add_parser(
        "view",
        help="a local web viewer of trained runs or a MoE-GS router folder: time, experts, gates",
        description="Serves a page (viser) with a free camera and the dataset's cameras, a time slider with "
        "play/pause and the modes rgb, depth, alpha, ground truth, error, and for a router folder each "
        "expert's gate map and the winner map (moegs.viewer).",
    )
    p.add_argument(
        "runs",
        nargs="+",
        metavar="RUN",
        help="a run folder (moegs train), several of one scene, or a router folder (moegs route)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=non_negative_int, default=8080, help="port (default 8080; 0: any free)")
    p.add_argument(
        "--mode",
        default="rgb",
        help="first mode: rgb, depth, alpha, ground truth, error, gate <expert>, winner (default rgb)",
    )
    p.add_argument("--source", help="first image source: blend (a router's) or an expert's name")
    p.add_argument(
        "--size", type=positive_int, help="longer side of a frame at rest (default the scene's, at least 256)"
    )
    add_device_argument(p, "render")

    p = sub.add_parser("compare", help="train and evaluate several experts on one scene; per-expert table")
    from moegs.compare import add_arguments

    add_arguments(p)

    p = sub.add_parser("route", help="MoE-GS: train experts, then a router over them; gate-map figures")
    from moegs.route import add_arguments as add_route_arguments

    add_route_arguments(p)
    return parser


#: commands that compute nothing with torch (and stay instant)
_COMPUTE_NOTHING = frozenset({"list", "recipe"})

_COMMANDS = {
    "list": _cmd_list,
    "train": _cmd_train,
    "recipe": _cmd_recipe,
    "eval": _cmd_eval,
    "render": _cmd_render,
    "export": _cmd_export,
    "view": _cmd_view,
    "compare": _cmd_compare,
    "route": _cmd_route,
}


def main(argv: list[str] | None = None) -> int:
    """Run one command. Every error ends in one line on stderr naming what was wrong (exit 2 for bad input
    or files, 1 for anything unexpected, 130 when interrupted); ``--debug`` raises it with its traceback."""
    from moegs.errors import INPUT_ERRORS, TrainingInterrupted, describe_error

    args = build_parser().parse_args(argv)
    prefix = f"moegs {args.command}:"
    try:
        if args.command not in _COMPUTE_NOTHING:
            start_cpu_workers()  # processes compute alike (moegs.threads)
        return _COMMANDS[args.command](args)
    except TrainingInterrupted as err:
        print(f"{prefix} interrupted: {err}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        if args.debug:
            raise
        print(f"{prefix} interrupted before anything could be saved", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - the one place every error becomes one line
        if args.debug:
            raise
        print(f"{prefix} {describe_error(err)}", file=sys.stderr)
        return 2 if isinstance(err, INPUT_ERRORS) else 1


if __name__ == "__main__":
    sys.exit(main())
