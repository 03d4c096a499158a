"""The render pipeline behind ``rasterize`` and ``rasterize_multi``: argument checks, backend choice,
colours -> 3D covariances -> EWA projection -> one compositing call -> expected depth -> background.
See the package docstring (``moegs.render``) for the backends."""

from __future__ import annotations

import contextlib
import contextvars
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cache, partial
from typing import Any

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.gaussians import GaussianFrame
from moegs.render import _cuda
from moegs.render._torch import _composite
from moegs.render.projection import (
    BLUR_3DGS,
    DILATION_ANTIALIASED,
    camera_points,
    covariance_3d,
    eval_sh,
    project,
    view_dirs,
)

BACKENDS = ("auto", "torch", "cpu", "cuda")
_WARNED: set[str] = set()
_VALUE_CHECKS = contextvars.ContextVar("moegs_render_value_checks", default=True)


@contextlib.contextmanager
def value_checks(enabled: bool) -> Iterator[None]:
    """Inside ``with value_checks(False)`` renders skip the checks that read tensor values (finite
    Gaussians and background, opacities in [0, 1], non-zero quaternions): on a GPU each is a wait for the
    device. The training loop skips them between its own finite checks; shapes and devices are always
    checked."""
    token = _VALUE_CHECKS.set(enabled)
    try:
        yield
    finally:
        _VALUE_CHECKS.reset(token)


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes:
        image: ``[H, W, C]``, composited over the background.
        alpha: accumulated opacity ``sum_i T_i alpha_i`` ``[H, W]``.
        depth: expected camera z, ``sum_i T_i alpha_i z_i / alpha`` (0 where alpha == 0) ``[H, W]``,
            or None with ``return_depth=False``.
        info: ``backend`` (the one used); with ``return_stats``: ``radii`` int32 ``[N]``, ``visible``
            bool ``[N]``, ``contrib`` ``[N]`` (sum over pixels of ``T_i alpha_i``, no gradient) and
            ``means2d`` ``[N, 2]`` whose ``.grad`` holds the screen-space gradient after backward (on
            CUDA a leaf filled from gsplat's projected means by a backward hook).
    """

    image: Tensor
    alpha: Tensor
    depth: Tensor | None
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class _Options:
    """The keyword options ``rasterize`` and ``rasterize_multi`` share (documented on ``rasterize``)."""

    sh_degree: int | None = None
    antialiased: bool = False
    eps2d: float | None = None
    return_depth: bool = True
    return_stats: bool = False
    backend: str = "auto"


@dataclass
class _Rendered:
    """``_render`` output for ``G`` groups."""

    images: Tensor  # [G, H, W, C]
    alphas: Tensor  # [G, H, W]
    depths: Tensor | None  # [G, H, W]
    extras: Tensor | None  # [G, H, W, E]
    info: dict[str, Any]


# -- argument checks --------------------------------------------------------------------------------
def _check_frame(frame: GaussianFrame, camera: Camera, what: str) -> None:
    """Shapes, device and finiteness of ``frame``; errors name ``what`` and the field."""
    if not isinstance(frame, GaussianFrame):
        raise TypeError(f"{what} must be a GaussianFrame, got {type(frame).__name__}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a moegs.Camera, got {type(camera).__name__}")
    try:
        frame.validate()
    except ValueError as err:
        raise ValueError(f"{what}: {err}") from None
    if frame.device != camera.device:
        raise ValueError(
            f"{what} is on {frame.device} but the camera is on {camera.device}; move one with .to(device)"
        )
    if _VALUE_CHECKS.get():
        frame.check_values(what)
        frame.check_finite(what)


def _check_tensor(name: str, value: Tensor, shape: tuple[int, ...], like: Tensor) -> Tensor:
    """``value`` with the expected ``shape`` on ``like``'s device, cast to ``like``'s dtype."""
    if not isinstance(value, Tensor):
        raise TypeError(f"{name} must be a tensor of shape {list(shape)}, got {type(value).__name__}")
    if tuple(value.shape) != shape:
        raise ValueError(f"{name} must have shape {list(shape)}, got {list(value.shape)}")
    if value.device != like.device:
        raise ValueError(f"{name} is on {value.device} but the Gaussians are on {like.device}")
    if _VALUE_CHECKS.get() and not torch.isfinite(value).all():
        raise FloatingPointError(f"{name} contains NaN or Inf")
    return value.to(like.dtype)


# -- backends ---------------------------------------------------------------------------------------
@cache
def _cpu_kernel() -> tuple[Any, str]:
    """``(module, "")`` for the compiled CPU kernel, or ``(None, reason)`` when it cannot be used."""
    try:
        from moegs.render import _cpu
    except (ImportError, OSError) as err:
        return None, f"the compiled CPU kernel cannot be imported ({err})"
    is_available = getattr(_cpu, "is_available", None)
    if is_available is None or not is_available():
        detail = getattr(_cpu, "load_error", lambda: None)() or "not built"
        return None, f"the compiled CPU kernel (moegs.render._cpu) is unavailable: {detail}"
    return _cpu, ""


def _fallback(reason: str) -> str:
    if reason not in _WARNED:
        _WARNED.add(reason)
        warnings.warn(
            f"moegs.render: {reason}; falling back to the pure-PyTorch reference rasterizer (exact, slower)",
            RuntimeWarning,
            stacklevel=5,  # the caller of rasterize / rasterize_multi
        )
    return "torch"


def _resolve_backend(backend: str, like: Tensor) -> str:
    """The backend that will run for Gaussians like ``like`` (see module docstring)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid backends: {', '.join(BACKENDS)}")
    device = like.device
    if backend == "auto":
        if device.type == "cuda":
            return (
                "cuda"
                if _cuda.is_available()
                else _fallback(f"gsplat is not installed ({_cuda.INSTALL_HINT})")
            )
        if device.type == "cpu":
            kernel, reason = _cpu_kernel()
            return "cpu" if kernel is not None else _fallback(reason)
        return "torch"
    if backend == "cpu":
        if device.type != "cpu":
            raise ValueError(f"backend='cpu' needs CPU tensors, the frame is on {device}")
        kernel, reason = _cpu_kernel()
        if kernel is None:
            raise RuntimeError(f"backend='cpu': {reason}; use backend='torch' or 'auto'")
    if backend == "cuda":
        _cuda.check(device, like.dtype)
    return backend


def _project_and_composite(
    means,
    covars,
    opacities,
    features,
    camera,
    *,
    kernels,
    groups,
    num_groups,
    eps2d,
    antialiased,
    with_contrib,
):
    """EWA projection + one compositing call; same inputs and outputs as ``_cuda.render``.
    ``kernels``: the module whose ``project`` and ``composite`` run (``_cpu``, or None for the torch
    references)."""
    project_fn, composite = (project, _composite) if kernels is None else (kernels.project, kernels.composite)
    proj = project_fn(means, covars, opacities, camera, eps2d=eps2d, antialiased=antialiased)
    image, alpha, contrib = composite(
        proj.means2d,
        proj.conics,
        proj.opacities,
        features,
        proj.depths,
        proj.radii,
        camera.width,
        camera.height,
        groups,
        num_groups,
    )
    return image, alpha, proj.radii, proj.means2d, contrib if with_contrib else None


def _rasterizer(backend: str):
    if backend == "cuda":
        return _cuda.render
    return partial(_project_and_composite, kernels=_cpu_kernel()[0] if backend == "cpu" else None)


# -- the shared pipeline ----------------------------------------------------------------------------
def frame_colors(frame: GaussianFrame, camera: Camera, sh_degree: int | None = None) -> Tensor:
    """Per-Gaussian channels ``[N, C]``: ``frame.colors``, or SH evaluated towards ``camera``."""
    if frame.sh is None:
        if sh_degree is not None:
            raise ValueError(f"sh_degree={sh_degree} was given but the frame has `colors`, not `sh`")
        return frame.colors
    degree = frame.sh_degree if sh_degree is None else sh_degree
    if not 0 <= degree <= frame.sh_degree:
        raise ValueError(f"sh_degree must be in 0..{frame.sh_degree} for this frame, got {degree}")
    return eval_sh(frame.sh, view_dirs(frame.means, camera), degree)


def _render(
    frame: GaussianFrame,
    camera: Camera,
    options: _Options,
    *,
    groups: Tensor | None = None,  # [N] int64 in [0, num_groups)
    num_groups: int = 1,
    group_sizes: tuple[int, ...] | None = None,  # when ``groups`` is sorted: the size of each group
    backgrounds: Tensor | None = None,  # [G, C], checked
    extra: Tensor | None = None,  # [N, E], checked
) -> _Rendered:
    """Colours -> projection -> one composite for ``num_groups`` groups -> depth -> background."""
    backend = _resolve_backend(options.backend, frame.means)
    colors = frame_colors(frame, camera, options.sh_degree)
    parts = [colors] + ([extra] if extra is not None else [])
    if options.return_depth:
        parts.append(camera_points(frame.means, camera)[:, 2:])
    eps2d = options.eps2d
    if eps2d is None:
        eps2d = DILATION_ANTIALIASED if options.antialiased else BLUR_3DGS
    covariance = _cpu_kernel()[0].covariance_3d if backend == "cpu" else covariance_3d
    rasterizer = _rasterizer(backend)
    if backend == "cuda":
        rasterizer = partial(rasterizer, group_sizes=group_sizes)
    image, alpha, radii, means2d, contrib = rasterizer(
        frame.means,
        covariance(frame.quats, frame.scales),
        frame.opacities,
        torch.cat(parts, dim=1),
        camera,
        groups=groups,
        num_groups=num_groups,
        eps2d=eps2d,
        antialiased=options.antialiased,
        with_contrib=options.return_stats,
    )

    c = colors.shape[1]
    images = image[..., :c]
    if backgrounds is not None:
        images = images + (1.0 - alpha)[..., None] * backgrounds[:, None, None, :]
    extras = image[..., c : c + extra.shape[1]] if extra is not None else None
    depths = None
    if options.return_depth:
        covered = alpha > 0
        depths = torch.where(
            covered, image[..., -1] / torch.where(covered, alpha, torch.ones_like(alpha)), 0.0
        )

    info: dict[str, Any] = {"backend": backend}
    if options.return_stats:
        if means2d.requires_grad and not means2d.is_leaf:
            means2d.retain_grad()
        info.update(radii=radii, visible=radii > 0, contrib=contrib, means2d=means2d)
    return _Rendered(images=images, alphas=alpha, depths=depths, extras=extras, info=info)


def rasterize(
    frame: GaussianFrame,
    camera: Camera,
    *,
    background: Tensor | None = None,
    sh_degree: int | None = None,
    antialiased: bool = False,
    eps2d: float | None = None,
    return_depth: bool = True,
    return_stats: bool = False,
    backend: str = "auto",
) -> RenderOutput:
    """Render ``frame`` (``N`` Gaussians, ``C`` channels) as seen by ``camera``.

    Args:
        frame: activated Gaussians; ``colors [N, C]`` (any C) or ``sh [N, B, C]``.
        camera: the view; must be on the frame's device.
        background: ``[C]`` composited with weight ``1 - alpha``; None = black.
        sh_degree: SH degree to evaluate (default: all of the frame's bases); only for ``sh`` frames.
        antialiased: Mip-Splatting / Ex4DGS 2D filter with opacity compensation.
        eps2d: pixels² added to the 2D covariance diagonal; default 0.3 (3DGS), or 0.1 (Ex4DGS)
            when ``antialiased``.
        return_depth: also composite camera z and return the expected depth.
        return_stats: add ``radii``, ``visible``, ``contrib`` and ``means2d`` to ``info``.
        backend: one of ``BACKENDS`` (see module docstring).

    Returns:
        RenderOutput with image ``[H, W, C]``, alpha ``[H, W]``, depth ``[H, W]`` or None, info.
    """
    _check_frame(frame, camera, "frame")
    backgrounds = None
    if background is not None:
        backgrounds = _check_tensor("background", background, (frame.num_channels,), frame.means)[None]
    options = _Options(sh_degree, antialiased, eps2d, return_depth, return_stats, backend)
    out = _render(frame, camera, options, backgrounds=backgrounds)
    depth = out.depths[0] if out.depths is not None else None
    return RenderOutput(image=out.images[0], alpha=out.alphas[0], depth=depth, info=out.info)
