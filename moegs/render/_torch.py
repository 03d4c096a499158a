"""Pure-PyTorch reference compositing: exact, differentiable by autograd, the test oracle.

The compositing contract shared by every backend (``_composite`` here, the compiled CPU kernel in
``_cpu``, gsplat on CUDA) is:

* Gaussians are visited front to back, sorted by ``depths`` (stable: ties keep index order).
* Gaussian ``i`` is evaluated at pixel ``(x, y)`` (centre ``p = (x + 0.5, y + 0.5)``) only if
  ``radii[i] > 0`` and ``|p - means2d[i]|_inf <= radii[i]`` (bounding-box rule; tiles are only an
  acceleration and never change the result).
* ``power = -0.5 (a dx^2 + c dy^2) - b dx dy`` with ``conics[i] = (a, b, c)`` and ``d = p - mean``;
  skipped if ``power > 0``. ``alpha = min(ALPHA_MAX, opacity * exp(power))``; skipped if
  ``alpha < ALPHA_MIN``. Where the clamp is active the gradient through alpha is zero.
* Each group ``g`` (an expert in single-pass rendering) keeps its own transmittance ``T_g``
  (initially 1). If ``T_g (1 - alpha) < T_MIN`` the group is finished at this pixel and the
  Gaussian is *not* composited (3DGS convention); otherwise its weight is ``T_g alpha`` and
  ``T_g <- T_g (1 - alpha)``. A pixel stops when every group has finished.
* Outputs: ``image[g, y, x] = sum_i w_i colors[i]`` and ``alpha[g, y, x] = sum_i w_i = 1 - T_g``
  over the Gaussians of group ``g``; ``contrib[i] = sum over pixels of w_i`` (no gradient).
"""

from __future__ import annotations

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99  # original 3DGS clamp (gsplat uses 0.999); shared by every backend
T_MIN = 1e-4


def _bbox_pixels(means2d: Tensor, radii: Tensor, width: int, height: int) -> tuple[Tensor, ...]:
    """Inclusive integer pixel ranges ``x0, x1, y0, y1 [N]`` whose centres lie inside each bbox."""
    r = radii.to(means2d.dtype)
    mx, my = means2d[:, 0].detach(), means2d[:, 1].detach()
    x0 = torch.ceil(mx - r - 0.5).clamp(min=0).long()
    x1 = torch.floor(mx + r - 0.5).clamp(max=width - 1).long()
    y0 = torch.ceil(my - r - 0.5).clamp(min=0).long()
    y1 = torch.floor(my + r - 0.5).clamp(max=height - 1).long()
    return x0, x1, y0, y1


def _pairs(means2d: Tensor, radii: Tensor, width: int, height: int) -> tuple[Tensor, Tensor]:
    """All (gaussian, pixel) pairs allowed by the bounding-box rule, ``[P]`` each."""
    x0, x1, y0, y1 = _bbox_pixels(means2d, radii, width, height)
    nx, ny = (x1 - x0 + 1).clamp(min=0), (y1 - y0 + 1).clamp(min=0)
    counts = torch.where(radii > 0, nx * ny, torch.zeros_like(nx))
    gauss = torch.repeat_interleave(torch.arange(len(radii), device=radii.device), counts)
    if gauss.numel() == 0:
        empty = torch.zeros(0, dtype=torch.long, device=radii.device)
        return empty, empty
    starts = torch.cumsum(counts, 0) - counts
    local = torch.arange(gauss.numel(), device=radii.device) - starts[gauss]
    xs = x0[gauss] + local % nx[gauss]
    ys = y0[gauss] + local // nx[gauss]
    return gauss, ys * width + xs


def _composite(
    means2d: Tensor,  # [N, 2] pixel coordinates
    conics: Tensor,  # [N, 3] inverse 2D covariance (a, b, c)
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    depths: Tensor,  # [N] sort key (camera-space z)
    radii: Tensor,  # [N] int, 0 = culled
    width: int,
    height: int,
    groups: Tensor | None = None,  # [N] int64 in [0, num_groups)
    num_groups: int = 1,
) -> tuple[Tensor, Tensor, Tensor]:
    """Reference front-to-back compositing (see module docstring for the exact rule).

    Returns:
        image ``[G, H, W, D]``, alpha ``[G, H, W]``, contrib ``[N]`` (detached).
    """
    n, d = colors.shape
    hw = width * height
    groups = torch.zeros(n, dtype=torch.long, device=colors.device) if groups is None else groups.long()
    gauss, pix = _pairs(means2d, radii, width, height)

    # sort pairs by (pixel, group, depth rank): one segment per (pixel, group)
    rank = torch.empty(n, dtype=torch.long, device=colors.device)
    rank[torch.argsort(depths.detach(), stable=True)] = torch.arange(n, device=colors.device)
    segment = pix * num_groups + groups[gauss]
    order = torch.argsort(segment * max(n, 1) + rank[gauss])
    gauss, pix, segment = gauss[order], pix[order], segment[order]

    # index_select, not x[gauss]: the backward of advanced indexing on CPU adds with atomics across
    # threads (order varies run to run); index_select's backward, an index_add, sums in index order
    px = (pix % width).to(means2d.dtype) + 0.5
    py = torch.div(pix, width, rounding_mode="floor").to(means2d.dtype) + 0.5
    mean = means2d.index_select(0, gauss)
    dx, dy = px - mean[:, 0], py - mean[:, 1]
    a, b, c = conics.index_select(0, gauss).unbind(1)
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    alpha = torch.clamp(opacities.index_select(0, gauss) * torch.exp(power), max=ALPHA_MAX)
    alpha = torch.where((power > 0) | (alpha < ALPHA_MIN), torch.zeros_like(alpha), alpha)

    # segmented transmittance: float64 log-space cumsum, restarted at each segment
    log_keep = torch.log1p(-alpha.double())
    csum = torch.cumsum(log_keep, 0)
    first = torch.ones_like(segment, dtype=torch.bool)
    first[1:] = segment[1:] != segment[:-1]
    seg_id = torch.cumsum(first.long(), 0) - 1
    seg_start = torch.nonzero(first).squeeze(1)
    offset = (csum - log_keep).index_select(0, seg_start).index_select(0, seg_id)
    t_incl = torch.exp(csum - offset)
    t_excl = torch.exp(csum - log_keep - offset)
    keep = (t_incl >= T_MIN).to(alpha.dtype)
    weight = keep * alpha * t_excl.to(alpha.dtype)

    out_index = groups[gauss] * hw + pix
    image = torch.zeros(num_groups * hw, d, dtype=colors.dtype, device=colors.device)
    image = image.index_add(0, out_index, weight[:, None] * colors.index_select(0, gauss))
    acc = torch.zeros(num_groups * hw, dtype=colors.dtype, device=colors.device)
    acc = acc.index_add(0, out_index, weight)
    contrib = torch.zeros(n, dtype=colors.dtype, device=colors.device).index_add(0, gauss, weight.detach())
    return image.view(num_groups, height, width, d), acc.view(num_groups, height, width), contrib
