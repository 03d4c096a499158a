"""gsplat's ``rasterization`` on CPU tensors, through gsplat's own pure-PyTorch kernels (tests only).

gsplat (``pip install gsplat``, pure Python) ships torch references of its CUDA kernels in
``gsplat.cuda._torch_impl`` and a torch version of the whole call, ``gsplat.rendering._rasterization``.
That path still reaches three things that need CUDA or another package; :func:`install` swaps them
for short torch equivalents written here from gsplat's documented semantics:

* ``isect_tiles`` / ``isect_offset_encode`` (CUDA wrappers) -> ``isect_tiles`` below
  (``_torch_impl._isect_tiles`` vectorised: the original loops over Gaussians and tiles in Python;
  same output, tested) and the ``_torch_impl`` offset encoder;
* ``rasterize_to_indices_in_range`` (CUDA only): per pixel, in depth order, the Gaussians with
  ``alpha = min(0.999, o exp(-sigma)) >= 1/255`` (``sigma >= 0``) until ``T (1 - alpha) <= 1e-4``;
* nerfacc's ``render_weight_from_alpha`` and ``accumulate_along_rays``.

``gsplat.rasterization`` is then replaced by a function that accepts ``covars`` (what ``moegs`` passes) and
runs ``_rasterization`` with those covariances. ``_indices_in_range`` loops over tiles, so keep scenes
small.
"""

from __future__ import annotations

import math
import sys
import types

import pytest
import torch
from torch import Tensor

BLOCK = 16  # gsplat's default tile size


def _indices_in_range(
    range_start, range_end, transmittances, means2d, conics, opacities, width, height, tile_size,
    isect_offsets, flatten_ids,
):  # fmt: skip
    """Torch twin of ``gsplat.cuda._wrapper.rasterize_to_indices_in_range`` (gsplat 1.5 semantics).

    Returns ``(gaussian_ids, pixel_ids, image_ids)`` sorted by image, pixel, then depth.
    """
    images = means2d.shape[:-2]
    n = means2d.shape[-2]
    count = math.prod(images)
    offsets = isect_offsets.reshape(count, -1)
    ends = torch.cat([offsets.flatten()[1:], offsets.new_tensor([len(flatten_ids)])]).reshape(count, -1)
    trans = transmittances.reshape(count, height, width)
    block = tile_size * tile_size
    tiles_x = isect_offsets.shape[-1]
    found = []
    for image in range(count):
        for tile in range(offsets.shape[1]):
            lo = int(offsets[image, tile]) + range_start * block
            hi = min(int(ends[image, tile]), int(offsets[image, tile]) + range_end * block)
            if hi <= lo:
                continue
            flat = flatten_ids[lo:hi].long()  # [M] indices into image * n + gaussian, near to far
            gauss = flat % n
            ty, tx = divmod(tile, tiles_x)
            ys, xs = torch.meshgrid(
                torch.arange(ty * tile_size, min((ty + 1) * tile_size, height)),
                torch.arange(tx * tile_size, min((tx + 1) * tile_size, width)),
                indexing="ij",
            )
            ys, xs = ys.flatten(), xs.flatten()  # [P]
            d = torch.stack([xs + 0.5, ys + 0.5], -1)[:, None] - means2d.reshape(count, n, 2)[image, gauss]
            c = conics.reshape(count, n, 3)[image, gauss]
            sigma = (
                0.5 * (c[:, 0] * d[..., 0] ** 2 + c[:, 2] * d[..., 1] ** 2) + c[:, 1] * d[..., 0] * d[..., 1]
            )
            alpha = torch.clamp_max(opacities.reshape(count, n)[image, gauss] * torch.exp(-sigma), 0.999)
            used = (sigma >= 0) & (alpha >= 1.0 / 255.0)  # [P, M]
            t_after = trans[image, ys, xs][:, None] * torch.cumprod(1 - alpha * used, dim=1)
            used &= t_after > 1e-4
            pix, k = torch.nonzero(used, as_tuple=True)  # row-major: by pixel, then depth order
            found.append((gauss[k], ys[pix] * width + xs[pix], torch.full_like(pix, image)))
    if not found:
        empty = torch.zeros(0, dtype=torch.long)
        return empty, empty, empty
    gs, px, im = (torch.cat(parts) for parts in zip(*found, strict=True))
    order = torch.argsort(im * height * width + px, stable=True)
    return gs[order], px[order], im[order]


