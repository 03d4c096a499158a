"""Learning-rate schedules.

The 3DGS exponential schedule (``utils/general_utils.py::get_expon_lr_func`` in graphdeco 3DGS and
every method built on it): log-linear interpolation from ``lr_init`` to ``lr_final`` over
``max_steps``, held at ``lr_final`` afterwards, optionally multiplied during the first
``delay_steps`` by a sine ramp from ``delay_mult`` to 1.
"""

from __future__ import annotations

import math

from moegs.train.params import ParamGroup


def expon_lr(
    step: int, lr_init: float, lr_final: float, max_steps: int, delay_steps: int = 0, delay_mult: float = 1.0
) -> float:
    """The 3DGS exponential learning rate at ``step`` (``step < 0`` gives 0, as in 3DGS)."""
    if max_steps <= 0:
        raise ValueError(f"max_steps must be positive, got {max_steps}")
    if lr_init < 0 or lr_final < 0:
        raise ValueError(f"learning rates must be non-negative, got {lr_init} -> {lr_final}")
    if step < 0 or (lr_init == 0.0 and lr_final == 0.0):
        return 0.0
    if lr_init == 0.0 or lr_final == 0.0:
        raise ValueError("expon_lr interpolates in log space: lr_init and lr_final must both be > 0")
    delay = 1.0
    if delay_steps > 0:
        delay = delay_mult + (1.0 - delay_mult) * math.sin(
            0.5 * math.pi * min(max(step / delay_steps, 0.0), 1.0)
        )
    t = min(max(step / max_steps, 0.0), 1.0)
    return delay * math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


def group_lr(group: ParamGroup, step: int) -> float:
    """Learning rate of ``group`` at 1-based iteration ``step`` (constant when ``lr_final`` is None).

    3DGS calls ``update_learning_rate(iteration)`` with the 1-based iteration, so the schedule is
    evaluated at ``step - group.start_step``.
    """
    if group.lr_final is None:
        return group.lr
    return expon_lr(
        step - group.start_step,
        group.lr,
        group.lr_final,
        group.max_steps,
        group.lr_delay_steps,
        group.lr_delay_mult,
    )
