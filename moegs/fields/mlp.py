"""Small MLP building blocks shared by the deformation networks.

* :func:`mlp` - ``Linear`` layers with ReLU between them (optionally a leading / trailing ReLU).
* :class:`SkipMLP` - NeRF-style trunk whose input is concatenated again after chosen layers
  (DeformableGS: 8 x 256, skip after layer 4).
* :class:`Heads` - named output heads on a shared feature, returning a dict.
* :func:`xavier_weights_` - Xavier-uniform weights, biases left at the PyTorch default (4DGaussians).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn


def mlp(dims: Sequence[int], *, relu_first: bool = False, relu_last: bool = False) -> nn.Sequential:
    """``Linear(dims[0], dims[1]) - ReLU - ... - Linear(dims[-2], dims[-1])``.

    Args:
        dims: layer widths, at least two (input and output).
        relu_first: put a ReLU before the first ``Linear`` (4DGaussians heads act on a pre-activation).
        relu_last: end with a ReLU.
    """
    if len(dims) < 2:
        raise ValueError(f"mlp needs at least an input and an output width, got {list(dims)}")
    layers: list[nn.Module] = [nn.ReLU()] if relu_first else []
    for k, (d_in, d_out) in enumerate(zip(dims[:-1], dims[1:], strict=True)):
        layers.append(nn.Linear(d_in, d_out))
        if k < len(dims) - 2 or relu_last:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class SkipMLP(nn.Module):
    """``depth`` Linear+ReLU layers of width ``width``; after layer ``i`` in ``skips`` the input is
    concatenated again as ``[input, h]`` (so layer ``i + 1`` takes ``in_dim + width``).

    Shapes: ``x [..., in_dim] -> [..., width]``.
    """

    def __init__(self, in_dim: int, width: int, depth: int, skips: Sequence[int] = ()) -> None:
        super().__init__()
        if depth < 1:
            raise ValueError(f"SkipMLP needs depth >= 1, got {depth}")
        bad = [s for s in skips if not 0 <= s < depth - 1]
        if bad:
            raise ValueError(f"SkipMLP skips must lie in [0, {depth - 2}], got {bad}")
        self.in_dim, self.width, self.skips = in_dim, width, tuple(skips)
        self.layers = nn.ModuleList(
            nn.Linear(in_dim if i == 0 else width + (in_dim if i - 1 in self.skips else 0), width)
            for i in range(depth)
        )

    def forward(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.in_dim:
            raise ValueError(f"SkipMLP expects [..., {self.in_dim}], got {list(x.shape)}")
        h = x
        for i, layer in enumerate(self.layers):
            h = torch.relu(layer(h))
            if i in self.skips:
                h = torch.cat([x, h], dim=-1)
        return h


class Heads(nn.Module):
    """Named heads on one feature ``h [..., in_dim]``; ``forward`` returns ``{name: [..., out_dim]}``.

    Args:
        in_dim: width of the shared feature.
        outputs: ``{name: out_dim}`` in output order.
        hidden: widths of hidden layers inside each head (``()`` = a single ``Linear``).
        relu_first: start each head with a ReLU (4DGaussians).
    """

    def __init__(
        self, in_dim: int, outputs: Mapping[str, int], hidden: Sequence[int] = (), relu_first: bool = False
    ) -> None:
        super().__init__()
        if not outputs:
            raise ValueError("Heads needs at least one output")
        self.heads = nn.ModuleDict(
            {name: mlp([in_dim, *hidden, dim], relu_first=relu_first) for name, dim in outputs.items()}
        )

    def forward(self, h: Tensor) -> dict[str, Tensor]:
        return {name: head(h) for name, head in self.heads.items()}


def xavier_weights_(module: nn.Module) -> nn.Module:
    """Xavier-uniform (gain 1) on every ``Linear`` weight below ``module``; biases untouched."""
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.xavier_uniform_(m.weight)
    return module
