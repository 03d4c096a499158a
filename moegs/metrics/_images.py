"""Shape checks shared by the image metrics.

Convention for every public metric: images are channels-last floats in [0, 1], either one image
``[H, W, C]`` (the layout ``rasterize`` returns) or a batch ``[B, H, W, C]``. A single image gives a
0-dim result, a batch gives one value per image ``[B]``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def as_batch(pred: Tensor, target: Tensor, fn: str) -> tuple[Tensor, Tensor, bool]:
    """Check ``pred``/``target`` and return them as ``[B, H, W, C]`` plus whether the input was batched."""
    for name, img in (("pred", pred), ("target", target)):
        if not isinstance(img, Tensor):
            raise TypeError(f"{fn}: `{name}` must be a torch.Tensor, got {type(img).__name__}")
        if img.ndim not in (3, 4):
            raise ValueError(
                f"{fn}: `{name}` must have shape [H, W, C] or [B, H, W, C], got {list(img.shape)}"
            )
        if not img.is_floating_point():
            raise TypeError(f"{fn}: `{name}` must be a floating-point tensor in [0, 1], got {img.dtype}")
    if pred.shape != target.shape:
        raise ValueError(
            f"{fn}: `pred` and `target` must have the same shape, "
            f"got {list(pred.shape)} and {list(target.shape)}"
        )
    batched = pred.ndim == 4
    if not batched:
        pred, target = pred.unsqueeze(0), target.unsqueeze(0)
    return pred, target, batched


def mask_as_batch(mask: Tensor, like: Tensor, batched: bool, fn: str) -> Tensor:
    """Broadcast a mask to ``like`` ``[B, H, W, C]``.

    Accepted: ``[H, W]``, ``[H, W, 1]``, ``[H, W, C]`` for a single image, the same with a leading
    ``B`` for a batch. Bool or float (soft weights) masks.
    """
    b, h, w, c = like.shape
    if not isinstance(mask, Tensor):
        raise TypeError(f"{fn}: `mask` must be a torch.Tensor, got {type(mask).__name__}")
    m = mask if batched else mask.unsqueeze(0)
    if m.ndim == 3:
        m = m.unsqueeze(-1)
    lead = "[B, H, W], [B, H, W, 1] or [B, H, W, C]" if batched else "[H, W], [H, W, 1] or [H, W, C]"
    shown = list(like.shape if batched else like.shape[1:])
    if m.ndim != 4 or m.shape[:3] != (b, h, w) or m.shape[3] not in (1, c):
        raise ValueError(
            f"{fn}: `mask` must have shape {lead} matching `pred` {shown}, got {list(mask.shape)}"
        )
    return m.to(like.dtype).expand(b, h, w, c)


def unbatch(values: Tensor, batched: bool) -> Tensor:
    """``[B]`` values back to the caller's layout: ``[B]`` if batched, else 0-dim."""
    return values if batched else values[0]


def to_bchw(img: Tensor) -> Tensor:
    """``[B, H, W, C]`` -> ``[B, C, H, W]`` (a view)."""
    return img.permute(0, 3, 1, 2)


def quantize_u8(img: Tensor) -> Tensor:
    """Round to the 8-bit grid as PNG saving does (``floor(255 x + 0.5)``, clamped), back to float."""
    return torch.floor(img.clamp(0.0, 1.0) * 255.0 + 0.5) / 255.0
