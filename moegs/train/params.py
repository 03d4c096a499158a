"""Optimiser groups as the experts declare them (``Expert.param_groups``) and the optimiser builds them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from torch import Tensor


@dataclass
class ParamGroup:
    """One optimiser group: a name, its tensors, the learning rate and an optional schedule.

    ``lr_final`` / ``lr_delay_steps`` / ``lr_delay_mult`` / ``max_steps`` parameterise the 3DGS
    exponential schedule (``moegs.train.schedules``); ``lr_final=None`` keeps the rate constant.
    ``optimizer`` is ``"adam"`` (every 3DGS-lineage method) or ``"radam"``. A per-Gaussian tensor
    (an entry of ``Expert.splats``) must sit in exactly one group so that densification can keep its
    optimiser state in step.
    """

    name: str
    params: list[Tensor]
    lr: float
    lr_final: float | None = None
    lr_delay_steps: int = 0
    lr_delay_mult: float = 1.0
    max_steps: int = 30_000
    eps: float = 1e-15
    optimizer: str = "adam"
    start_step: int = 0
    """Iteration at which the schedule starts (its step 0), e.g. the first step of a later stage."""
    second_set: Callable[[], Tensor] | None = None
    """Which rows ``[N]`` of each tensor belong to a second set of Gaussians that counts its own optimiser
    steps (``moegs.train.set_optim``; Ex4DGS's dynamic set); None: one set."""
    second_lr: float | None = None
    """Constant rate of the second set's rows (None: the group's, scheduled with it)."""

    def __post_init__(self) -> None:
        if self.second_lr is not None and (self.second_set is None or self.lr_final is not None):
            raise ValueError(
                f"param group {self.name!r}: second_lr needs a second_set and a constant lr (lr_final=None)"
            )
