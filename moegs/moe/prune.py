"""Gate-aware Gaussian pruning (paper Sec. "Practical Efficiency Design" (ii)).

Importance of Gaussian ``i`` of expert ``k`` over the views ``D``::

    E_i = 1/|D| sum_v || d( sum_u G'_k(u; v) ) / d w_i^per ||

the sensitivity of expert ``k``'s own gate map to ``i``'s routing parameters. Gaussians with
``E_i < threshold`` are removed from the expert and from the router; or, with ``ratio``, the ``ratio``
least important Gaussians of every expert (the paper's 55 % / 75 % settings).

What the paper leaves open and we fix (the authors' code has the accumulator but never calls it, see
``specs/official_moegs.md`` section 4): the gate is summed over the view's pixels before differentiating
(one backward per view and expert), each Gaussian is scored on its own expert's gate, the gradient is
taken with respect to the stored parameters ``(w, w_dir, w_time)``, and ``ratio`` applies per expert so
that no expert is emptied. We prune once, after router training; the paper says "progressively
pruned", and the code's unused schedule would prune every 500 iterations from iteration 500
(``prune_weight_interval``, ``prune_from_iter``). The default threshold is the code's
``prune_weight_threshold`` (1e-5), which there probably bounds a mean accumulated loss gradient, a
different quantity from our pixel-summed gate gradient: the number does not carry over, and the
paper's tables prune by ratio.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor
from tqdm.auto import tqdm

from moegs.data.scene import View
from moegs.moe.model import MoEGS
from moegs.moe.routers import GaussianWeights
from moegs.train.evaluate import eval_views

DEFAULT_THRESHOLD = 1e-5
"""Code ``configs/N3V/*.json`` ``prune_weight_threshold``."""


def _weights(model: MoEGS) -> GaussianWeights:
    weights = getattr(model.router, "weights", None)
    if not isinstance(weights, GaussianWeights):
        raise ValueError(
            f"gate-aware pruning needs per-Gaussian routing parameters; the {model.config.variant!r} router "
            "has none (use the 'vapr' or 'volume' router)"
        )
    return weights


def gate_importance(model: MoEGS, views: Sequence[View], background, progress: bool = False) -> list[Tensor]:
    """``E`` per expert, ``[N_k]`` each on the model's device (see module docstring); vapr and volume
    routers."""
    weights = _weights(model)
    model.eval()
    device = model.device
    background = None if background is None else background.to(device)
    k_all = len(weights.mix)
    totals = [p.new_zeros(p.shape[0]) for p in weights.mix]
    for view in tqdm(views, disable=not progress, desc="gate importance"):
        gates = model.render(view.camera.to(device), background).gates
        for k in range(k_all):
            grads = torch.autograd.grad(
                gates[k].sum(),
                [weights.mix[k], weights.time[k]],
                retain_graph=k < k_all - 1,
                allow_unused=True,
            )
            parts = [g for g in grads if g is not None]
            if parts:
                totals[k] += torch.cat(parts, dim=1).norm(dim=1)
    return [t / max(len(views), 1) for t in totals]


def prune(
    model: MoEGS,
    scene,
    ratio: float | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    max_views: int | None = None,
    progress: bool = False,
) -> dict:
    """Prune ``model``'s experts and routing parameters in place by gate importance over the training views.

    Args:
        model: a trained MoE-GS model (vapr or volume router).
        scene: its scene (training views, background).
        ratio: drop this fraction of every expert's least important Gaussians (in [0, 1)); None: threshold.
        threshold: drop Gaussians with importance below it (when ``ratio`` is None).
        max_views: score on at most this many training views, evenly spaced (None: all).

    Returns:
        ``{"before": [N_k], "after": [N_k], "removed_fraction", "ratio", "threshold", "views"}``.
    """
    if ratio is not None and not 0.0 <= ratio < 1.0:
        raise ValueError(f"prune: ratio must be in [0, 1), got {ratio}")
    views = eval_views(scene.train, max_views)
    scores = gate_importance(model, views, scene.background, progress)
    weights = _weights(model)
    before = [e.num_gaussians for e in model.experts]
    for k, (expert, score) in enumerate(zip(model.experts, scores, strict=True)):
        if ratio is not None:
            drop = int(ratio * score.numel())
            keep = torch.ones_like(score, dtype=torch.bool)
            keep[torch.argsort(score, stable=True)[:drop]] = False
        else:
            keep = score >= threshold
        expert.keep_gaussians(keep)
        weights.keep(k, keep)
        if model.responsibilities is not None:
            model.responsibilities[k] = model.responsibilities[k][keep]
    after = [e.num_gaussians for e in model.experts]
    return {
        "before": before,
        "after": after,
        "removed_fraction": 1.0 - sum(after) / max(sum(before), 1),
        "ratio": ratio,
        "threshold": None if ratio is not None else threshold,
        "views": len(views),
    }
