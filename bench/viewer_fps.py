"""Frames per second of ``moegs view``'s drawing along an orbit: what the viewer can show while the camera
moves (issue target: at least 10 at 256x256 for a MoE-GS model of mutant on 2 CPU cores).

    python -m bench.viewer_fps runs/route_dnerf_mutant_quick_s0/router_vapr --size 256 128 --frames 120

Each frame is ``moegs.viewer.render.render_mode`` through a camera of the orbit
(``moegs.render_path.camera_path``), square, at every ``--size`` in turn so that the sizes see the same
load. ``--time`` fixes the time (each expert's Gaussians are then computed once and kept, as the viewer
does at rest in time); without it the orbit sweeps time once, so every frame computes them anew (the
viewer's ``Play``). Prints the 10th percentile, median and 90th percentile of the per-frame rate per mode
and size; the first ``--warmup`` frames are left out.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def frame_rates(model, cameras, mode: str, source: str, sizes: list[int]) -> dict[int, np.ndarray]:
    """``{size: frames per second of each camera}`` of ``render_mode`` at each square ``size``."""
    from moegs.viewer.render import camera_from_pose, pose_of_camera, render_mode

    rates: dict[int, list[float]] = {size: [] for size in sizes}
    for camera in cameras:
        wxyz, position, fov = pose_of_camera(camera)
        for size in sizes:
            square = camera_from_pose(wxyz, position, fov, size, size, camera.time)
            start = time.perf_counter()
            render_mode(model, square, mode, source)
            rates[size].append(1.0 / (time.perf_counter() - start))
    return {size: np.asarray(r) for size, r in rates.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.viewer_fps", description=__doc__.split("\n")[0])
    parser.add_argument("run", nargs="+", help="what moegs view opens: run folders or a router folder")
    parser.add_argument("--size", type=int, nargs="+", default=[256, 128], help="square frame sizes")
    parser.add_argument("--frames", type=int, default=120, help="cameras along the orbit")
    parser.add_argument("--warmup", type=int, default=5, help="first frames left out")
    parser.add_argument("--time", type=float, default=None, help="fixed time (default: sweep 0 to 1)")
    parser.add_argument(
        "--modes",
        nargs="+",
        default=None,
        help="'MODE:SOURCE' pairs (default: the blend, the last expert's gate map and that expert alone "
        "for a MoE-GS model, else the first expert's rgb)",
    )
    args = parser.parse_args(argv)
    if args.frames <= args.warmup:
        parser.error(f"--frames ({args.frames}) must exceed --warmup ({args.warmup})")

    from moegs.render_path import camera_path
    from moegs.viewer.model import load_model

    start = time.perf_counter()
    model = load_model(args.run)
    print(f"loaded {', '.join(model.names)} in {time.perf_counter() - start:.2f} s")
    times = (0.0, 1.0) if args.time is None else (args.time, args.time)
    cameras = [v.camera for v in model.scene.train]
    _, orbit = camera_path(
        "orbit", cameras, (model.scene.test or model.scene.train)[0].camera, args.frames, times
    )
    pairs = args.modes or (
        ["rgb:blend", f"gate {model.names[-1]}:blend", f"rgb:{model.names[-1]}"]
        if model.moe is not None
        else [f"rgb:{model.names[0]}"]
    )
    when = "time swept" if args.time is None else f"t={args.time:g}"
    print(f"frames/s over {args.frames - args.warmup} orbit cameras ({when}): p10 / median / p90")
    for pair in pairs:
        mode, _, source = pair.partition(":")
        source = source or model.sources[0]
        rates = frame_rates(model, orbit, mode, source, args.size)
        cells = [
            f"{size}x{size} " + " / ".join(f"{np.percentile(r[args.warmup :], q):.1f}" for q in (10, 50, 90))
            for size, r in rates.items()
        ]
        print(f"  {mode} of {source}: " + " | ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
