"""Where one training step of an expert spends its time (``python -m bench.profile``).

    python -m bench.profile --expert deformable --scene dnerf:mutant [--json profile.json]
    python -m bench.profile --expert static,deformable,grid4d --scene dnerf:mutant --readme docs/speed.md

Builds the expert as the bench does (``moegs.recipes.config_for`` at ``--preset``, the recipe's scene
loading), runs ``--warmup`` steps, then times ``--steps`` steps of the training loop itself
(``moegs.train.loop.TrainingRun.iteration``), with exclusive wall-clock timers around:

==============  ===========================================================================================
data            ``View.image``: decoding and resizing the ground truth (or the image cache)
fields          the expert's ``splat_inputs``: deformation networks, encoders, per-Gaussian activations
projection      SH colours, 3D covariances, EWA projection, camera points (``moegs.render.pipeline``)
raster fwd      the compositing call (compiled kernel or torch reference)
raster bwd      the compiled kernel's backward (with the torch reference it is autograd, in "backward")
backward        the rest of ``loss.backward()``: fields, projection and loss gradients
loss            the photometric loss and the method's regularisers (which may evaluate its fields again)
optimizer       the optimisers' ``step`` and ``zero_grad``
densification   the strategy's hooks (densify, prune, relocate, reset)
other           the remainder of the step (view sampling, training-time observers, finiteness checks ...)
==============  ===========================================================================================

It also states the step's arithmetic against a floor: the networks' FLOPs (``torch.utils.flop_counter``:
matmuls and convolutions only, forward x 3 for forward and backward), the rasterizer's (``RASTER_FLOPS``
per Gaussian-pixel pair of the screen boxes, forward and backward) and the projection's
(``PROJECT_FLOPS`` per Gaussian), divided by this machine's measured float32 matmul rate. The floor is a
lower bound, not a prediction.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from moegs.cli_types import non_negative_int, positive_int
from moegs.cli_types import seed as seed_arg

CATEGORIES = (
    "data",
    "fields",
    "projection",
    "raster fwd",
    "raster bwd",
    "backward",
    "loss",
    "optimizer",
    "densification",
    "other",
)
RASTER_FLOPS = 60
"""Floating-point operations per Gaussian-pixel pair, forward (~20: offset, quadratic form, exp, alpha,
transmittance, 3 colour channels) and backward (~40)."""
PROJECT_FLOPS = 600
"""Per Gaussian, forward and backward: covariance from quaternion and scale, world-to-camera, Jacobian,
2D covariance, conic, radius."""


class ExclusiveTimers:
    """Wall-clock seconds per category, each counted once: time inside a nested timed call goes to the
    inner category only."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(CATEGORIES, 0.0)
        self._stack: list[list[Any]] = []  # [category, time the category last resumed]

    @contextlib.contextmanager
    def timing(self, category: str) -> Iterator[None]:
        now = time.perf_counter()
        if self._stack:
            outer = self._stack[-1]
            self.seconds[outer[0]] += now - outer[1]
        self._stack.append([category, now])
        try:
            yield
        finally:
            end = time.perf_counter()
            name, start = self._stack.pop()
            self.seconds[name] += end - start
            if self._stack:
                self._stack[-1][1] = end

    def wrap(self, category: str, fn: Callable) -> Callable:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.timing(category):
                return fn(*args, **kwargs)

        return timed


