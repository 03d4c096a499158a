"""gsplat on CUDA tensors only (``pip install 'moegs[cuda]'``, torch installed first).

``render`` takes the same inputs as the CPU pipeline after colour evaluation: world means, our own
3D covariances (passed to gsplat as ``covars``, so quaternions keep the semantics of
``projection.covariance_3d``), opacities and any number of feature channels. gsplat does the
projection and the tile compositing; ``gsplat.rasterization`` is called with ``packed=False``,
``sh_degree=None``, the same ``eps2d`` and ``rasterize_mode="antialiased"`` in antialiased mode.

It matches the torch reference only to a tolerance. Differences from ``_torch.py``:

* alpha clamp 0.999 (gsplat) instead of 0.99 (3DGS, ``_torch.ALPHA_MAX``);
* gsplat stops a pixel when ``T (1 - alpha) <= 1e-4`` (ours: ``< 1e-4``);
* screen radius: gsplat 1.5 (``rasterization`` passes the opacities) uses per-axis radii
  ``ceil(e sqrt(cov_ii))`` with ``e = min(3.33, sqrt(2 ln(255 opacity)))`` and culls opacity
  (x compensation) < 1/255, which changes only ``visible`` since such splats never pass the alpha cut;
  gsplat 1.4 uses one radius ``ceil(3 sqrt(lambda_max))`` with a 0.01 floor under the eigen-gap and
  no opacity cull; 3DGS: ``ceil(3 sqrt(lambda_max))`` with the 0.1 floor;
* tiles: gsplat evaluates a Gaussian at every pixel of the 16x16 tiles its radius touches, not only
  inside its ``[mean - r, mean + r]`` box, so faint tails (alpha >= 1/255) can reach a few more pixels;
* culling: gsplat keeps ``near <= z <= far`` (ours: ``near < z < far``).

Never call gsplat with CPU tensors: it then tries to JIT-build its CUDA extension and fails with a
misleading ``ImportError`` about ``gsplat_cuda.so`` (``specs/cpu_feasibility.md``).

Groups (experts in single-pass rendering) become gsplat's batch dimension: one call renders every
group, each padded to the largest with invisible Gaussians, and gsplat keeps one transmittance per
image, so group ``g``'s image equals its own render. ``means2d`` is a leaf ``[N, 2]`` whose
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


# gsplat 1.5's fused projection backward sums the gradients of one warp's threads that hold the same
# Gaussian index, whatever their batch: with batches of fewer than 32 Gaussians, Gaussian i of one group
# takes the gradient of Gaussian i of the next (measured on an H100, gsplat 1.5.3: the means gradient of a
# 25-Gaussian group was off by up to 1.6 where 9- and 17-Gaussian groups followed it; a fix of the same
# defect in the packed path is proposed in gsplat PR 1059, open when this was written). Padding every
# group of a multi-group call to at least a warp keeps one batch per Gaussian index inside any warp.
MIN_GROUP_WIDTH = 32


def _padded_layout(
    groups: Tensor, num_groups: int, sizes: tuple[int, ...] | None = None
) -> tuple[Tensor, int]:
    """Where each Gaussian goes when the groups are padded to one batch ``[G, M]``.

    Returns ``slot [N]`` (flat index into ``G * M``, stable within a group) and ``M``: the largest group,
    at least ``MIN_GROUP_WIDTH`` when there are several groups. ``sizes``, the size of each group when
    ``groups`` is sorted (``moegs.gaussians.cat``), spares reading the counts back from the device.
    """
    minimum = MIN_GROUP_WIDTH if num_groups > 1 else 1
    if sizes is not None:
        width = max(max(sizes, default=0), minimum)
        starts = torch.tensor([sum(sizes[:g]) for g in range(num_groups)], device=groups.device)
        index = torch.arange(len(groups), device=groups.device)
        return groups * width + index - starts[groups], width
    counts = torch.bincount(groups, minlength=num_groups)
    width = max(int(counts.max()), minimum)
    order = torch.argsort(groups, stable=True)
    starts = torch.cumsum(counts, 0) - counts
    rank = torch.empty_like(groups)
    rank[order] = torch.arange(len(groups), device=groups.device) - starts[groups[order]]
    return groups * width + rank, width


def _pad(values: Tensor, slot: Tensor, num_groups: int, width: int, fill: Tensor) -> Tensor:
    """``values [N, ...]`` scattered to ``[G, M, ...]`` at ``slot``; empty slots hold ``fill [...]``."""
    padded = fill.expand(num_groups * width, *values.shape[1:]).contiguous().index_copy(0, slot, values)
    return padded.reshape(num_groups, width, *values.shape[1:])


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
    group_sizes: tuple[int, ...] | None = None,  # the size of each group when ``groups`` is sorted
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Rasterize with ONE gsplat call: the groups become its batch dimension.

    Each group is padded to the largest group with Gaussians of zero opacity one unit behind the camera
    (gsplat culls them before any tile work); every group keeps its own transmittance.

    Returns:
        image ``[G, H, W, D]``, alpha ``[G, H, W]``, radii int32 ``[N]``, means2d ``[N, 2]`` (a leaf whose
        ``.grad`` is the screen-space gradient after backward), contrib ``[N]`` or None.
    """
    import gsplat  # optional dependency, imported only for CUDA tensors

    check(means.device, means.dtype)
    n, d = features.shape
    if groups is None:
        groups, group_sizes = torch.zeros(n, dtype=torch.long, device=means.device), (n,)
    slot, width = _padded_layout(groups, num_groups, group_sizes)
    w2c = camera.world_to_camera.to(means)
    behind = w2c[:3, :3].T @ (means.new_tensor([0.0, 0.0, -1.0]) - w2c[:3, 3])  # camera point (0, 0, -1)

    def pad(values: Tensor, fill: Tensor) -> Tensor:
        return _pad(values, slot, num_groups, width, fill.to(values))

    ones = torch.ones(n, 1, dtype=features.dtype, device=features.device, requires_grad=with_contrib)
    inputs = (means, covars, opacities, features)
    keep_graph = torch.is_grad_enabled() and any(t.requires_grad for t in inputs)
    with torch.set_grad_enabled(keep_graph or with_contrib):
        image, alpha, meta = gsplat.rasterization(
            pad(means, behind), None, None, pad(opacities, means.new_zeros(())),
            pad(torch.cat([features, ones], dim=1), means.new_zeros(())),
            w2c.expand(num_groups, 1, 4, 4),
            camera.K.to(means).expand(num_groups, 1, 3, 3), camera.width, camera.height,
            near_plane=camera.near, far_plane=camera.far, eps2d=eps2d, sh_degree=None, packed=False,
            render_mode="RGB", rasterize_mode="antialiased" if antialiased else "classic",
            covars=pad(covars, torch.eye(3, device=means.device)),
        )  # fmt: skip
        contrib = None
        if with_contrib:
            (grad_ones,) = torch.autograd.grad(image[..., -1].sum(), ones, retain_graph=keep_graph)
            contrib = grad_ones[:, 0]
    if not keep_graph:
        image, alpha = image.detach(), alpha.detach()
    per_axis = meta["radii"].reshape(num_groups * width, -1)[slot]  # [N, 1] (gsplat < 1.5) or [N, 2]
    radii = torch.where((per_axis > 0).all(-1), per_axis.amax(-1), 0).to(torch.int32)
    probe = torch.zeros(n, 2, dtype=means.dtype, device=means.device, requires_grad=True)
    if meta["means2d"].requires_grad:
        _route_grad(meta["means2d"], probe, slot)
    return image[:, 0, ..., :-1], alpha[:, 0, ..., 0], radii, probe, contrib


def _route_grad(source: Tensor, probe: Tensor, slot: Tensor) -> None:
    """During backward, add rows ``slot`` of the gradient of ``source [G, 1, M, 2]`` to ``probe.grad``."""

    def hook(grad: Tensor) -> None:
        if probe.grad is None:
            probe.grad = torch.zeros_like(probe)
        probe.grad += grad.reshape(-1, 2)[slot]

    source.register_hook(hook)
