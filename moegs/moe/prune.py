"""Gate-aware Gaussian pruning (paper Sec. "Practical Efficiency Design" (ii)), in two variants.

**After training** (``prune``; the paper's formula): importance of Gaussian ``i`` of expert ``k`` over the
views ``D``::

    E_i = 1/|D| sum_v || d( sum_u G'_k(u; v) ) / d w_i^per ||

the sensitivity of expert ``k``'s own gate map to ``i``'s routing parameters. Gaussians with
``E_i < threshold`` are removed from the expert and from the router; or, with ``ratio``, the ``ratio``
least important Gaussians of every expert (the paper's 55 % / 75 % settings). What the paper leaves open
and we fix: the gate is summed over the view's pixels before differentiating (one backward per view and
expert), each Gaussian is scored on its own expert's gate, the gradient is taken with respect to the
stored parameters ``(w, w_dir, w_time)``, and ``ratio`` applies per expert so that no expert is emptied.
On this quantity the code's threshold (1e-5) removes almost nothing: it was written for another one.

**While training** (``RouterConfig.prune_every``; the authors' machinery, which their stored scripts never
call, ``specs/official_moegs.md`` section 4, MoE-GS-studio ``scene/c_gaussian_model.py``
``add_weight_grad`` / ``weight_pruning``): every router step adds each Gaussian's loss-gradient norm on
its ``(w, w_dir)`` to an accumulator and counts the steps in which it had one (``WeightGradients``); every
``prune_every`` steps from ``prune_from`` (code 500 and 500 of 5000) the Gaussians whose mean is below
``prune_threshold`` (code 1e-5) go, and the router trains on. Our choices where the code is silent: a
Gaussian "seen" in a step is one whose weights received a nonzero gradient (the code's visibility filter
is not stored), a Gaussian not seen since the last pruning is kept, and the accumulator restarts after
each pruning (as 3DGS's densification statistics do).
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
from moegs.train.optim import Optimizers

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
    before = [e.num_gaussians for e in model.experts]
    keep = []
    for score in scores:
        if ratio is not None:
            drop = int(ratio * score.numel())
            mask = torch.ones_like(score, dtype=torch.bool)
            mask[torch.argsort(score, stable=True)[:drop]] = False
        else:
            mask = score >= threshold
        keep.append(mask)
    keep_gaussians(model, keep)
    after = [e.num_gaussians for e in model.experts]
    return {
        "before": before,
        "after": after,
        "removed_fraction": 1.0 - sum(after) / max(sum(before), 1),
        "ratio": ratio,
        "threshold": None if ratio is not None else threshold,
        "views": len(views),
    }


def keep_gaussians(model: MoEGS, keep: Sequence[Tensor], optimizers: Optimizers | None = None) -> None:
    """Keep the Gaussians where ``keep[k] [N_k]`` (bool) of every expert, in the expert, the router's
    rows (with their moments in ``optimizers`` while training) and the lifted responsibilities; record
    them in ``model.kept`` (over each expert's trained rows) for the checkpoint."""
    weights = _weights(model)
    kept = []
    for k, (expert, mask) in enumerate(zip(model.experts, keep, strict=True)):
        old = (weights.mix[k], weights.time[k])
        expert.keep_gaussians(mask)
        weights.keep(k, mask)
        if optimizers is not None:
            optimizers.keep_rows(old[0], weights.mix[k], mask)
            optimizers.keep_rows(old[1], weights.time[k], mask)
        if model.responsibilities is not None:
            model.responsibilities[k] = model.responsibilities[k][mask]
        mask = mask.cpu()
        if model.kept is not None:  # compose with an earlier pruning: index the trained rows
            whole = model.kept[k].clone()
            whole[whole.nonzero(as_tuple=True)[0]] = mask
            mask = whole
        kept.append(mask)
    model.kept = kept


class WeightGradients:
    """The authors' importance accumulator (``add_weight_grad``): per expert, the sum over router steps
    of each Gaussian's loss-gradient norm on its ``(w, w_dir)`` and the number of steps in which it had
    one; a Gaussian's score is their ratio."""

    def __init__(self, model: MoEGS) -> None:
        weights = _weights(model)
        self.total = [p.new_zeros(p.shape[0]) for p in weights.mix]
        self.seen = [p.new_zeros(p.shape[0]) for p in weights.mix]

    @torch.no_grad()
    def add(self, model: MoEGS) -> None:
        """Add this step's gradients (call between ``backward`` and the optimiser step)."""
        for k, param in enumerate(_weights(model).mix):
            if param.grad is not None:
                norm = param.grad.norm(dim=1)
                self.total[k] += norm
                self.seen[k] += norm > 0

    def prune_masks(self, threshold: float) -> list[Tensor]:
        """Per expert, True for the Gaussians to keep: mean below ``threshold`` goes, unseen stays; a
        pruning that would empty an expert is skipped for it (ours: the code has no such case)."""
        pairs = zip(self.total, self.seen, strict=True)
        masks = [(s == 0) | (t / s.clamp(min=1) >= threshold) for t, s in pairs]
        return [m if m.any() else torch.ones_like(m) for m in masks]

    def restart(self, keep: Sequence[Tensor] | None = None) -> None:
        """Zero the sums (after a pruning, to the ``keep`` rows)."""
        if keep is not None:
            self.total = [t[m] for t, m in zip(self.total, keep, strict=True)]
        self.total = [torch.zeros_like(t) for t in self.total]
        self.seen = [torch.zeros_like(t) for t in self.total]

    def state_dict(self) -> dict[str, list[Tensor]]:
        return {"total": list(self.total), "seen": list(self.seen)}

    def load_state_dict(self, state: dict[str, list[Tensor]]) -> None:
        device = self.total[0].device
        self.total = [t.to(device) for t in state["total"]]
        self.seen = [s.to(device) for s in state["seen"]]
