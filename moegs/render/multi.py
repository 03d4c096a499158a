"""Single-pass multi-expert rendering (MoE-GS eq. for ``C_k(u)``).

The experts' frames are concatenated (``moegs.gaussians.cat``), projected once and composited in ONE
call with ``groups = expert_id``: every expert keeps its own transmittance, so expert ``k``'s image
equals its separate ``rasterize`` while projection and sorting are shared.

Routers splat per-Gaussian routing weights with the same geometry: pass them as ``extras`` (one
``[N_k, E]`` tensor per frame) to get per-expert weight maps from the same pass, or render frames
whose ``colors`` are the weights (``frame.with_colors(w)``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.gaussians import GaussianFrame, cat
from moegs.render.pipeline import _check_frame, _check_tensor, _Options, _render


@dataclass
class MultiRenderOutput:
    """``K`` experts rendered in one pass.

    Attributes:
        images: ``[K, H, W, C]``, each over its background.
        alphas: ``[K, H, W]``.
        depths: expected depth per expert ``[K, H, W]`` (0 where alpha == 0), or None.
        extras: the ``extras`` channels composited per expert ``[K, H, W, E]`` (no background), or None.
        info: ``backend``; with ``return_stats`` the per-Gaussian statistics of ``rasterize`` over the
            concatenated Gaussians plus ``expert_id`` int64 ``[N_total]``.
    """

    images: Tensor
    alphas: Tensor
    depths: Tensor | None
    extras: Tensor | None = None
    info: dict[str, Any] = field(default_factory=dict)


def _backgrounds(backgrounds: Tensor | None, k: int, c: int, like: Tensor) -> Tensor | None:
    """``[K, C]`` from None, a shared ``[C]`` or per-expert ``[K, C]`` backgrounds."""
    if backgrounds is None:
        return None
    if isinstance(backgrounds, Tensor) and backgrounds.ndim == 1:
        return _check_tensor("backgrounds", backgrounds, (c,), like).expand(k, c)
    return _check_tensor("backgrounds", backgrounds, (k, c), like)


def _joint_extras(extras: Sequence[Tensor], frames: Sequence[GaussianFrame], like: Tensor) -> Tensor:
    """Concatenate one ``[N_k, E]`` tensor per frame into ``[N_total, E]``."""
    if len(extras) != len(frames):
        raise ValueError(f"extras must hold one tensor per frame ({len(frames)}), got {len(extras)}")
    first = extras[0]
    if not isinstance(first, Tensor) or first.ndim != 2:
        raise ValueError(
            f"extras[0] must have shape [{len(frames[0])}, E], got {getattr(first, 'shape', first)}"
        )
    e = first.shape[1]
    return torch.cat(
        [
            _check_tensor(f"extras[{k}]", x, (len(f), e), like)
            for k, (f, x) in enumerate(zip(frames, extras, strict=True))
        ]
    )


def rasterize_multi(
    frames: Sequence[GaussianFrame],
    camera: Camera,
    *,
    backgrounds: Tensor | None = None,
    extras: Sequence[Tensor] | None = None,
    sh_degree: int | None = None,
    antialiased: bool = False,
    eps2d: float | None = None,
    return_depth: bool = True,
    return_stats: bool = False,
    backend: str = "auto",
) -> MultiRenderOutput:
    """Render ``K`` expert frames in a single pass with one transmittance per expert.

    Args:
        frames: ``K`` frames with the same colour representation (see ``moegs.gaussians.cat``).
        camera: the shared view.
        backgrounds: ``[C]`` for every expert or ``[K, C]``; None = black.
        extras: optional per-frame channels ``[N_k, E]`` (e.g. routing weights) composited with the
            same weights, returned in ``extras``.
        sh_degree, antialiased, eps2d, return_depth, return_stats, backend: as in ``rasterize``.

    Returns:
        MultiRenderOutput; ``images[k]``, ``alphas[k]``, ``depths[k]`` equal ``rasterize(frames[k])``.
    """
    for k, frame in enumerate(frames):
        _check_frame(frame, camera, f"frames[{k}]")
    joint, expert_id = cat(list(frames))
    extra = None if extras is None else _joint_extras(extras, frames, joint.means)
    out = _render(
        joint,
        camera,
        _Options(sh_degree, antialiased, eps2d, return_depth, return_stats, backend),
        groups=expert_id,
        num_groups=len(frames),
        group_sizes=tuple(len(f) for f in frames),
        backgrounds=_backgrounds(backgrounds, len(frames), joint.num_channels, joint.means),
        extra=extra,
    )
    if return_stats:
        out.info["expert_id"] = expert_id
    return MultiRenderOutput(
        images=out.images, alphas=out.alphas, depths=out.depths, extras=out.extras, info=out.info
    )
