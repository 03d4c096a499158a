"""gsplat on CUDA tensors only (``pip install 'moegs[cuda]'``, torch installed first).

``render`` takes the same inputs as the CPU pipeline after colour evaluation: world means, our own
3D covariances (passed to gsplat as ``covars``, so quaternions keep the semantics of
``projection.covariance_3d``), opacities and any number of feature channels. gsplat does the
projection and the tile compositing; ``gsplat.rasterization`` is called with ``packed=False``,
``sh_degree=None``, the same ``eps2d`` and ``rasterize_mode="antialiased"`` in antialiased mode.

It matches the torch reference only to a tolerance. Differences from ``_torch.py``:

* alpha clamp 0.999 (gsplat) instead of 0.99 (3DGS, ``_torch.ALPHA_MAX``);
* gsplat stops a pixel when ``T (1 - alpha) <= 1e-4`` (ours: ``< 1e-4``);
* screen radius: gsplat uses per-axis radii ``ceil(e sqrt(cov_ii))`` with ``e = 3.33`` or, in recent
  versions, ``e = min(3.33, sqrt(2 ln(255 opacity)))``, instead of 3DGS's ``ceil(3 sqrt(lambda_max))``
  with the 0.1 eigen-gap floor; it also culls opacity (x compensation) < 1/255, which changes only
  ``visible`` since such splats never pass the alpha cut;
* tiles: gsplat evaluates a Gaussian at every pixel of the 16x16 tiles its radius touches, not only
  inside its ``[mean - r, mean + r]`` box, so faint tails (alpha >= 1/255) can reach a few more pixels;
* culling: gsplat keeps ``near <= z <= far`` (ours: ``near < z < far``).

Never call gsplat with CPU tensors: it then tries to JIT-build its CUDA extension and fails with a
misleading ``ImportError`` about ``gsplat_cuda.so`` (``specs/cpu_feasibility.md``).

Groups (experts in single-pass rendering) become one gsplat call per group on that group's
Gaussians, since gsplat keeps one transmittance per image. ``means2d`` is a leaf ``[N, 2]`` whose
``.grad`` is filled during backward from gsplat's own projected means, and ``contrib`` is the
gradient of the summed image of an all-ones channel with respect to that channel (``sum_pixels w_i``),
which costs one extra backward through the rasterizer; it is computed only when asked for.
"""

from __future__ import annotations

import importlib.util
from functools import cache

import torch
from torch import Tensor

from moegs.camera import Camera

INSTALL_HINT = "pip install 'moegs[cuda]' (install torch first, or gsplat pulls a CUDA torch)"


@cache
def is_installed() -> bool:
    return importlib.util.find_spec("gsplat") is not None


def is_available() -> bool:
    """gsplat is installed and CUDA is usable."""
    return is_installed() and torch.cuda.is_available()


def check(device: torch.device, dtype: torch.dtype) -> None:
    """Raise a clear error unless tensors on ``device`` with ``dtype`` can go to gsplat."""
    if device.type != "cuda":
        raise ValueError(
            f"backend='cuda' needs CUDA tensors, the frame is on {device}; move it with frame.to('cuda') "
            "or use backend='auto'. (gsplat is never called with CPU tensors: it would try to JIT-build "
            "its CUDA extension and fail with a misleading ImportError.)"
        )
    if not is_installed():
        raise ImportError(f"backend='cuda' needs gsplat, which is not installed: {INSTALL_HINT}")
    if dtype != torch.float32:
        raise TypeError(f"backend='cuda' (gsplat) needs float32 Gaussians, got {dtype}")


def _route_grad(source: Tensor, probe: Tensor, index: Tensor) -> None:
    """During backward, add the gradient of ``source`` ``[1, n, 2]`` into ``probe.grad[index]``."""

    def hook(grad: Tensor) -> None:
        if probe.grad is None:
            probe.grad = torch.zeros_like(probe)
        probe.grad.index_add_(0, index, grad.reshape(-1, 2))

    source.register_hook(hook)


def _render_group(means, covars, opacities, features, camera, eps2d, antialiased, with_contrib):
    """One gsplat call on ``n`` Gaussians.

    Returns image ``[H, W, D]``, alpha ``[H, W]``, radii int32 ``[n]``, gsplat's means2d ``[1, n, 2]``
    and contrib ``[n]`` (or None).
    """
    import gsplat  # optional dependency, imported only for CUDA tensors

    n = len(means)
    inputs = (means, covars, opacities, features)
    keep_graph = torch.is_grad_enabled() and any(t.requires_grad for t in inputs)
    ones = torch.ones(n, 1, dtype=features.dtype, device=features.device, requires_grad=with_contrib)
    with torch.set_grad_enabled(keep_graph or with_contrib):
        image, alpha, meta = gsplat.rasterization(
            means, None, None, opacities, torch.cat([features, ones], dim=1),
            camera.world_to_camera[None].to(means), camera.K[None].to(means), camera.width, camera.height,
            near_plane=camera.near, far_plane=camera.far, eps2d=eps2d, sh_degree=None, packed=False,
            render_mode="RGB", rasterize_mode="antialiased" if antialiased else "classic", covars=covars,
        )  # fmt: skip
        contrib = None
        if with_contrib:
            (grad_ones,) = torch.autograd.grad(image[..., -1].sum(), ones, retain_graph=keep_graph)
            contrib = grad_ones[:, 0]
    if not keep_graph:
        image, alpha = image.detach(), alpha.detach()
    per_axis = meta["radii"].reshape(n, -1)  # [1, n] (gsplat < 1.5) or [1, n, 2]
    radii = torch.where((per_axis > 0).all(-1), per_axis.amax(-1), 0).to(torch.int32)
    return image[0, ..., :-1], alpha[0, ..., 0], radii, meta["means2d"], contrib


def render(
    means: Tensor,  # [N, 3]
    covars: Tensor,  # [N, 3, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    camera: Camera,
    *,
    groups: Tensor | None,  # [N] int64 in [0, num_groups)
    num_groups: int,
    eps2d: float,
    antialiased: bool,
    with_contrib: bool,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Rasterize with gsplat, one call per group.

    Returns:
        image ``[G, H, W, D]``, alpha ``[G, H, W]``, radii int32 ``[N]``, means2d ``[N, 2]`` (a leaf whose
        ``.grad`` is the screen-space gradient after backward), contrib ``[N]`` or None.
    """
    check(means.device, means.dtype)
    n, d = features.shape
    groups = torch.zeros(n, dtype=torch.long, device=means.device) if groups is None else groups
    radii = torch.zeros(n, dtype=torch.int32, device=means.device)
    contrib = features.new_zeros(n) if with_contrib else None
    probe = torch.zeros(n, 2, dtype=means.dtype, device=means.device, requires_grad=True)
    images, alphas = [], []
    for g in range(num_groups):
        index = torch.nonzero(groups == g).squeeze(1)
        if index.numel() == 0:
            images.append(features.new_zeros(camera.height, camera.width, d))
            alphas.append(features.new_zeros(camera.height, camera.width))
            continue
        image, alpha, radii_g, means2d, contrib_g = _render_group(
            means[index],
            covars[index],
            opacities[index],
            features[index],
            camera,
            eps2d,
            antialiased,
            with_contrib,
        )
        radii[index] = radii_g
        if with_contrib:
            contrib[index] = contrib_g
        if means2d.requires_grad:
            _route_grad(means2d, probe, index)
        images.append(image)
        alphas.append(alpha)
    return torch.stack(images), torch.stack(alphas), radii, probe, contrib
