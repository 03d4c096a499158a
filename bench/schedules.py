"""Quick schedules stretched to N iterations: the training length of the ``standard`` preset and of the
convergence study (``bench.convergence``).

Scaling rule: every iteration-valued field of an expert's quick reduction that places an event or a
decay in the run (``SCHEDULE_FIELDS``: static phase, warm-ups, lr decay lengths, densification window,
opacity reset period, phases) is multiplied by ``N / 600`` (unset, 0 and ``NEVER`` stay as they are);
the periods of repeated steps (``INTERVAL_FIELDS``: ``densify_every``, ``prune_every`` ...) keep the
quick value, so a longer run densifies more often, closer to the original's event count; counts and
model sizes stay quick's. N = 600 is exactly the quick recipe. Only experts with a ``SCHEDULE_FIELDS`` row
can be stretched; the others raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any

QUICK_ITERATIONS = 600  # moegs.experts.base.QUICK_ITERATIONS without importing torch (checked by tests)
ADC_WINDOW = ("strategy.densify_from", "strategy.densify_until", "strategy.reset_every")
SH_BANDS = "train.sh_degree_interval"  # the steps at which SH bands 1, 2, 3 switch on
SCHEDULE_FIELDS: dict[str, tuple[str, ...]] = {
    "static": (SH_BANDS, "means_lr_max_steps", *ADC_WINDOW),
    # warm_up: static phase; time_noise_steps: AST annealing; deform_lr_max_steps is the paper's (>= N)
    "deformable": (SH_BANDS, "warm_up", "time_noise_steps", "means_lr_max_steps", *ADC_WINDOW),
    # select_best_at: the steps the best model is chosen among (() at quick: the last model)
    "grid4d": (SH_BANDS, "warm_up", "means_lr_max_steps", *ADC_WINDOW, "train.select_best_at"),
    # coarse (static) stage, its copy in the strategy, the densify/prune window and the reset period
    "fourdgs": (
        SH_BANDS,
        "coarse_iterations",
        "means_lr_max_steps",
        "strategy.coarse_iterations",
        *ADC_WINDOW,
        "strategy.prune_from",
    ),
    # coarse-to-fine and random-view phases, the deformation's start and ramp, both lr decays, the window
    "ed3dgs": (
        SH_BANDS,
        "coarse_to_fine_until",
        "anneal_steps",
        "deform_from",
        "means_lr_max_steps",
        "deformation_lr_max_steps",
        "random_until",
        "strategy.densify_from",
        "strategy.densify_until",
    ),
    # the window, the resets, the omega-mask phase, the bbox prune and the start of guided sampling
    "stg": (
        SH_BANDS,
        "means_lr_max_steps",
        "strategy.densify_from",
        "strategy.densify_until",
        "strategy.prune_until",
        "strategy.reset_at",
        "strategy.omega_mask_from",
        "strategy.omega_mask_until",
        "strategy.bbox_prune_at",
        "strategy.guided_from",
    ),
    # the starts of frame growth, regularisation and pruning, the adjustment phase and the window
    "ex4dgs": (
        SH_BANDS,
        "grow_from",
        "reg_from",
        "means_lr_max_steps",
        "adjust_until",
        "strategy.densify_from",
        "strategy.densify_until",
        "strategy.prune_from",
    ),
    "mcmc": (SH_BANDS, "means_lr_max_steps", "strategy.refine_from", "strategy.refine_until"),
}
"""Quick-reduction fields scaled with the run length, per expert (the keys of ``quick_fields``)."""
INTERVAL_FIELDS = (
    "strategy.densify_every",
    "strategy.prune_every",
    "strategy.refine_every",
    "strategy.z_prune_every",
    "strategy.guided_gap",
    "grow_every",
    "make_dynamic_interval",  # an offset inside the growth period, kept with it
    "extract_every",
    "adjust_every",
)
"""Iteration-valued quick fields that are periods of a repeated step: they keep the quick value."""


def _stretch(value: Any, ratio: float) -> Any:
    """One schedule value times ``ratio``: None, 0 and never (``NEVER``) stay; tuples element-wise."""
    from moegs.train.strategy import NEVER

    if isinstance(value, tuple):
        return tuple(_stretch(v, ratio) for v in value)
    if value is None or value == 0 or value >= NEVER:
        return value
    return max(1, round(value * ratio))


def scaled_overrides(expert: str, scene: str, iterations: int) -> dict[str, Any]:
    """Resolver overrides that stretch the quick recipe of ``expert`` on ``scene`` to ``iterations``."""
    from moegs.recipes import config_for

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
        out[key] = _stretch(quick[key], ratio)
    return out
