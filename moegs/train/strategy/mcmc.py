"""3DGS as Markov chain Monte Carlo (Kheradmand et al. 2024; ``ubc-vision/3dgs-mcmc``).

Every ``refine_every`` iterations in (``refine_from``, ``refine_until``): dead Gaussians
(opacity ≤ ``min_opacity``) are relocated onto live ones drawn ∝ opacity, then ``5 %`` more are added
up to ``cap_max``; after every optimiser step the means get SGLD noise. No clone, split, prune or
opacity reset. Facts: ``specs/experts_noncanonical.md`` section 3.

With ``group_key`` naming a splat entry that holds one model index per Gaussian, every model is an
independent fit: its dead Gaussians are refilled from its own live ones and it grows up to
``cap_max`` on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from moegs.train.strategy import ops
from moegs.train.strategy.base import Strategy

MAX_COPIES = 50  # N is clamped to 50 and the binomial table has 51 rows (3dgs-mcmc `n_max = 51`)


def binomial_table(n_max: int = MAX_COPIES + 1, device: torch.device | str = "cpu") -> Tensor:
    """``[n_max, n_max]`` with ``C(n, k)`` at ``[n, k]`` (0 for k > n), float64, on ``device``."""
    return torch.tensor(
        [[math.comb(n, k) for k in range(n_max)] for n in range(n_max)], dtype=torch.float64, device=device
    )


def relocation_update(
    opacities: Tensor, scales: Tensor, copies: Tensor, min_opacity: float = 0.005
) -> tuple[Tensor, Tensor]:
    """New opacity and scale of a Gaussian shared by ``copies`` Gaussians (MCMC paper eq. 9).

    ``o' = 1 - (1 - o)^(1/N)`` and ``s' = s · o / Σ_{i=1..N} Σ_{k=0..i-1} C(i-1, k) (-1)^k o'^(k+1) / √(k+1)``
    with ``N = clamp(copies, 1, 50)``; ``o'`` is then clamped to ``[min_opacity, 1 - eps]`` (3dgs-mcmc
    clamps after computing ``s'``; gsplat clamps before).

    Args:
        opacities: activated opacities ``[M]``.
        scales: activated scales ``[M, 3]``.
        copies: ``[M]`` number of Gaussians sharing each source after the move (drawn count + 1).

    Returns:
        activated ``(opacities [M], scales [M, 3])``.
    """
    n = copies.clamp(1, MAX_COPIES).to(torch.float64)
    o = opacities.to(torch.float64)
    new_o = 1.0 - (1.0 - o) ** (1.0 / n)  # [M]
    binoms = binomial_table(device=o.device)
    i = torch.arange(1, MAX_COPIES + 1, dtype=torch.float64, device=o.device)  # [I]
    k = torch.arange(MAX_COPIES, dtype=torch.float64, device=o.device)  # [K]
    coef = binoms[:MAX_COPIES, :MAX_COPIES] * (-1.0) ** k / torch.sqrt(k + 1.0)  # [I, K], C(i-1, k) ...
    terms = coef[None] * new_o[:, None, None] ** (k + 1.0)  # [M, I, K]
    active = (i[None, :] <= n[:, None]).to(torch.float64)  # [M, I]: i runs to N
    denom = (terms.sum(dim=2) * active).sum(dim=1)  # [M]
    new_s = scales.to(torch.float64) * (o / denom)[:, None]
    eps = torch.finfo(torch.float32).eps
    return new_o.clamp(min_opacity, 1.0 - eps).to(opacities.dtype), new_s.to(scales.dtype)


@dataclass
class MCMCStrategy(Strategy):
    """Relocation, growth and SGLD noise (defaults: 3dgs-mcmc ``train.py`` / gsplat ``MCMCStrategy``)."""

    cap_max: int = 1_000_000
    """Maximum Gaussians per model; per scene in 3DGS-MCMC (the count the original 3DGS run reached,
    3dgs-mcmc ``README.md:107``); gsplat's default."""
    noise_lr: float = 5e5
    """SGLD noise multiplier (``noise_lr``)."""
    refine_from: int = 500
    """Relocate / grow when ``step > refine_from`` (``densify_from_iter``)."""
    refine_until: int = 25_000
    """... and ``step < refine_until`` (``densify_until_iter``)."""
    refine_every: int = 100
    """... and ``step % refine_every == 0`` (``densification_interval``)."""
    min_opacity: float = 0.005
    """Dead below or at this opacity; floor of relocated opacities."""
    growth_rate: float = 0.05
    """Grow to ``min(cap_max, floor((1 + growth_rate) · N))`` per refinement."""
    noise_gate_k: float = 100.0
    """Noise gate ``sigmoid(-k (o - t))``: steepness k."""
    noise_gate_t: float = 0.005
    """... and threshold t (3dgs-mcmc ``op_sigmoid(1 - o, k=100, x0=0.995)``)."""
    noise_until: int = -1
    """Noise while ``step < noise_until``; -1 = to the end (gsplat ``noise_injection_stop_iter``,
    ``strategy/mcmc.py``: ``if step < noise_stop``)."""
    opacity_reg: float = 0.01
    """Weight of mean opacity in the loss (``opacity_reg``; 0.001 on Deep Blending)."""
    scale_reg: float = 0.01
    """Weight of mean scale in the loss (``scale_reg``)."""
    group_key: str | None = None
    """Splat entry with the model index ``[N]`` of each Gaussian (independent fits), or None."""

    def regularization(self, opacities: Tensor, scales: Tensor) -> Tensor:
        """``opacity_reg · mean |o| + scale_reg · mean |s|`` over activated ``[N]`` / ``[N, 3]`` values."""
        return self.opacity_reg * opacities.abs().mean() + self.scale_reg * scales.abs().mean()

    def initialize_state(self, scene_scale: float, white_background: bool = False) -> dict[str, Any]:
        state = super().initialize_state(scene_scale, white_background)
        state["last_refine"] = {"relocated": 0, "added": 0}
        return state

    # -- refinement -------------------------------------------------------------------------------
    def _draw(self, weights: Tensor, pool: Tensor, count: int) -> Tensor:
        """``count`` indices from ``pool`` drawn ∝ ``weights`` with replacement."""
        probs = weights / (weights.sum() + torch.finfo(weights.dtype).eps)
        return pool[torch.multinomial(probs, count, replacement=True)]

    def _new_values(self, params, sources: Tensor, n: int) -> tuple[Tensor, Tensor]:
        """Raw (logit, log) opacity and scale of each drawn source; ``copies`` = times drawn + 1."""
        copies = torch.bincount(sources, minlength=n)[sources] + 1
        o, s = relocation_update(
            torch.sigmoid(params["opacities"][sources]),
            torch.exp(params["scales"][sources]),
            copies,
            self.min_opacity,
        )
        return torch.logit(o), torch.log(s)

    @torch.no_grad()
    def _relocate(self, params, optimizers, groups: list[Tensor]) -> int:
        opacity = torch.sigmoid(params["opacities"])
        dead_all, sources_all = [], []
        for members in groups:
            dead = opacity[members] <= self.min_opacity
            alive = members[~dead]
            if dead.any() and len(alive) > 0:
                dead_all.append(members[dead])
                sources_all.append(self._draw(opacity[alive], alive, int(dead.sum())))
        if not dead_all:
            return 0
        dead, sources = torch.cat(dead_all), torch.cat(sources_all)
        new_o, new_s = self._new_values(params, sources, opacity.shape[0])
        ops.relocate(params, optimizers, dead, sources, new_o, new_s)
        return len(dead)

    @torch.no_grad()
    def _grow(self, params, optimizers, groups: list[Tensor]) -> int:
        opacity = torch.sigmoid(params["opacities"])
        sources_all = []
        for members in groups:
            add = max(0, min(self.cap_max, int((1.0 + self.growth_rate) * len(members))) - len(members))
            if add > 0:
                sources_all.append(self._draw(opacity[members], members, add))
        if not sources_all:
            return 0
        sources = torch.cat(sources_all)
        new_o, new_s = self._new_values(params, sources, opacity.shape[0])
        ops.sample_add(params, optimizers, sources, new_o, new_s)
        return len(sources)

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        if not (self.refine_from < step < self.refine_until and step % self.refine_every == 0):
            return
        relocated = self._relocate(params, optimizers, self._groups(params))
        added = self._grow(params, optimizers, self._groups(params))
        state["last_refine"] = {"relocated": relocated, "added": added}

    @torch.no_grad()
    def step_post_optimizer(self, params, optimizers, state, step: int, info: dict) -> None:
        if 0 <= self.noise_until <= step:
            return
        opacity = torch.sigmoid(params["opacities"])
        gate = torch.sigmoid(-self.noise_gate_k * (opacity - self.noise_gate_t))
        lr_means = optimizers["means"].param_groups[0]["lr"]
        ops.inject_noise(params, gate * self.noise_lr * lr_means)

    def _groups(self, params) -> list[Tensor]:
        """Indices of each model's Gaussians (one model of all when ``group_key`` is None)."""
        if self.group_key is None:
            return [torch.arange(params["means"].shape[0], device=params["means"].device)]
        if self.group_key not in params:
            raise ValueError(
                f"MCMCStrategy.group_key {self.group_key!r} is not a splat entry ({list(params)})"
            )
        ids = params[self.group_key].detach()
        sizes = torch.bincount(ids).tolist()  # one read; a stable sort lists each model's rows in order
        return [rows for rows in ids.argsort(stable=True).split(sizes) if len(rows)]
