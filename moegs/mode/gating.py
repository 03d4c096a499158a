"""MoDE temporal gating: per-Gaussian weight spline, top-k softmax, random warm-up (paper Sec. "Temporal
Gating via Weight Spline"; authors' code ``interpolate_cubic_hermite`` and ``gating``).

    w = weight_spline(control, t)            # control [N, N_w, G] -> [N, G] unnormalised scores
    g = top_k_gates(w, k=2)                  # [N, G], zero outside each Gaussian's top-k, rows sum to 1
"""

from __future__ import annotations

import torch
from torch import Tensor


def weight_spline(control: Tensor, t: float) -> Tensor:
    """Cubic Hermite spline through ``N_w`` uniformly spaced control points at normalised time ``t``.

    Time ``t in [0, 1]`` is scaled by ``N_w - 1``; the segment index is clamped to ``[0, N_w - 2]``.
    Tangents are Catmull-Rom, ``m_k = (p_{k+1} - p_{k-1}) / 2``, one-sided ``p_1 - p_0`` and
    ``p_{N-1} - p_{N-2}`` at the ends (code). ``control [N, N_w, G]`` -> ``[N, G]``.
    """
    n_w = control.shape[1]
    if control.ndim != 3 or n_w < 2:
        raise ValueError(f"weight_spline needs control points [N, N_w >= 2, G], got {list(control.shape)}")
    x = min(max(float(t), 0.0), 1.0) * (n_w - 1)
    k = min(int(x), n_w - 2)
    d = x - k
    p0, p1 = control[:, k], control[:, k + 1]
    m0 = (p1 - control[:, k - 1]) / 2 if k > 0 else p1 - p0
    m1 = (control[:, k + 2] - p0) / 2 if k + 2 < n_w else p1 - p0
    d2, d3 = d * d, d * d * d
    h00, h10, h01, h11 = 2 * d3 - 3 * d2 + 1, d3 - 2 * d2 + d, -2 * d3 + 3 * d2, d3 - d2
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1


def top_k_gates(scores: Tensor, k: int, std_normalize: bool = False) -> Tensor:
    """Sparse gates ``[N, E]``: softmax over each row's ``k`` largest scores, zero elsewhere.

    ``std_normalize`` first divides each row by its unbiased standard deviation across experts (clamped
    at 1e-6): the authors' code does this; the paper does not mention it. With E = 2 it fixes the
    normalised gap at sqrt(2), so the gates are always about 0.80 / 0.20.
    """
    e = scores.shape[-1]
    if not 1 <= k <= e:
        raise ValueError(f"top-k must be in 1..{e} experts, got {k}")
    if std_normalize and e > 1:
        scores = scores / scores.std(dim=-1, keepdim=True).clamp_min(1e-6)
    top, index = scores.topk(k, dim=-1)
    return torch.zeros_like(scores).scatter(-1, index, torch.softmax(top, dim=-1))


def warmup_scores(n: int, e: int, like: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """Random scores ``softmax(randn) [n, e]`` drawn afresh per Gaussian and step (code's warm-up)."""
    noise = torch.randn(n, e, generator=generator, dtype=like.dtype, device=like.device)
    return torch.softmax(noise, dim=-1)
