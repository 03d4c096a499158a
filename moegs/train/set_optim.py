"""Adam or RAdam over per-Gaussian tensors whose rows belong to two sets that count their steps apart.

Ex4DGS keeps its static and dynamic Gaussians in separate tensors, each with its own optimiser state. The
dynamic tensors only enter the optimiser at the first static-to-dynamic conversion
(``c_gaussian_model.py:78-87, 439-449, 765-787``), so their step count, which sets the bias corrections
(and RAdam's rectification), starts there. This suite keeps both sets in one tensor per attribute with a
``dynamic`` flag; ``SetOptimizer`` updates each set's rows with torch's own functional Adam or RAdam
(its ``foreach`` implementation, the CUDA default, as ``moegs.train.optim``) and that set's step count, so
every row moves bit for bit as it would in its own set's tensor. A set counts
every update from the first one at which it holds a row (an emptied tensor keeps being stepped in the
original).

Moments are per row, so densification (``moegs.train.strategy.ops``) keeps them in step as for Adam; the
two counts are scalars and are kept. The rows of each set are read from the device once per change of the
flags (``row_sets``), not at every update. The second set may learn at its own constant rate (``second_lr``:
Ex4DGS's ``feature_motion_lr``, 2.5e-4 on Technicolor Birthday, Painter and Train, ``configs/techni/*.json``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import Tensor
from torch.optim.adam import adam as adam_update
from torch.optim.radam import radam as radam_update

KINDS = ("adam", "radam")
FOREACH = True
"""Every optimiser of the suite (this one and ``moegs.train.optim``'s) runs torch's foreach implementation."""


class RowSets(NamedTuple):
    """Row indices of a set flag ``[N]``: those outside the set (``first``) and inside it (``second``)."""

    first: Tensor
    second: Tensor


def row_sets(flags: Tensor) -> RowSets:
    """The rows of ``flags [N]`` (bool) outside and inside the set, each ascending. Reads one count from
    the device per change of ``flags``: the answer is kept on the tensor for its version and storage, which
    in-place writes and moves change (a write through ``.data`` does not: write the tensor itself)."""
    key = (flags._version, flags.data_ptr())
    cached = getattr(flags, "_row_sets", None)
    if cached is None or cached[0] != key:
        second = flags.nonzero(as_tuple=True)[0]
        first = torch.nonzero_static(~flags, size=flags.shape[0] - second.shape[0])[:, 0]
        cached = flags._row_sets = (key, RowSets(first, second))
    return cached[1]


class SetOptimizer(torch.optim.Optimizer):
    """torch's Adam or RAdam (``kind``; no weight decay) where ``second_set() -> [N]`` bool marks the rows
    of each parameter ``[N, ...]`` that count steps in ``state["step_second"]`` and learn at
    ``second_lr`` (None: the group's ``lr``); the others count in ``state["step"]``."""

    def __init__(
        self,
        params,
        kind: str,
        second_set: Callable[[], Tensor],
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
        second_lr: float | None = None,
    ) -> None:
        if kind not in KINDS:
            raise ValueError(f"SetOptimizer: kind must be one of {KINDS}, got {kind!r}")
        super().__init__(params, {"lr": lr, "betas": betas, "eps": eps, "second_lr": second_lr})
        self.kind, self.second_set = kind, second_set

    @torch.no_grad()
    def step(self, closure=None) -> None:
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is not None:
                    self._update(p, group)

    def _update(self, p: Tensor, group: dict) -> None:
        state = self.state[p]
        if not state:  # step counts on the host, as torch's Adam keeps them (not capturable)
            state.update(
                step=torch.tensor(0.0, device="cpu"),
                step_second=torch.tensor(0.0, device="cpu"),
                exp_avg=torch.zeros_like(p),
                exp_avg_sq=torch.zeros_like(p),
            )
        flags = self.second_set()
        if flags.shape != p.shape[:1]:
            raise ValueError(
                f"SetOptimizer: second_set() gives {tuple(flags.shape)} rows for {tuple(p.shape)}"
            )
        moments = (state["exp_avg"], state["exp_avg_sq"])
        second_lr = group["lr"] if group["second_lr"] is None else group["second_lr"]
        first, second = row_sets(flags)
        for key, idx, lr in (("step", first, group["lr"]), ("step_second", second, second_lr)):
            if not (idx.numel() or float(state[key]) > 0):
                continue  # the set has never held a row: its tensors are not in the original's optimiser yet
            if idx.numel() == p.shape[0]:
                self._functional(group, lr, p, p.grad, *moments, state[key])
                continue
            part, part_moments = p[idx], [m[idx] for m in moments]
            self._functional(group, lr, part, p.grad[idx], *part_moments, state[key])
            p[idx] = part
            for m, part_m in zip(moments, part_moments, strict=True):
                m[idx] = part_m

    def _functional(
        self,
        group: dict,
        lr: float,
        param: Tensor,
        grad: Tensor,
        exp_avg: Tensor,
        exp_avg_sq: Tensor,
        step: Tensor,
    ) -> None:
        """One update of one set's rows at rate ``lr`` by torch's foreach implementation (``step`` counts
        up)."""
        beta1, beta2 = group["betas"]
        options = {
            "beta1": beta1,
            "beta2": beta2,
            "lr": lr,
            "weight_decay": 0.0,
            "eps": group["eps"],
        }
        tensors = ([param], [grad], [exp_avg], [exp_avg_sq])
        if self.kind == "adam":
            adam_update(*tensors, [], [step], foreach=FOREACH, amsgrad=False, maximize=False, **options)
        else:
            radam_update(*tensors, [step], foreach=FOREACH, **options)
