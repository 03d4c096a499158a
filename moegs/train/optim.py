"""One torch optimiser per ``ParamGroup``, with its learning-rate schedule.

Keeping one optimiser per group (rather than one optimiser with many groups) lets densification
swap a per-Gaussian tensor and its moments without touching anything else, and lets a method mix
Adam and RAdam groups.

Every optimiser runs torch's ``foreach`` implementation (``FOREACH``): torch's default on CUDA tensors,
so the one every original ran. On CPU torch defaults to the single-tensor one, which for RAdam rounds
differently (about 1e-7 after a few steps) and takes 3-7x as long; for Adam the two agree bit for bit.
"""

from __future__ import annotations

import torch
from torch import nn

from moegs.train.params import ParamGroup
from moegs.train.schedules import group_lr
from moegs.train.set_optim import FOREACH, SetOptimizer

ADAM_BETAS = (0.9, 0.999)  # torch defaults, used unchanged by 3DGS and every expert built on it
_OPTIMIZERS = {"adam": torch.optim.Adam, "radam": torch.optim.RAdam}


class Optimizers:
    """The optimisers of one expert, keyed by ``ParamGroup.name``."""

    def __init__(self, groups: list[ParamGroup]) -> None:
        names = [g.name for g in groups]
        if len(set(names)) != len(names):
            raise ValueError(f"param group names must be unique, got {names}")
        self.groups = {g.name: g for g in groups}
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        for g in groups:
            if g.optimizer not in _OPTIMIZERS:
                raise ValueError(
                    f"param group {g.name!r}: unknown optimizer {g.optimizer!r}; "
                    f"valid: {', '.join(_OPTIMIZERS)}"
                )
            if not g.params:
                raise ValueError(f"param group {g.name!r} has no parameters")
            params, options = [{"params": list(g.params), "lr": g.lr}], {"betas": ADAM_BETAS, "eps": g.eps}
            if g.second_set is None:
                self.optimizers[g.name] = _OPTIMIZERS[g.optimizer](
                    params, lr=g.lr, foreach=FOREACH, **options
                )
            else:
                self.optimizers[g.name] = SetOptimizer(
                    params, g.optimizer, g.second_set, lr=g.lr, second_lr=g.second_lr, **options
                )

    def for_splats(self, splats: nn.ParameterDict) -> dict[str, torch.optim.Optimizer]:
        """Map each trainable per-Gaussian key to the optimiser holding it (for strategy ops).

        Raises ``ValueError`` when a trainable splat tensor is in no group or in several.
        """
        out = {}
        for key, param in splats.items():
            holders = [
                name
                for name, opt in self.optimizers.items()
                if any(p is param for p in opt.param_groups[0]["params"])
            ]
            if not param.requires_grad:
                if holders:
                    raise ValueError(f"splats[{key!r}] does not require grad but is in group(s) {holders}")
                continue
            if len(holders) != 1:
                raise ValueError(
                    f"splats[{key!r}] must be in exactly one param group, found {holders or 'none'}"
                )
            out[key] = self.optimizers[holders[0]]
        return out

    def set_step(self, step: int) -> dict[str, float]:
        """Apply every group's schedule at 1-based iteration ``step``; returns the rates by group."""
        rates = {}
        for name, group in self.groups.items():
            rates[name] = group_lr(group, step)
            for pg in self.optimizers[name].param_groups:
                pg["lr"] = rates[name]
        return rates

    def step(self) -> None:
        for opt in self.optimizers.values():
            opt.step()

    def zero_grad(self) -> None:
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)

    @torch.no_grad()
    def keep_rows(self, old: nn.Parameter, new: nn.Parameter, keep: torch.Tensor) -> None:
        """Put ``new`` (``old``'s rows where ``keep [N]``) in ``old``'s place in the optimiser holding it,
        with the moments of those rows (pruning a parameter while training)."""
        for opt in self.optimizers.values():
            for group in opt.param_groups:
                for i, param in enumerate(group["params"]):
                    if param is old:
                        group["params"][i] = new
                        for g in self.groups.values():  # the schedules' record of the group's tensors
                            g.params = [new if q is old else q for q in g.params]
                        state = opt.state.pop(old, None)
                        if state is not None:
                            opt.state[new] = {
                                k: v[keep] if torch.is_tensor(v) and v.ndim > 0 and len(v) == len(keep) else v
                                for k, v in state.items()
                            }
                        return
        raise ValueError("Optimizers.keep_rows: the parameter is in no optimiser")

    def state_dict(self) -> dict:
        return {name: opt.state_dict() for name, opt in self.optimizers.items()}

    def load_state_dict(self, state: dict) -> None:
        if set(state) != set(self.optimizers):
            raise ValueError(
                f"optimizer state has groups {sorted(state)}, the expert has {sorted(self.optimizers)}"
            )
        for name, opt in self.optimizers.items():
            opt.load_state_dict(state[name])