@torch.no_grad()
def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, **_):
    """``_torch_impl._isect_tiles`` without its Python loops: ``(tiles_per_gauss [..., N], isect_ids [M],
    flatten_ids [M])``, ids = image | tile | depth bits, sorted."""
    images = means2d.shape[:-2]
    n = means2d.shape[-2]
    count = math.prod(images)
    lo = torch.floor(means2d.reshape(count, n, 2) / tile_size - radii.reshape(count, n, 2) / tile_size).int()
    hi = torch.ceil(means2d.reshape(count, n, 2) / tile_size + radii.reshape(count, n, 2) / tile_size).int()
    limits = torch.tensor([tile_width, tile_height], dtype=torch.int32)
    lo, hi = torch.minimum(lo.clamp(min=0), limits), torch.minimum(hi.clamp(min=0), limits)
    span = hi - lo  # [I, N, 2]
    per_gauss = span.prod(-1) * (radii.reshape(count, n, 2) > 0).all(-1)
    counts = per_gauss.flatten().long()
    flat = torch.repeat_interleave(torch.arange(count * n), counts)  # image * n + gaussian, per pair
    local = torch.arange(len(flat)) - (torch.cumsum(counts, 0) - counts)[flat]
    width = span.reshape(-1, 2)[flat, 0].long()
    x = lo.reshape(-1, 2)[flat, 0].long() + local % width
    y = lo.reshape(-1, 2)[flat, 1].long() + local // width
    tile_bits = (tile_width * tile_height).bit_length()
    depth_bits = depths.reshape(-1)[flat].float().view(torch.int32).long() & 0xFFFFFFFF
    ids = ((flat // n) << (tile_bits + 32)) | ((y * tile_width + x) << 32) | depth_bits
    ids, order = torch.sort(ids)
    return per_gauss.reshape(*images, n).int(), ids, flat[order].int()


def _render_weight_from_alpha(alphas: Tensor, ray_indices: Tensor, n_rays: int):
    """nerfacc: ``weights = alpha_i prod_{j<i} (1 - alpha_j)`` along each ray (samples grouped by ray)."""
    log_keep = torch.log1p(-alphas.double())
    total = torch.cumsum(log_keep, 0)
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    before = torch.cummax(torch.where(first, torch.arange(len(alphas)), 0), 0).values  # start of each ray
    excl = total - log_keep - (total - log_keep)[before]
    trans = torch.exp(excl).to(alphas.dtype)
    return alphas * trans, trans


def _accumulate_along_rays(weights: Tensor, values: Tensor | None, ray_indices: Tensor, n_rays: int):
    """nerfacc: ``sum_i w_i v_i`` per ray (``v = 1`` when ``values`` is None)."""
    src = weights[:, None] if values is None else weights[:, None] * values
    return src.new_zeros(n_rays, src.shape[1]).index_add(0, ray_indices, src)


def install(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """Patch gsplat (skipping the test when it is missing) so ``gsplat.rasterization`` runs on CPU."""
    gsplat = pytest.importorskip(
        "gsplat", reason="gsplat not installed (test extra: pip install 'moegs[test]')"
    )
    import gsplat.cuda._torch_impl as impl
    import gsplat.cuda._wrapper as wrapper
    import gsplat.rendering as rendering

    nerfacc = types.ModuleType("nerfacc")
    nerfacc.render_weight_from_alpha = _render_weight_from_alpha
    nerfacc.accumulate_along_rays = _accumulate_along_rays
    monkeypatch.setitem(sys.modules, "nerfacc", nerfacc)
    monkeypatch.setattr(wrapper, "rasterize_to_indices_in_range", _indices_in_range)
    monkeypatch.setattr(rendering, "isect_tiles", isect_tiles)
    monkeypatch.setattr(
        rendering, "isect_offset_encode", lambda ids, n, tw, th: impl._isect_offset_encode(ids, n, tw, th)
    )

    def rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, *, covars, **kw):
        assert quats is None and scales is None and kw.pop("packed") is False
        with monkeypatch.context() as patch:  # _rasterization builds covars from quats/scales: give ours
            patch.setattr(impl, "_quat_scale_to_covar_preci", lambda *a, **k: (covars, None))
            dummy = means.new_zeros(*means.shape[:-1], 4)
            return rendering._rasterization(
                means, dummy, dummy[..., :3], opacities, colors, viewmats, Ks, width, height, tile_size=BLOCK,
                **kw,
            )  # fmt: skip

    monkeypatch.setattr(gsplat, "rasterization", rasterization)
    return gsplat


def install_cpu_glue(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """:func:`install`, and ``moegs.render._cuda`` accepting CPU tensors: ``backend="cuda"`` then runs our
    CUDA glue with gsplat's torch kernels on the CPU (the CUDA code path of rendering and training)."""
    from moegs.render import _cuda

    module = install(monkeypatch)
    check = _cuda.check
    monkeypatch.setattr(_cuda, "check", lambda device, dtype: check(torch.device("cuda"), dtype))
    monkeypatch.setattr(_cuda, "is_installed", lambda: True)
    return module
