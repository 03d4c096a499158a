"""NeRF positional encoding (the ``get_embedder`` of NeRF / DeformableGS).

``PE_L(x) = [x, sin(2^0 x), cos(2^0 x), sin(2^1 x), cos(2^1 x), ..., sin(2^{L-1} x), cos(2^{L-1} x)]``:
each ``sin``/``cos`` block acts on the whole input vector, frequencies are powers of two (``log_sampling``),
no factor of pi. ``[..., D] -> [..., D (1 + 2L)]`` with ``include_input``
(63 for xyz at L=10, 13 for t at L=6).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def positional_encoding(x: Tensor, num_freqs: int, include_input: bool = True) -> Tensor:
    """Encode ``x [..., D]`` as ``[..., D * (int(include_input) + 2 * num_freqs)]`` (order: module doc)."""
    if num_freqs < 0:
        raise ValueError(f"num_freqs must be >= 0, got {num_freqs}")
    if x.ndim == 0:
        raise ValueError("positional_encoding needs at least one dimension [..., D]")
    freqs = 2.0 ** torch.arange(num_freqs, dtype=x.dtype, device=x.device)  # [L]
    scaled = x[..., None, :] * freqs[:, None]  # [..., L, D]
    # per frequency: sin block then cos block -> [..., L, 2, D] -> [..., 2 L D]
    periodic = torch.stack([torch.sin(scaled), torch.cos(scaled)], dim=-2).flatten(-3)
    return torch.cat([x, periodic], dim=-1) if include_input else periodic


class PositionalEncoding(nn.Module):
    """Module form of :func:`positional_encoding`; ``out_dim`` gives the encoded width."""

    def __init__(self, in_dim: int, num_freqs: int, include_input: bool = True) -> None:
        super().__init__()
        self.in_dim, self.num_freqs, self.include_input = in_dim, num_freqs, include_input
        self.out_dim = in_dim * (int(include_input) + 2 * num_freqs)

    def forward(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.in_dim:
            raise ValueError(f"PositionalEncoding expects [..., {self.in_dim}], got {list(x.shape)}")
        return positional_encoding(x, self.num_freqs, self.include_input)

    def extra_repr(self) -> str:
        return f"in_dim={self.in_dim}, num_freqs={self.num_freqs}, out_dim={self.out_dim}"
