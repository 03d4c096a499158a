"""Quick schedules stretched to N iterations: the training length of the ``standard`` preset and of the
convergence study (``bench.convergence``).

Scaling rule: every iteration-valued field of an expert's quick reduction that places an event or a
decay in the run (``SCHEDULE_FIELDS``: static phase, warm-ups, lr decay lengths, densification window,
opacity reset period) is multiplied by ``N / 600`` (``NEVER`` stays never); per-step intervals
(``densify_every``, ``prune_every``) keep the quick value, so a longer run densifies more often, closer
to the original's event count; model sizes stay quick's. N = 600 is exactly the quick recipe. Only
experts with a ``SCHEDULE_FIELDS`` row can be stretched; the others raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any

QUICK_ITERATIONS = 600  # moegs.experts.static.QUICK_ITERATIONS (checked by tests)
ADC_WINDOW = ("strategy.densify_from", "strategy.densify_until", "strategy.reset_every")
SCHEDULE_FIELDS: dict[str, tuple[str, ...]] = {
    "static": ("means_lr_max_steps", *ADC_WINDOW),
    # warm_up: static phase; time_noise_steps: AST annealing; deform_lr_max_steps is the paper's (>= N)
    "deformable": ("warm_up", "time_noise_steps", "means_lr_max_steps", *ADC_WINDOW),
    "grid4d": ("warm_up", "means_lr_max_steps", *ADC_WINDOW),
    # coarse (static) stage, its copy in the strategy, the densify/prune window and the reset period
    "fourdgs": (
        "coarse_iterations",
        "means_lr_max_steps",
        "strategy.coarse_iterations",
        *ADC_WINDOW,
        "strategy.prune_from",
    ),
}
"""Quick-reduction fields scaled with the run length, per expert (the keys of ``quick_fields``)."""


def scaled_overrides(expert: str, scene: str, iterations: int) -> dict[str, Any]:
    """Resolver overrides that stretch the quick recipe of ``expert`` on ``scene`` to ``iterations``."""
    from moegs.recipes import config_for
    from moegs.train.strategy import NEVER

    if expert not in SCHEDULE_FIELDS:
        raise ValueError(
            f"no schedule table for expert {expert!r} (bench.schedules.SCHEDULE_FIELDS has "
            f"{', '.join(SCHEDULE_FIELDS)})"
        )
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    quick = config_for(expert, scene, "quick").reductions
    ratio = iterations / QUICK_ITERATIONS
    out: dict[str, Any] = {"train.iterations": iterations}
    for key in SCHEDULE_FIELDS[expert]:
        out[key] = quick[key] if quick[key] >= NEVER else max(1, round(quick[key] * ratio))
    return out
