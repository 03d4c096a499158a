"""Densification strategy contract (gsplat style): a dataclass of hyperparameters plus an explicit
state dict, stepped around backward by the training loop.

Per iteration the loop calls, with the 1-based iteration ``step`` (3DGS ``iteration``)::

    strategy.step_pre_backward(params, optimizers, state, step, info)
    loss.backward()
    strategy.step_post_backward(params, optimizers, state, step, info)   # 3DGS densifies here,
    optimizers.step()                                                      # before the optimiser step
    strategy.step_post_optimizer(params, optimizers, state, step, info)  # 3DGS-MCMC noise

``params`` is ``expert.splats``; ``optimizers`` maps its keys to optimisers
(``Optimizers.for_splats``); ``info`` holds

* ``"renders"``: one dict per rendered view of the batch with ``radii [N]`` (int32), ``visible [N]``,
  ``means2d [N, 2]`` (pixels; ``.grad`` after backward), ``width``, ``height`` (only when
  ``needs_render_stats``).

The current learning rate of a tensor is ``optimizers[key].param_groups[0]["lr"]``.

The state holds only plain values and tensors so that checkpoints can save it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

NEVER = 10**9
"""An iteration no run reaches (a schedule event that never happens, e.g. E-D3DGS's 6e6 reset interval)."""


@dataclass
class Strategy:
    """Base class: hyperparameters as dataclass fields; no mutable attributes."""

    needs_render_stats = False
    """Whether the loop must render with ``return_stats=True`` and keep ``means2d`` gradients."""
    needs_views = False
    """Whether ``info["views"]`` must hold each view's ``camera``, ``rgb`` (detached) and ``target``."""

    def initialize_state(self, scene_scale: float, white_background: bool = False) -> dict[str, Any]:
        """A fresh state; ``scene_scale`` is the scene extent (3DGS ``cameras_extent``)."""
        return {"scene_scale": float(scene_scale), "white_background": bool(white_background)}

    def check_sanity(self, params: nn.ParameterDict, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        """Raise ``ValueError`` when a trainable per-Gaussian tensor has no optimiser."""
        for key in ("means", "scales", "quats", "opacities"):
            if key not in params:
                raise ValueError(
                    f"{type(self).__name__} needs splats[{key!r}]; the expert has {list(params)}"
                )
        missing = [k for k, p in params.items() if p.requires_grad and k not in optimizers]
        if missing:
            raise ValueError(f"{type(self).__name__}: splats {missing} have no optimiser")

    def step_pre_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        """Before ``loss.backward()`` (default: nothing)."""

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        """After ``loss.backward()``, before the optimiser step (default: nothing)."""

    def step_post_optimizer(self, params, optimizers, state, step: int, info: dict) -> None:
        """After the optimiser step (default: nothing)."""
