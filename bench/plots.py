"""Matplotlib figures (Agg, PNG): paper-vs-ours bars for every table, and the figure specs' plots.

Every plot function takes the spec's ``SpecValues`` and an output folder and returns the files it
wrote (empty when there is nothing of ours to draw: a figure is never drawn from paper numbers
alone). Figures that need arrays (best-expert maps, gate maps, trajectories) read the ``.npz`` files
their cells wrote next to their result JSON.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bench.values import AVERAGE, MEAN, STAND_IN, SpecValues  # noqa: E402
from moegs.atomic import atomic_path  # noqa: E402

OURS, PAPER = "#1f77b4", "#9e9e9e"


def save_figure(fig: Any, path: Path, tight: bool = True) -> Path:
    """Write ``fig`` to ``path`` at 110 dpi (``tight``: cropped to its content) through a temporary file,
    so an interrupted render leaves no broken image; the figure is closed."""
    try:
        with atomic_path(path) as tmp:
            crop = {"bbox_inches": "tight"} if tight else {}
            fig.savefig(tmp, dpi=110, format=path.suffix.lstrip("."), **crop)
    finally:
        plt.close(fig)
    return path


def _row_files(values: SpecValues, row: str, name: str) -> list[Path]:
    """``name`` files written by the row's ok slots (first seed), in scene order."""
    out = []
    for slot in values.plan.slots_of(row):
        res = values.results.result(slot)
        if res is not None and res["status"] == "ok" and name in res.get("files", {}):
            out.append(values.results.workspace.files_dir(slot.task) / name)
    return out


def paper_vs_ours(values: SpecValues, out_dir: Path) -> list[Path]:
    """One panel per computed column (at most 4): ours next to the paper's value for every row."""
    spec = values.spec
    if spec.axis == "none":
        return []
    cols = [
        c
        for c in values.display_columns
        if c != AVERAGE
        and any(
            values.cells.get((r.name, c, m)) and values.cells[(r.name, c, m)].value is not None
            for r in spec.rows
            for m in values.metrics_of(c)
        )
    ][:4]
    panels = [(c, m) for c in cols for m in values.metrics_of(c)][:6]
    if not panels:
        return []
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), squeeze=False)
    for ax, (col, m) in zip(axes[0], panels, strict=False):
        rows = [r for r in spec.rows if values.cells.get((r.name, col, m)) is not None]
        paper_col = AVERAGE if col == STAND_IN else col
        ours = [values.cells[(r.name, col, m)].value for r in rows]
        paper = [values.paper.get(r.name, paper_col, m) for r in rows]
        x = np.arange(len(rows))
        ax.bar(x - 0.2, [p if p is not None else 0 for p in paper], 0.4, color=PAPER, label="paper")
        vals = [v for v in ours + paper if v is not None]
        lo, hi = (min(vals), max(vals)) if vals else (0.0, 1.0)
        bottom = 0.0 if lo <= 0 or lo < 0.7 * hi else lo - 0.25 * (hi - lo + 1e-9)
        for xi, row, o in zip(x, rows, ours, strict=True):
            if o is None:
                ax.text(xi + 0.2, bottom, " n/a", ha="center", va="bottom", fontsize=7, rotation=90)
                continue
            hatch = None if values.cells[(row.name, col, m)].comparable else "//"
            ax.bar(xi + 0.2, o, 0.4, color=OURS, hatch=hatch, label="ours" if xi == x[0] else None)
        ax.set_ylim(bottom, hi + 0.08 * (hi - bottom + 1e-9))
        ax.set_xticks(x, [r.display for r in rows], rotation=35, ha="right", fontsize=7)
        ref = f"paper: {paper_col}" if col == STAND_IN else "paper"
        ax.set_title(f"{m} - {col}" + (" (synthetic stand-in)" if col == STAND_IN else ""), fontsize=9)
        ax.legend(fontsize=6, title=ref, title_fontsize=6, loc="best", framealpha=0.6)
    fig.suptitle(f"{spec.id}: {spec.title} (hatched: not comparable, stand-in or subset)", fontsize=9)
    return [save_figure(fig, out_dir / f"{spec.id}_paper_vs_ours.png")]


