"""Lifting pixel gates back to Gaussians and post-hoc fusion (MoE-GS appendix "Gaussian-Level
Interpretation").

Responsibility of Gaussian ``j`` of expert ``k`` over all pixels ``u`` of the training views::

    R_kj = sum_u G'_k(u) T_kj(u) alpha_kj(u)  /  sum_u T_kj(u) alpha_kj(u)

Both sums come from one backward per view: every Gaussian carries two zero "probe" channels through
expert ``k``'s single-pass composite; the gradient of ``sum_u G'_k(u) probe_0(u) + probe_1(u)`` with
respect to the probes is exactly ``(sum_u G'_k T alpha, sum_u T alpha)``. Gaussians never visible in a
training view get ``R = 0``.

The fused model (``lift``) concatenates every expert's Gaussians at time t with opacity ``R_kj alpha_kj``
and is rendered by the plain 3DGS renderer, without 2D blending.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor
from tqdm.auto import tqdm

from moegs.data.scene import View
from moegs.gaussians import GaussianFrame, cat
from moegs.moe.model import MoEGS
from moegs.moe.splat import expert_inputs, splat_experts
from moegs.render.projection import rgb_to_sh0


def compute_responsibilities(
    model: MoEGS, views: Sequence[View], background, progress: bool = False
) -> list[Tensor]:
    """``R`` per expert (``[N_k]`` each, in [0, 1], on the model's device) over ``views``, kept as
    ``model.responsibilities``."""
    model.eval()
    device = model.device
    background = None if background is None else background.to(device)
    num = [torch.zeros(e.num_gaussians, device=device) for e in model.experts]
    den = [torch.zeros(e.num_gaussians, device=device) for e in model.experts]
    for view in tqdm(views, disable=not progress, desc="lifting gates"):
        camera = view.camera.to(device)
        with torch.no_grad():
            gates = model.render(camera, background).gates  # [K, H, W]
        inputs = expert_inputs(model.experts, camera, background)
        probes = [torch.zeros(len(inp.frame), 2, device=device, requires_grad=True) for inp in inputs]
        splat = splat_experts(
            inputs, camera, extras=probes, single_pass=model.config.single_pass, backend=model.config.backend
        )
        maps = splat.extras  # [K, H, W, 2]
        objective = (gates * maps[..., 0]).sum() + maps[..., 1].sum()
        grads = torch.autograd.grad(objective, probes)
        for k, (expert, g) in enumerate(zip(model.experts, grads, strict=True)):
            rows = expert.frame_rows(camera.time)
            rows = torch.arange(expert.num_gaussians, device=device) if rows is None else rows
            num[k].index_add_(0, rows, g[:, 0])
            den[k].index_add_(0, rows, g[:, 1])
    resp = [
        torch.where(d > 0, n / d.clamp_min(1e-20), torch.zeros_like(n)).clamp(0, 1)
        for n, d in zip(num, den, strict=True)
    ]
    model.responsibilities = resp
    return resp


def _as_sh(frame: GaussianFrame, bases: int) -> GaussianFrame:
    """``frame`` with SH of ``bases`` coefficients (RGB colours become the DC term; higher bands zero)."""
    sh = frame.sh if frame.sh is not None else rgb_to_sh0(frame.colors)[:, None, :]
    if sh.shape[2] != 3:
        raise ValueError(
            f"lift needs RGB experts; an expert splats {sh.shape[2]} channels (STG color='full')"
        )
    sh = torch.nn.functional.pad(sh, (0, 0, 0, bases - sh.shape[1]))
    return replace(frame, sh=sh, colors=None)


@torch.no_grad()
def lift(model: MoEGS, t: float) -> GaussianFrame:
    """The post-hoc fused Gaussians at time ``t``: all experts' frames, opacities scaled by ``R``.

    Needs ``model.responsibilities`` (``compute_responsibilities``; a router checkpoint keeps them
    when they were set before it was written; ``train_router`` does not compute them)."""
    if model.responsibilities is None:
        raise ValueError(
            "lift needs the lifted gate responsibilities: call moegs.moe.compute_responsibilities(model, "
            "scene.train, scene.background) first"
        )
    frames = []
    for expert, resp in zip(model.experts, model.responsibilities, strict=True):
        frame = expert.frame(t)
        rows = expert.frame_rows(t)
        r = (resp if rows is None else resp[rows]).to(frame.opacities)
        frames.append(replace(frame, opacities=frame.opacities * r))
    if len({(f.sh is None, None if f.sh is None else f.sh.shape[1]) for f in frames}) > 1:
        bases = max(1 if f.sh is None else f.sh.shape[1] for f in frames)
        frames = [_as_sh(f, bases) for f in frames]
    return cat(frames)[0]
