"""Photometric losses of the 3DGS lineage: L1, D-SSIM (3DGS SSIM) and their weighted sum.

Images are channels-last ``[H, W, C]`` (as ``rasterize`` returns them).
"""

from __future__ import annotations

from torch import Tensor

from moegs.metrics import ssim


def l1(pred: Tensor, target: Tensor) -> Tensor:
    """Mean absolute error, 0-dim."""
    if pred.shape != target.shape:
        raise ValueError(f"l1: pred {list(pred.shape)} and target {list(target.shape)} differ")
    return (pred - target).abs().mean()


def dssim(pred: Tensor, target: Tensor) -> Tensor:
    """``1 - SSIM`` with the 3DGS SSIM (11x11 Gaussian window, sigma 1.5, zero padding), 0-dim.

    3DGS-lineage code calls ``1 - ssim`` "D-SSIM" (without the usual halving); so do we.
    """
    return 1.0 - ssim(pred, target, variant="3dgs")


def photometric(pred: Tensor, target: Tensor, lambda_dssim: float) -> Tensor:
    """``(1 - lambda) * L1 + lambda * (1 - SSIM)`` (3DGS ``train.py``); ``lambda = 0`` skips SSIM."""
    if not 0.0 <= lambda_dssim <= 1.0:
        raise ValueError(f"lambda_dssim must be in [0, 1], got {lambda_dssim}")
    loss = l1(pred, target)
    if lambda_dssim == 0.0:
        return loss
    return (1.0 - lambda_dssim) * loss + lambda_dssim * dssim(pred, target)