def limitations(values: SpecValues, out_dir: Path) -> list[Path]:
    """Fig. 1: (a) per-scene PSNR of the experts, (b) per-pixel best expert, (c) best expert over time."""
    out = paper_vs_ours(values, out_dir)
    files = _row_files(values, "Best-expert analysis", "bestmap.npz")
    if not files:
        return out
    data = np.load(files[0])
    names = list(data["experts"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].imshow(data["gt"])
    axes[0].set_title(f"ground truth ({data['view']})", fontsize=9)
    cmap = plt.get_cmap("tab10", len(names))
    im = axes[1].imshow(data["winner"], cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5)
    cbar = fig.colorbar(im, ax=axes[1], ticks=range(len(names)))
    cbar.ax.set_yticklabels(names, fontsize=7)
    axes[1].set_title("(b) best expert per pixel (lowest L1)", fontsize=9)
    dynamic = "psnr_dynamic" in data and len(data["psnr_dynamic"]) == len(data["times"])
    curves = data["psnr_dynamic"] if dynamic else data["psnr"]
    for k, name in enumerate(names):
        axes[2].plot(data["times"], curves[:, k], marker="o", ms=3, label=name, color=cmap(k))
    axes[2].set_xlabel("normalised time")
    axes[2].set_ylabel("PSNR (dB)")
    region = "dynamic-region" if dynamic else "full-image"
    axes[2].set_title(f"(c) per-frame {region} PSNR of each expert", fontsize=9)
    axes[2].legend(fontsize=7)
    for ax in axes[:2]:
        ax.axis("off")
    out.append(save_figure(fig, out_dir / f"{values.spec.id}_spatial_temporal.png"))
    return out


def gates(values: SpecValues, out_dir: Path) -> list[Path]:
    """Gate maps, expert renders and the blend of the gates cell."""
    files = _row_files(values, values.spec.rows[0].name, "gates.npz")
    if not files:
        return []
    d = np.load(files[0])
    k = d["gates"].shape[0]
    fig, axes = plt.subplots(2, k + 1, figsize=(3.2 * (k + 1), 6))
    for i in range(k):
        axes[0, i].imshow(d["expert_images"][i])
        axes[0, i].set_title(f"expert {d['experts'][i]}", fontsize=9)
        axes[1, i].imshow(d["gates"][i], vmin=0, vmax=1, cmap="viridis")
        axes[1, i].set_title(f"gate {d['experts'][i]}", fontsize=9)
    axes[0, k].imshow(d["image"])
    axes[0, k].set_title("MoE-GS blend", fontsize=9)
    axes[1, k].imshow(d["gt"])
    axes[1, k].set_title("ground truth", fontsize=9)
    for ax in axes.flat:
        ax.axis("off")
    return [save_figure(fig, out_dir / f"{values.spec.id}.png")]


def trajectories(values: SpecValues, out_dir: Path) -> list[Path]:
    """Trajectories (x-y projection of the most moving Gaussians) per row, plus the statistics."""
    rows = [(r, _row_files(values, r.name, "trajectories.npz")) for r in values.spec.rows]
    rows = [(r, f[0]) for r, f in rows if f]
    if not rows:
        return []
    fig, axes = plt.subplots(1, len(rows), figsize=(3.6 * len(rows), 3.6), squeeze=False)
    for ax, (row, path) in zip(axes[0], rows, strict=True):
        d = np.load(path)
        means = d["means"][:, :64]  # [T, K, 3]
        for j in range(means.shape[1]):
            ax.plot(means[:, j, 0], means[:, j, 1], lw=0.8)
            ax.plot(means[-1, j, 0], means[-1, j, 1], ".", ms=2, color="k")
        ax.set_title(row.display, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=6)
    out = [save_figure(fig, out_dir / f"{values.spec.id}.png")]
    return out + paper_vs_ours(values, out_dir)


def mdc(values: SpecValues, out_dir: Path) -> list[Path]:
    """MDC per row and scene (lower is better)."""
    return paper_vs_ours(values, out_dir)


PLOTS: dict[str, Callable[[SpecValues, Path], list[Path]]] = {
    "paper_vs_ours": paper_vs_ours,
    "limitations": limitations,
    "gates": gates,
    "trajectories": trajectories,
    "mdc": mdc,
}


def plot_spec(values: SpecValues, out_dir: Path) -> list[Path]:
    """All figures of a spec."""
    if values.spec.plot not in PLOTS:
        raise KeyError(f"{values.spec.id}: unknown plot {values.spec.plot!r}; valid: {', '.join(PLOTS)}")
    return PLOTS[values.spec.plot](values, out_dir)


__all__ = ["MEAN", "PLOTS", "plot_spec"]