@contextlib.contextmanager
def _patched(timers: ExclusiveTimers, run: Any) -> Iterator[None]:
    """Wrap the functions of each category for the duration of the block (restored afterwards)."""
    import torch

    from moegs.data.scene import View
    from moegs.render import _cpu, pipeline
    from moegs.train import loop
    from moegs.train.optim import Optimizers

    targets: list[tuple[Any, str, str]] = [
        (View, "image", "data"),
        (type(run.expert), "splat_inputs", "fields"),
        (pipeline, "frame_colors", "projection"),
        (pipeline, "covariance_3d", "projection"),
        (pipeline, "project", "projection"),
        (_cpu, "project", "projection"),
        (_cpu, "covariance_3d", "projection"),
        (pipeline, "camera_points", "projection"),
        (pipeline, "_composite", "raster fwd"),
        (_cpu, "composite", "raster fwd"),
        (torch.Tensor, "backward", "backward"),
        (loop, "photometric", "loss"),
        (type(run.expert), "regularization", "loss"),
        (Optimizers, "step", "optimizer"),
        (Optimizers, "zero_grad", "optimizer"),
    ]
    if run.strategy is not None:
        for hook in ("step_pre_backward", "step_post_backward", "step_post_optimizer"):
            targets.append((run.strategy, hook, "densification"))
    own = [(owner, name, vars(owner).get(name)) for owner, name, _ in targets]  # None: inherited
    backward = _cpu._Composite.backward
    try:
        for owner, name, category in targets:
            setattr(owner, name, timers.wrap(category, getattr(owner, name)))
        _cpu._Composite.backward = staticmethod(timers.wrap("raster bwd", backward))
        yield
    finally:
        _cpu._Composite.backward = staticmethod(backward)
        for owner, name, original in own:
            if original is None:
                delattr(owner, name)
            else:
                setattr(owner, name, original)


def matmul_gflops(size: int = 1024, repeats: int = 5) -> float:
    """This machine's float32 matmul rate (GFLOP/s, best of ``repeats``) at the current thread count."""
    import torch

    a, b = torch.rand(size, size), torch.rand(size, size)
    best = float("inf")
    for _ in range(repeats + 1):
        start = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - start)
    return 2 * size**3 / best / 1e9


