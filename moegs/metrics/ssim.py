"""SSIM with named variants; the differences move the third decimal (see ``SSIM_VARIANTS``).

All variants use a Gaussian window of 11 taps, sigma 1.5, ``C1 = 0.01^2``, ``C2 = 0.03^2`` (data
range 1) and average over channels; they differ only at the image border and in variance clipping.
Away from the border (5 px) the "3dgs", "valid" and "reflect" maps are identical.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from moegs.metrics._images import as_batch, mask_as_batch, to_bchw, unbatch

WINDOW = 11
SIGMA = 1.5
C1 = 0.01**2
C2 = 0.03**2
_HALF = WINDOW // 2

SSIM_VARIANTS: dict[str, str] = {
    "3dgs": "Gaussian 11x11/1.5, zero-padded 'same' conv, mean over the full map including borders, "
    "no clipping (graphdeco 3DGS utils/loss_utils.py; used by MoE-GS and most dynamic-GS codes). Default.",
    "valid": "Gaussian 11x11/1.5, valid conv (5 px border cropped), variances clipped at 0: the interior "
    "skimage keeps. pytorch_msssim takes the same window unclipped; dm_pix floors the variances at eps^2 "
    "and clamps the covariance to their geometric mean.",
    "reflect": "kornia.metrics.ssim: Gaussian 11x11/1.5, reflect-padded 'same' conv, mean over the full map.",
    "skimage": "skimage structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, "
    "data_range=1): reflect-filtered then 5 px crop; numpy, not differentiable, for cross-checks.",
}


def _check_variant(variant: str, fn: str) -> None:
    if variant not in SSIM_VARIANTS:
        valid = ", ".join(repr(v) for v in SSIM_VARIANTS)
        raise ValueError(f"{fn}: unknown SSIM variant {variant!r}; valid variants: {valid}")


def _check_size(x: Tensor, fn: str) -> None:
    h, w = x.shape[1:3]
    if h < WINDOW or w < WINDOW:
        raise ValueError(f"{fn}: images must be at least {WINDOW}x{WINDOW} pixels, got {h}x{w}")


def _gaussian_1d(device: torch.device, dtype: torch.dtype) -> Tensor:
    """Normalised 1-D Gaussian ``[WINDOW]``."""
    x = torch.arange(WINDOW, dtype=torch.float64, device="cpu") - _HALF
    g = torch.exp(-(x**2) / (2.0 * SIGMA**2))
    return (g / g.sum()).to(device=device, dtype=dtype)


def _local_moments(x: Tensor, y: Tensor, pad: int) -> tuple[Tensor, ...]:
    """Gaussian-filtered ``x, y, x^2, y^2, xy`` of ``[B, C, H, W]`` images, zero padding ``pad``."""
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    ch = stack.shape[1]
    g = _gaussian_1d(x.device, x.dtype)
    out = F.conv2d(stack, g.view(1, 1, WINDOW, 1).expand(ch, 1, WINDOW, 1), padding=(pad, 0), groups=ch)
    out = F.conv2d(out, g.view(1, 1, 1, WINDOW).expand(ch, 1, 1, WINDOW), padding=(0, pad), groups=ch)
    return out.chunk(5, dim=1)


def _ssim_from_moments(
    mu_x: Tensor, mu_y: Tensor, exx: Tensor, eyy: Tensor, exy: Tensor, clip: bool
) -> Tensor:
    var_x = exx - mu_x * mu_x
    var_y = eyy - mu_y * mu_y
    cov = exy - mu_x * mu_y
    if clip:
        var_x, var_y = var_x.clamp_min(0.0), var_y.clamp_min(0.0)
    num = (2.0 * mu_x * mu_y + C1) * (2.0 * cov + C2)
    den = (mu_x * mu_x + mu_y * mu_y + C1) * (var_x + var_y + C2)
    return num / den


def _map_bchw(x: Tensor, y: Tensor, variant: str) -> Tensor:
    """SSIM map ``[B, C, H', W']`` for the torch variants."""
    if variant == "3dgs":
        return _ssim_from_moments(*_local_moments(x, y, _HALF), clip=False)
    if variant == "valid":
        return _ssim_from_moments(*_local_moments(x, y, 0), clip=True)
    import kornia  # "reflect"; imported lazily to keep `import moegs.metrics` light

    return kornia.metrics.ssim(x, y, WINDOW, max_val=1.0, padding="same")


def ssim_map(pred: Tensor, target: Tensor, variant: str = "3dgs") -> Tensor:
    """Per-pixel, per-channel SSIM map (differentiable).

    Args:
        pred: ``[H, W, C]`` or ``[B, H, W, C]`` float in [0, 1].
        target: same shape.
        variant: "3dgs", "valid" or "reflect" ("skimage" has no map here; use ``ssim``).

    Returns:
        ``[H', W', C]`` or ``[B, H', W', C]``; ``H' = H`` except ``H - 10`` for "valid".
    """
    _check_variant(variant, "ssim_map")
    if variant == "skimage":
        raise ValueError("ssim_map: variant 'skimage' has no torch map; use ssim(..., variant='skimage')")
    x, y, batched = as_batch(pred, target, "ssim_map")
    _check_size(x, "ssim_map")
    out = _map_bchw(to_bchw(x), to_bchw(y), variant).permute(0, 2, 3, 1)
    return out if batched else out[0]


def _ssim_skimage(x: Tensor, y: Tensor) -> Tensor:
    """skimage reference, ``[B, H, W, C]`` -> ``[B]`` (float64 numpy under the hood)."""
    from skimage.metrics import structural_similarity

    xs = x.detach().cpu().double().numpy()
    ys = y.detach().cpu().double().numpy()
    values = [
        structural_similarity(
            yi,
            xi,
            channel_axis=-1,
            gaussian_weights=True,
            sigma=SIGMA,
            use_sample_covariance=False,
            data_range=1.0,
        )
        for xi, yi in zip(xs, ys, strict=True)
    ]
    return torch.tensor(values, dtype=x.dtype, device=x.device)


def ssim(pred: Tensor, target: Tensor, variant: str = "3dgs", mask: Tensor | None = None) -> Tensor:
    r"""Structural similarity, one value per image (mean of the SSIM map over pixels and channels).

    .. math::
        \mathrm{SSIM} = \frac{(2\mu_x\mu_y + C_1)(2\sigma_{xy} + C_2)}
                             {(\mu_x^2 + \mu_y^2 + C_1)(\sigma_x^2 + \sigma_y^2 + C_2)}

    Args:
        pred: ``[H, W, C]`` or ``[B, H, W, C]`` float in [0, 1], at least 11x11.
        target: same shape.
        variant: one of ``SSIM_VARIANTS`` ("3dgs" default, the paper's code and the training D-SSIM).
        mask: optional ``[H, W]``/``[H, W, 1]``/``[H, W, C]`` (leading ``B`` when batched) weights; the
            result is the mask-weighted mean of the map ("valid" crops the mask by 5 px to match).
            Not supported for "skimage".

    Returns:
        0-dim tensor for one image, ``[B]`` for a batch. Differentiable except "skimage".

    Examples:
        >>> x = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
        >>> round(ssim(x, x).item(), 6)
        1.0
    """
    _check_variant(variant, "ssim")
    x, y, batched = as_batch(pred, target, "ssim")
    _check_size(x, "ssim")
    if variant == "skimage":
        if mask is not None:
            raise ValueError("ssim: variant 'skimage' does not take a mask")
        return unbatch(_ssim_skimage(x, y), batched)
    smap = _map_bchw(to_bchw(x), to_bchw(y), variant).permute(0, 2, 3, 1)
    if mask is None:
        return unbatch(smap.mean(dim=(1, 2, 3)), batched)
    m = mask_as_batch(mask, x, batched, "ssim")
    if variant == "valid":
        m = m[:, _HALF:-_HALF, _HALF:-_HALF, :]
    return unbatch((smap * m).sum(dim=(1, 2, 3)) / m.sum(dim=(1, 2, 3)), batched)


class SSIM(nn.Module):
    """Module form of ``ssim``; ``1 - SSIM(variant="3dgs")`` is the D-SSIM training loss term."""

    def __init__(self, variant: str = "3dgs") -> None:
        super().__init__()
        _check_variant(variant, "SSIM")
        self.variant = variant

    def forward(self, pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
        return ssim(pred, target, self.variant, mask)

    def extra_repr(self) -> str:
        return f"variant={self.variant!r}"
