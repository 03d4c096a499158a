"""Gate-map pictures: which expert wins where, and how strongly each expert is weighted.

winner_map(out.gates)          # [H, W, 3] uint8: the winning expert's colour, shaded by its gate
weight_map(out.gates[k])       # [H, W, 3] uint8: expert k's gate through a colour map
save_gate_figure(path, out, target, names)   # one panel: GT | MoE | experts | winners | weights
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [140, 86, 75]],
    dtype=np.float32,
)
"""Expert colours (matplotlib tab10), expert k gets ``PALETTE[k % 6]``."""


def winner_map(gates: Tensor) -> np.ndarray:
    """``gates [K, H, W]`` -> ``[H, W, 3]`` uint8: each pixel in its winning expert's colour, blended
    towards white as the winning gate falls to ``1/K`` (a uniform blend is white)."""
    k = gates.shape[0]
    top, winner = gates.detach().cpu().max(0)
    strength = ((top - 1.0 / k) / max(1.0 - 1.0 / k, 1e-12)).clamp(0, 1).numpy()[..., None]
    colour = PALETTE[winner.numpy() % len(PALETTE)]
    return (strength * colour + (1 - strength) * 255.0).round().astype(np.uint8)


def weight_map(gate: Tensor, cmap: str = "viridis") -> np.ndarray:
    """``gate [H, W]`` in [0, 1] -> ``[H, W, 3]`` uint8 through a matplotlib colour map."""
    from matplotlib import colormaps

    rgba = colormaps[cmap](gate.detach().cpu().clamp(0, 1).numpy())
    return (rgba[..., :3] * 255).round().astype(np.uint8)


def to_u8(image: Tensor) -> np.ndarray:
    """``[H, W, 3]`` float in [0, 1] -> uint8."""
    return (image.detach().cpu().clamp(0, 1) * 255).round().to(torch.uint8).numpy()


def save_gate_figure(
    path: str | Path, out, target: Tensor | None, names: Sequence[str], title: str = ""
) -> Path:
    """One figure: ground truth, the MoE image, each expert's image, the winner map and each expert's
    gate map (``out`` is a ``MoERender``). Written as PNG; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = out.gates.shape[0]
    panels = ([("ground truth", to_u8(target))] if target is not None else []) + [
        ("MoE-GS", to_u8(out.image))
    ]
    panels += [(f"expert {n}", to_u8(img)) for n, img in zip(names, out.expert_images, strict=True)]
    panels += [("winner", winner_map(out.gates))]
    panels += [(f"gate {n}", weight_map(out.gates[i])) for i, n in enumerate(names)]
    cols = 3 + k if target is not None else 2 + k
    rows = 2
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 2.4 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    first_row = 2 + k if target is not None else 1 + k
    for i, (label, image) in enumerate(panels[:first_row]):
        axes[0, i].imshow(image)
        axes[0, i].set_title(label, fontsize=8)
    for i, (label, image) in enumerate(panels[first_row:]):
        axes[1, i].imshow(image)
        axes[1, i].set_title(
            label, fontsize=8, color=tuple(PALETTE[(i - 1) % len(PALETTE)] / 255) if i else "k"
        )
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