def step_flops(run: Any) -> dict[str, float]:
    """FLOPs of one training step of ``run``: networks (forward x 3), projection and rasterizer."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from moegs.render.projection import covariance_3d, project

    expert, scene = run.expert, run.scene
    views = [scene.train[i] for i in range(min(len(scene.train), run.config.batch_size))]
    networks = projection = raster = 0.0
    for view in views:
        with torch.no_grad(), FlopCounterMode(display=False) as counter:
            inputs = expert.splat_inputs(view.camera, scene.background)
        networks += 3.0 * counter.get_total_flops()
        frame = inputs.frame
        with torch.no_grad():
            proj = project(
                frame.means, covariance_3d(frame.quats, frame.scales), frame.opacities, view.camera
            )
        r = proj.radii.long()
        x, y = proj.means2d[:, 0], proj.means2d[:, 1]
        w = (torch.minimum(x + r, torch.tensor(view.camera.width)) - torch.clamp(x - r, min=0)).clamp(min=0)
        h = (torch.minimum(y + r, torch.tensor(view.camera.height)) - torch.clamp(y - r, min=0)).clamp(min=0)
        raster += RASTER_FLOPS * float((w * h)[r > 0].sum())
        projection += PROJECT_FLOPS * len(frame)
    return {"networks": networks, "projection": projection, "rasterizer": raster}


def profile(
    expert: str, scene: str, preset: str = "quick", steps: int = 40, warmup: int = 20, seed: int = 0
) -> dict[str, Any]:
    """Time ``steps`` training steps after ``warmup`` (see the module docstring); JSON-ready result."""
    import torch

    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import build_expert
    from moegs.train.loop import TrainingRun

    if steps < 1 or warmup < 0:
        raise ValueError(f"need steps >= 1 and warmup >= 0, got steps={steps}, warmup={warmup}")
    recipe = config_for(expert, scene, preset, overrides={"train.seed": seed})
    config = recipe.config.train
    if warmup + steps > config.iterations:
        raise ValueError(
            f"--warmup {warmup} + --steps {steps} exceed the recipe's {config.iterations} iterations"
        )
    data = load_scene(scene, **recipe.load_kwargs)
    model = build_expert(recipe, data)
    run = TrainingRun(model, data, config, None)
    torch.manual_seed(config.seed)
    model.train()
    for step in range(1, warmup + 1):
        run.iteration(step)
    timers = ExclusiveTimers()
    per_step = []
    with _patched(timers, run):
        for step in range(warmup + 1, warmup + steps + 1):
            start = time.perf_counter()
            with timers.timing("other"):
                run.iteration(step)
            per_step.append(time.perf_counter() - start)
    total = sum(per_step)
    flops = step_flops(run)
    rate = matmul_gflops()
    floor_ms = sum(flops.values()) / (rate * 1e9) * 1e3
    return {
        "expert": expert,
        "scene": scene,
        "preset": preset,
        "backend": config.backend,
        "threads": torch.get_num_threads(),
        "steps": [warmup + 1, warmup + steps],
        "num_gaussians": model.num_gaussians,
        "step_ms": {"mean": 1e3 * total / steps, "median": 1e3 * statistics.median(per_step)},
        "ms_per_step": {k: 1e3 * v / steps for k, v in timers.seconds.items()},
        "share": {k: v / total for k, v in timers.seconds.items()},
        "flops_per_step": flops,
        "matmul_gflops": rate,
        "floor_ms": floor_ms,
    }


def format_profile(result: dict[str, Any]) -> str:
    """A table of the shares and the arithmetic summary."""
    r = result
    lines = [
        f"{r['expert']} on {r['scene']} ({r['preset']}, backend {r['backend']}, {r['threads']} threads, "
        f"{r['num_gaussians']} Gaussians), steps {r['steps'][0]}-{r['steps'][1]}: "
        f"{r['step_ms']['mean']:.1f} ms a step (median {r['step_ms']['median']:.1f})",
        f"{'part':<14} {'ms/step':>8} {'share':>7}",
    ]
    for k in CATEGORIES:
        lines.append(f"{k:<14} {r['ms_per_step'][k]:>8.2f} {100 * r['share'][k]:>6.1f}%")
    f = r["flops_per_step"]
    lines.append(
        "arithmetic per step: "
        + ", ".join(f"{k} {v / 1e6:.1f} MFLOP" for k, v in f.items())
        + f"; at this machine's matmul rate ({r['matmul_gflops']:.0f} GFLOP/s) the floor is "
        f"{r['floor_ms']:.2f} ms, the step takes {r['step_ms']['mean'] / max(r['floor_ms'], 1e-9):.0f}x that"
    )
    return "\n".join(lines)


def markdown(results: list[dict[str, Any]]) -> str:
    """The README table: one row per expert, the share of each part and the arithmetic floor."""
    head = "| expert | ms / step | " + " | ".join(CATEGORIES) + " | floor (ms) |"
    lines = [head, "|---" * (len(CATEGORIES) + 3) + "|"]
    for r in results:
        shares = " | ".join(f"{100 * r['share'][k]:.0f}%" for k in CATEGORIES)
        lines.append(f"| {r['expert']} | {r['step_ms']['mean']:.1f} | {shares} | {r['floor_ms']:.2f} |")
    r = results[0]
    lines.append("")
    lines.append(
        f"`python -m bench.profile` on `{r['scene']}`, preset `{r['preset']}`, steps {r['steps'][0]}-"
        f"{r['steps'][1]}, {r['threads']} threads; floor = the step's FLOPs at this machine's measured "
        f"matmul rate ({r['matmul_gflops']:.0f} GFLOP/s)."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--expert", required=True, help="registry name(s), comma-separated (moegs list)")
    parser.add_argument("--scene", required=True, help="<dataset>:<scene>, e.g. dnerf:mutant")
    parser.add_argument("--preset", default="quick", help="recipe preset (default quick)")
    parser.add_argument("--steps", type=positive_int, default=40, help="timed steps (default 40)")
    parser.add_argument(
        "--warmup", type=non_negative_int, default=20, help="untimed steps first (default 20)"
    )
    parser.add_argument("--seed", type=seed_arg, default=0)
    parser.add_argument("--json", type=Path, help="also write the results here (a list, one per expert)")
    parser.add_argument("--readme", type=Path, help="rewrite this README's results:profile section")
    args = parser.parse_args(argv)
    results = []
    for expert in [e.strip() for e in args.expert.split(",") if e.strip()]:
        try:
            results.append(profile(expert, args.scene, args.preset, args.steps, args.warmup, args.seed))
        except (ValueError, FileNotFoundError, KeyError) as err:
            parser.exit(2, f"bench.profile: {err}\n")
        print(format_profile(results[-1]), flush=True)
    if args.json:
        from moegs.io import write_json

        write_json(args.json, results)
    if args.readme:
        from bench.readme import machine_line, update_readme

        update_readme(args.readme, "profile", markdown(results) + f" Machine: {machine_line()}.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
