"""Files the commands leave for people: comparison strips, even-sized video frames, the loss curve, and
what each file of a run folder holds (``moegs render``, ``moegs train``).

Images are uint8 ``[H, W, 3]`` numpy arrays (RGB). The error panel of a strip is the mean absolute error
over the channels, magnified ``ERROR_GAIN`` times and clipped (an error of ``1 / ERROR_GAIN`` or more is
the brightest colour), through matplotlib's ``inferno`` colour map: black where the render is exact.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ERROR_GAIN = 4.0
"""Magnification of the error panel: an absolute error of 0.25 (of the [0, 1] range) or more saturates."""

ERROR_COLORMAP = "inferno"

RUN_FILES = {
    "config.json": "what trained: expert, scene, configs, recipe, device",
    "checkpoint.safetensors": "the trained expert (training resumes from it)",
    "segments.json": "the time windows of a segmented run (one run folder per segment)",
    "metrics.json": "test PSNR, SSIM, LPIPS (mean and per view), timings, Gaussians",
    "loss.json": "the training loss of every step",
    "loss.png": "the loss curve",
}
"""What each file of a run folder holds, in the order ``moegs train`` lists them."""


def pad_even(image: np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` -> ``[H + H % 2, W + W % 2, 3]``: the last row / column repeated (yuv420p needs even
    sizes)."""
    return np.pad(image, ((0, image.shape[0] % 2), (0, image.shape[1] % 2), (0, 0)), mode="edge")


def error_image(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """uint8 ``[H, W, 3]`` colour-mapped error of two uint8 ``[H, W, 3]`` images (see the module)."""
    from matplotlib import colormaps

    if render.shape != truth.shape:
        raise ValueError(f"render {list(render.shape)} and ground truth {list(truth.shape)} differ in shape")
    error = np.abs(render.astype(np.float32) - truth.astype(np.float32)).mean(-1) / 255.0  # [H, W]
    rgba = colormaps[ERROR_COLORMAP](np.clip(error * ERROR_GAIN, 0.0, 1.0))
    return (rgba[..., :3] * 255).round().astype(np.uint8)


def comparison_strip(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """uint8 ``[H, 3W, 3]``: ground truth | render | error (``error_image``)."""
    return np.concatenate([truth, render, error_image(render, truth)], axis=1)


def write_loss_curve(curves: dict[str, list[float]], out_dir: Path, title: str = "") -> list[Path]:
    """``out_dir/loss.json`` (``{"curves": {name: {"first_step": 1, "loss": [loss of each step]}}}``) and
    ``out_dir/loss.png`` (each curve per step, on a log axis when every loss is positive, with its moving
    average over 5% of the steps). ``curves``: ``{name: loss of step 1, 2, ...}``. Returns both paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from moegs.io import write_json

    json_path = write_json(
        out_dir / "loss.json", {"curves": {k: {"first_step": 1, "loss": v} for k, v in curves.items()}}
    )
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=120)
    for name, values in curves.items():
        steps = np.arange(1, len(values) + 1)
        line = ax.plot(steps, values, lw=0.6, alpha=0.35)[0]
        window = max(1, len(values) // 20)
        smooth = np.convolve(values, np.ones(window) / window, mode="valid")
        ax.plot(steps[window - 1 :], smooth, color=line.get_color(), lw=1.5, label=name)
    positive = all(v > 0 for values in curves.values() for v in values)
    ax.set_yscale("log" if positive else "linear")
    ax.set(xlabel="step", ylabel="training loss", title=title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    png_path = out_dir / "loss.png"
    fig.savefig(png_path)
    plt.close(fig)
    return [Path(json_path), png_path]


def loss_curves(run: Path) -> dict[str, list[float]]:
    """``{name: loss per step}`` read from the final checkpoint(s) of a run folder: the run's own, or one
    curve per ``segment_<k>`` of a segmented run."""
    from moegs.train.checkpoint import CHECKPOINT_NAME, read_checkpoint

    if (run / "segments.json").is_file():
        folders = sorted(run.glob("segment_*"), key=lambda p: int(p.name.rpartition("_")[2]))
        return {p.name: list(read_checkpoint(p / CHECKPOINT_NAME)["history"]) for p in folders}
    state = read_checkpoint(run / CHECKPOINT_NAME)
    return {state["expert"]["name"]: list(state["history"])}


def describe_run(run: Path) -> list[tuple[str, str]]:
    """``(name, what it holds)`` of each entry of a run folder: the known files (``RUN_FILES``) first, then
    the rest (a segment's folder, ``eval-<profile>.json``, ...; "" when unknown)."""
    entries = sorted(p.name + ("/" if p.is_dir() else "") for p in run.iterdir())
    ordered = [name for name in RUN_FILES if name in entries] + [n for n in entries if n not in RUN_FILES]
    return [(name, _holds(name)) for name in ordered]


def _holds(name: str) -> str:
    """What the run-folder entry ``name`` holds ("" when unknown)."""
    if name in RUN_FILES:
        return RUN_FILES[name]
    if name.startswith("segment_") and name.endswith("/"):
        return "one time segment's run folder (config, checkpoint, metrics, as above)"
    if name.startswith("eval-") and name.endswith(".json"):
        return "scores of `moegs eval` with that metric profile"
    if name == "renders/":
        return "videos and test-view strips of `moegs render`"
    return ""


def format_scores(test: dict | None) -> str:
    """``PSNR 24.13  SSIM 0.8123  LPIPS 0.1234`` of a run's test scores (LPIPS ``n/a`` with the reason
    when its weights are absent)."""
    if not test:
        return "not evaluated (the scene has no test views)"
    if test.get("lpips") is not None:
        lpips = f"{test['lpips']:.4f}"
    else:
        reason = str(test.get("lpips_unavailable") or "not computed").splitlines()[0]
        lpips = f"n/a ({reason})"
    return f"PSNR {test['psnr']:.2f}  SSIM {test['ssim']:.4f}  LPIPS {lpips}"


__all__ = [
    "ERROR_COLORMAP",
    "ERROR_GAIN",
    "RUN_FILES",
    "comparison_strip",
    "describe_run",
    "error_image",
    "format_scores",
    "loss_curves",
    "pad_even",
    "write_loss_curve",
]
