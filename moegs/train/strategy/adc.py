"""3DGS adaptive density control (Kerbl et al. 2023, ``gaussian_model.py`` / ``train.py``).

Screen-space gradient convention. 3DGS thresholds the norm of the gradient of the loss with
respect to the projected mean *in NDC units*: its CUDA backward multiplies the pixel gradient by
``0.5 * W`` (x) and ``0.5 * H`` (y). ``rasterize`` returns ``means2d`` in pixels, so the pixel
gradient is scaled by ``(W / 2, H / 2)`` here. With that, ``grad_threshold = 0.0002`` means what it
means in 3DGS.

A step of several views enters the statistics as its method's code has it (``ADCStrategy.batch_stats``).
The loss here is the mean over the step's views, as in 4DGaussians and E-D3DGS; STG backpropagates each
view's loss on its own, and gsplat's ``DefaultStrategy`` multiplies the batch size back, so those two
conventions scale each view's gradient by the batch size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from moegs.train.strategy import ops
from moegs.train.strategy.base import Strategy

BATCH_STATS = ("per_view", "summed", "last")


@dataclass
class ADCStrategy(Strategy):
    """Clone / split / prune / opacity reset on the 3DGS schedule (defaults: 3DGS
    ``OptimizationParams``). Iterations are 1-based, as in 3DGS ``train.py``."""

    densify_from: int = 500
    """Densify when ``step > densify_from`` (3DGS ``densify_from_iter``)."""
    densify_until: int = 15_000
    """Statistics, densification and resets only while ``step < densify_until``."""
    densify_every: int = 100
    """Densify when ``step % densify_every == 0`` (``densification_interval``)."""
    reset_every: int = 3000
    """Opacity reset when ``step % reset_every == 0`` (``opacity_reset_interval``); also the step after
    which large Gaussians are pruned."""
    grad_threshold: float = 0.0002
    """Mean NDC-space ‖∂L/∂μ2D‖ above which a Gaussian is cloned or split (``densify_grad_threshold``)."""
    percent_dense: float = 0.01
    """Clone if max scale ≤ ``percent_dense · extent``, else split."""
    prune_opacity: float = 0.005
    """Prune opacity below this at every densification (``min_opacity`` in ``densify_and_prune``)."""
    prune_world_scale: float | None = 0.1
    """After the first reset interval prune max scale > ``prune_world_scale · extent`` (None: never;
    Grid4D's ``disable_ws_prune``)."""
    prune_screen_size: float | None = None
    """After the first reset interval prune Gaussians whose max screen radius since the last
    densification exceeds this many pixels. 3DGS passes 20, but its ``densification_postfix`` zeroes
    ``max_radii2D`` before the test, so the rule never fires there: None reproduces that; 20 gives the
    intended rule."""
    split_samples: int = 2
    """Children per split Gaussian (3DGS ``N=2``)."""
    split_scale_divisor: float = 1.6
    """Children scale = parent / divisor (3DGS ``0.8 * N``)."""
    reset_value: float = 0.01
    """Opacity reset to ``min(opacity, reset_value)``."""
    reset_at_densify_from_if_white: bool = True
    """3DGS also resets at ``step == densify_from`` when the background is white."""
    batch_stats: str = "per_view"
    """How the views of one step enter the screen-space statistics: ``"per_view"`` (3DGS, gsplat: each
    view adds its gradient norm, times the batch size, and a count where it sees the Gaussian),
    ``"summed"`` (4DGaussians and E-D3DGS ``train.py``: the views' gradients are summed before the norm, and
    a Gaussian seen by any view counts once) or ``"last"`` (STG ``train.py:257-258``: the last view's
    gradient, times the batch size, visibility and radii)."""
    prune_after_reset_only: bool = False
    """Prune nothing, not even low opacity, until ``step > reset_every`` (Grid4D calls ``prune_points``
    inside ``if max_screen_size:``, ``scene/gaussian_model.py:374-380``)."""

    needs_render_stats = True

    def initialize_state(self, scene_scale: float, white_background: bool = False) -> dict[str, Any]:
        state = super().initialize_state(scene_scale, white_background)
        state.update(grad2d=None, count=None, max_radii=None)  # [N] each, created on first update
        return state

    # -- statistics -------------------------------------------------------------------------------
    def _reset_stats(self, state: dict, n: int, like: Tensor) -> None:
        state["grad2d"] = like.new_zeros(n)
        state["count"] = like.new_zeros(n)
        state["max_radii"] = like.new_zeros(n)

    @staticmethod
    def _remove_keeping_stats(params, optimizers, state: dict, prune: Tensor) -> None:
        """Drop the Gaussians of ``prune [N]`` and the same rows of the statistics, which keep
        accumulating for the rest (the originals' ``prune_points`` masks them, it does not restart them)."""
        ops.remove(params, optimizers, prune)
        keep = (~prune).nonzero(as_tuple=True)[0]
        for key in ("grad2d", "count", "max_radii"):
            state[key] = state[key][keep]

    def __post_init__(self) -> None:
        if self.batch_stats not in BATCH_STATS:
            raise ValueError(
                f"{type(self).__name__}.batch_stats must be one of {BATCH_STATS}, got {self.batch_stats!r}"
            )

    def _ndc_gradients(self, renders: list[dict], n: int) -> list[Tensor]:
        """Each view's ``∂L/∂μ2D`` in NDC units ``[N, 2]`` (checked: one row per Gaussian, a gradient)."""
        out = []
        for r in renders:
            means2d = r["means2d"]
            if means2d.shape[0] != n:
                raise ValueError(
                    f"{type(self).__name__} needs one projected mean per Gaussian: got {means2d.shape[0]}, "
                    f"the expert has {n} (frame() must return every Gaussian)"
                )
            if means2d.grad is None:
                raise RuntimeError(
                    f"{type(self).__name__}: means2d has no gradient; render with return_stats=True "
                    "and call step_post_backward after loss.backward()"
                )
            out.append(means2d.grad * means2d.new_tensor([r["width"] / 2.0, r["height"] / 2.0]))
        return out

    def _update_stats(self, params, state: dict, info: dict) -> None:
        n = params["means"].shape[0]
        if state["grad2d"] is None or state["grad2d"].shape[0] != n:
            self._reset_stats(state, n, params["means"].detach())
        batch = len(info["renders"])
        renders = info["renders"][-1:] if self.batch_stats == "last" else info["renders"]
        grads = self._ndc_gradients(renders, n)
        visible = [r["visible"] for r in renders]
        radii = [r["radii"].float() for r in renders]
        if self.batch_stats == "summed":
            grads = [sum(grads[1:], grads[0])]
            visible = [torch.stack(visible).any(dim=0)]
            radii = [torch.stack(radii).amax(dim=0)]
        else:
            grads = [g * batch for g in grads]  # the batch-mean loss divided each view's gradient
        for g, seen, r in zip(grads, visible, radii, strict=True):
            state["grad2d"] += torch.where(seen, g.norm(dim=-1), 0.0)
            state["count"] += seen
            state["max_radii"] = torch.maximum(state["max_radii"], torch.where(seen, r, 0.0))

    # -- refinement -------------------------------------------------------------------------------
    @torch.no_grad()
    def _densify_and_prune(self, params, optimizers, state: dict, step: int) -> None:
        extent = state["scene_scale"]
        grads = state["grad2d"] / state["count"].clamp(min=1)  # 0 where never visible (3DGS: NaN -> 0)
        max_scale = torch.exp(params["scales"]).max(dim=1).values
        small = max_scale <= self.percent_dense * extent
        candidates = grads >= self.grad_threshold
        clone, to_split = candidates & small, candidates & ~small
        big_screen = (
            state["max_radii"] > self.prune_screen_size
            if self.prune_screen_size is not None
            else torch.zeros_like(clone)
        )

        ops.duplicate(params, optimizers, clone)
        to_split = torch.cat([to_split, to_split.new_zeros(int(clone.sum()))])
        big_screen = torch.cat([big_screen, big_screen[clone]])
        ops.split(params, optimizers, to_split, self.split_samples, self.split_scale_divisor)
        big_screen = torch.cat([big_screen[~to_split], big_screen[to_split].repeat(self.split_samples)])

        prune = torch.sigmoid(params["opacities"]) < self.prune_opacity
        if step > self.reset_every:
            if self.prune_world_scale is not None:
                prune |= torch.exp(params["scales"]).max(dim=1).values > self.prune_world_scale * extent
            prune |= big_screen
        elif self.prune_after_reset_only:
            prune = torch.zeros_like(prune)
        self._remove_and_record(params, optimizers, state, clone, to_split, prune)

    def _remove_and_record(self, params, optimizers, state, clone, to_split, prune) -> None:
        """Last step of a refinement: drop ``prune``, restart the statistics, record the counts."""
        ops.remove(params, optimizers, prune)
        self._reset_stats(state, params["means"].shape[0], params["means"].detach())
        cloned, split, pruned = torch.stack([clone.sum(), to_split.sum(), prune.sum()]).tolist()  # one read
        state["last_refine"] = {"clone": cloned, "split": split, "prune": pruned}

    def densifies(self, step: int) -> bool:
        """Whether ``step`` (inside the densification window) is a densification step."""
        return step > self.densify_from and step % self.densify_every == 0

    def step_post_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        if step >= self.densify_until:
            return
        self._update_stats(params, state, info)
        if self.densifies(step):
            self._densify_and_prune(params, optimizers, state, step)
        white_start = (
            self.reset_at_densify_from_if_white and state["white_background"] and step == self.densify_from
        )
        if step % self.reset_every == 0 or white_start:
            ops.reset_opacity(params, optimizers, self.reset_value)
