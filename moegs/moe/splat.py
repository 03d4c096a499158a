"""Render several frozen experts (and per-Gaussian channels riding on their geometry) for one view.

    inputs = expert_inputs(experts, camera, background)       # no gradient into the experts
    splat = splat_experts(inputs, camera, extras=[w_k ...])    # images [K, H, W, 3], extras [K, H, W, E]

With ``single_pass=True`` the experts are rendered by ``rasterize_multi``: projection and sorting once,
one transmittance per expert (the paper's Single-Pass Multi-Expert Rendering, which the text says leaves
each expert's rendering unchanged; its equation for C_k(u) writes one product over all experts' Gaussians,
which would let one expert occlude another). Experts whose rasterizer
modes differ (Ex4DGS's antialiased 0.1-px dilation vs the 3DGS 0.3-px blur) cannot share one projection;
they are rendered in one pass per mode. Each expert keeps its own clipping planes
(``SplatInputs.near`` / ``far``) inside a shared pass: its Gaussians outside them get zero opacity,
which composites nothing, exactly as culling them does. ``single_pass=False`` renders each expert on
its own, as the authors' code does. Both give the same images (tested).

The weight maps ride on each expert's own pass (its blur mode, its clipping planes). The authors' code
splats them with a separate stock-3DGS rasterizer (``diff_gaussian_rasterization_ch3``: 0.3-px blur,
3DGS culling) over the expert's deformed Gaussians, a second pass per expert (``specs/official_moegs.md``
section 1); for Ex4DGS and STG (0.1-px antialiased mode, near/far 4 / 300) the maps differ at edges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.experts.base import Expert, SplatInputs
from moegs.gaussians import GaussianFrame
from moegs.render import frame_colors, rasterize_multi
from moegs.render.projection import camera_points


@dataclass
class ExpertSplats:
    """``K`` experts rendered for one view.

    Attributes:
        images: decoded RGB ``[K, H, W, 3]`` over each expert's background.
        alphas: accumulated opacity ``[K, H, W]``.
        extras: the per-Gaussian ``extras`` composited per expert ``[K, H, W, E]`` (no background), or None.
        passes: number of rasterizer calls used.
    """

    images: Tensor
    alphas: Tensor
    extras: Tensor | None
    passes: int


@torch.no_grad()
def expert_inputs(experts: Sequence[Expert], camera: Camera, background: Tensor | None) -> list[SplatInputs]:
    """Each expert's rasterizer inputs at ``camera.time``, without gradients (experts are frozen)."""
    return [e.splat_inputs(camera, background) for e in experts]


def _passes(inputs: Sequence[SplatInputs], single_pass: bool) -> list[list[int]]:
    """Expert indices rendered together: one list per rasterizer mode, or one per expert."""
    if not single_pass:
        return [[k] for k in range(len(inputs))]
    modes: dict[bool, list[int]] = {}
    for k, inp in enumerate(inputs):
        modes.setdefault(inp.antialiased, []).append(k)
    return list(modes.values())


def depth_culled(
    frame: GaussianFrame, camera: Camera, near: float | None, far: float | None = None
) -> GaussianFrame:
    """``frame`` with zero opacity where the view depth is ``<= near`` or ``>= far`` (an expert's own
    clipping planes, where tighter than the camera's): the Gaussians its rasterizer would cull composite
    nothing."""
    near = near if near is not None and near > camera.near else None
    far = far if far is not None and far < camera.far else None
    if near is None and far is None:
        return frame
    depth = camera_points(frame.means, camera)[:, 2]  # [N], as the projection culls by it
    keep = torch.ones_like(depth, dtype=torch.bool)
    if near is not None:
        keep &= depth > near
    if far is not None:
        keep &= depth < far
    return replace(frame, opacities=torch.where(keep, frame.opacities, 0.0))


def splat_experts(
    inputs: Sequence[SplatInputs],
    camera: Camera,
    *,
    extras: Sequence[Tensor] | None = None,
    single_pass: bool = True,
    backend: str = "auto",
) -> ExpertSplats:
    """Render the experts of ``inputs`` and composite ``extras[k] [N_k, E]`` with expert ``k``'s weights.

    Colours are resolved per expert (SH evaluated towards the camera) and zero-padded to the widest
    expert (STG's 9 feature channels next to RGB), so one pass serves experts of any colour model; each
    expert's image is then decoded from its own channels.
    """
    if not inputs:
        raise ValueError("splat_experts needs at least one expert")
    if extras is not None and len(extras) != len(inputs):
        raise ValueError(f"extras must hold one tensor per expert ({len(inputs)}), got {len(extras)}")
    k_all = len(inputs)
    images: list[Tensor | None] = [None] * k_all
    alphas: list[Tensor | None] = [None] * k_all
    maps: list[Tensor | None] = [None] * k_all
    groups = _passes(inputs, single_pass)
    for members in groups:
        colors = [frame_colors(inputs[k].frame, camera) for k in members]
        width = max(c.shape[1] for c in colors)
        frames = [
            depth_culled(inputs[k].frame, camera, inputs[k].near, inputs[k].far).with_colors(
                torch.nn.functional.pad(c, (0, width - c.shape[1]))
            )
            for k, c in zip(members, colors, strict=True)
        ]
        backgrounds = torch.stack(
            [
                torch.nn.functional.pad(inputs[k].background, (0, width - inputs[k].background.shape[0]))
                if inputs[k].background is not None
                else colors[0].new_zeros(width)
                for k in members
            ]
        )
        out = rasterize_multi(
            frames,
            camera,
            backgrounds=backgrounds,
            extras=None if extras is None else [extras[k] for k in members],
            antialiased=inputs[members[0]].antialiased,
            return_depth=False,
            backend=backend,
        )
        for j, k in enumerate(members):
            images[k] = inputs[k].decoded(out.images[j, ..., : colors[j].shape[1]])
            alphas[k] = out.alphas[j]
            if out.extras is not None:
                maps[k] = out.extras[j]
    return ExpertSplats(
        images=torch.stack(images),
        alphas=torch.stack(alphas),
        extras=None if extras is None else torch.stack(maps),
        passes=len(groups),
    )


def ray_features(camera: Camera) -> Tensor:
    """r(u): per-pixel ray origin and unit direction ``[6, H, W]`` (the code's ``cam.rays``, no encoding)."""
    origins, dirs = camera.rays()
    return torch.cat([origins, dirs], dim=-1).permute(2, 0, 1)
