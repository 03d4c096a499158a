"""PSNR, full-image and mask-normalised (ROI)."""

from __future__ import annotations

import torch
from torch import Tensor

from moegs.metrics._images import as_batch, mask_as_batch, unbatch


def psnr(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    r"""Peak signal-to-noise ratio of images in [0, 1], one value per image.

    .. math:: \mathrm{PSNR} = 20 \log_{10}\left(1 / \sqrt{\mathrm{MSE}}\right)

    With ``mask`` the MSE is ``sum(mask * (pred - target)^2) / sum(mask)`` over pixels *and* channels
    (a ``[H, W]`` mask counts once per channel), the MoE-GS ``utils/image_utils.py::m_psnr`` ROI form.
    Average per-image values over frames yourself (the papers' convention), not the MSEs.

    Args:
        pred: rendered image ``[H, W, C]`` or ``[B, H, W, C]``, float; not clamped here.
        target: ground truth, same shape.
        mask: optional ``[H, W]``, ``[H, W, 1]`` or ``[H, W, C]`` (leading ``B`` when batched),
            bool or soft weights.

    Returns:
        0-dim tensor for one image, ``[B]`` for a batch. ``inf`` for identical images, ``nan`` for
        an empty mask.

    Examples:
        >>> x = torch.full((4, 4, 3), 0.5)
        >>> round(psnr(x, x + 0.1).item(), 4)
        20.0
    """
    x, y, batched = as_batch(pred, target, "psnr")
    err = (x - y).square()
    if mask is None:
        mse = err.mean(dim=(1, 2, 3))
    else:
        m = mask_as_batch(mask, x, batched, "psnr")
        mse = (err * m).sum(dim=(1, 2, 3)) / m.sum(dim=(1, 2, 3))
    return unbatch(20.0 * torch.log10(1.0 / torch.sqrt(mse)), batched)
