"""Compiled CPU compositing and projection (``moegs/kernels/raster.c``, ``project.c``; C + OpenMP via
ctypes), forward and backward.

``composite`` has exactly the signature, return values and maths of
:func:`moegs.render._torch._composite` (see that module's docstring for the contract); it is the
fast CPU path, ``_torch._composite`` is the oracle it is tested against. ``covariance_3d`` and
``project`` are those of :mod:`moegs.render.projection` for float32 inputs: their forwards equal the
references to the bit (radii included), their backwards are the chain rule of the same graphs. Every
buffer is a torch tensor allocated here and passed to C as a raw pointer. If the compiled library is
missing or stale, ``is_available()`` is False and ``load_error()`` says why (:mod:`moegs.kernels`);
callers fall back to the references.

Results are deterministic and bit-identical for any thread count (per-Gaussian sums go through
per-(tile, Gaussian) slots reduced in a fixed order). ``composite``'s outputs are float32 whatever the
input dtype; ``covariance_3d`` and ``project`` hand other dtypes to the references.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from moegs.camera import Camera
from moegs.kernels import check as _check
from moegs.kernels import is_available, library, library_path, load_error
from moegs.render import projection as _reference
from moegs.render.projection import BLUR_3DGS, Projection

__all__ = ["composite", "covariance_3d", "project", "is_available", "load_error", "library_path", "TILE_SIZE"]

TILE_SIZE = 16  # pixels per tile side; only affects speed, never the result (8 and 16 measured within 5%)


def _ptr(t: Tensor | None) -> int | None:
    return None if t is None or t.numel() == 0 else t.data_ptr()


class _Composite(torch.autograd.Function):
    """Autograd wrapper; inputs are already contiguous float32 / int32 / int64 CPU tensors."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, radii, groups, order, width, height, num_groups):
        lib = library()
        n, d = colors.shape
        g, tile, threads = num_groups, TILE_SIZE, torch.get_num_threads()
        ntiles = -(-width // tile) * -(-height // tile)
        geo = torch.empty(n, 8, dtype=torch.float32, device="cpu")
        box = torch.empty(n, 4, dtype=torch.int32, device="cpu")
        grp = torch.empty(n, dtype=torch.int32, device="cpu")
        col = torch.empty(n, d, dtype=torch.float32, device="cpu")
        gstart = torch.empty(n + 1, dtype=torch.int64, device="cpu")
        tile_off = torch.empty(ntiles + 1, dtype=torch.int64, device="cpu")
        total = lib.moegs_prepare(
            n, d, g, width, height, tile, threads, _ptr(order), _ptr(means2d), _ptr(conics),
            _ptr(opacities), _ptr(colors), _ptr(radii), _ptr(groups),
            _ptr(geo), _ptr(box), _ptr(grp), _ptr(col), gstart.data_ptr(), tile_off.data_ptr(),
        )  # fmt: skip
        _check(total, "prepare")
        lists = torch.empty(total, dtype=torch.int32, device="cpu")
        pairpos = torch.empty(total, dtype=torch.int64, device="cpu")
        image = torch.empty(g, height, width, d, dtype=torch.float32, device="cpu")
        alpha = torch.empty(g, height, width, dtype=torch.float32, device="cpu")
        contrib = torch.empty(n, dtype=torch.float32, device="cpu")
        tfinal = torch.empty(g, height, width, dtype=torch.float64, device="cpu")
        last = torch.empty(g, height, width, dtype=torch.int32, device="cpu")
        code = lib.moegs_forward(
            n, d, g, width, height, tile, threads, _ptr(order), _ptr(geo), _ptr(box), _ptr(grp),
            _ptr(col), gstart.data_ptr(), tile_off.data_ptr(), total, _ptr(lists), _ptr(pairpos),
            image.data_ptr(), alpha.data_ptr(), _ptr(contrib), tfinal.data_ptr(), last.data_ptr(),
        )  # fmt: skip
        _check(code, "forward")
        ctx.save_for_backward(order, geo, box, grp, col, gstart, tile_off, lists, pairpos, tfinal, last)
        ctx.dims = (n, d, g, width, height, tile, total)
        ctx.mark_non_differentiable(contrib)
        return image, alpha, contrib

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_image, grad_alpha, _grad_contrib):
        lib = library()
        order, geo, box, grp, col, gstart, tile_off, lists, pairpos, tfinal, last = ctx.saved_tensors
        n, d, g, width, height, tile, total = ctx.dims
        grad_image = grad_image.to(torch.float32).contiguous()
        grad_alpha = grad_alpha.to(torch.float32).contiguous()
        gm = torch.empty(n, 2, dtype=torch.float32, device="cpu")
        gc = torch.empty(n, 3, dtype=torch.float32, device="cpu")
        go = torch.empty(n, dtype=torch.float32, device="cpu")
        gcol = torch.empty(n, d, dtype=torch.float32, device="cpu")
        code = lib.moegs_backward(
            n, d, g, width, height, tile, torch.get_num_threads(), _ptr(order), _ptr(geo), _ptr(box),
            _ptr(grp), _ptr(col), gstart.data_ptr(), tile_off.data_ptr(), total, _ptr(lists),
            _ptr(pairpos), tfinal.data_ptr(), last.data_ptr(), grad_image.data_ptr(),
            grad_alpha.data_ptr(), _ptr(gm), _ptr(gc), _ptr(go), _ptr(gcol),
        )  # fmt: skip
        _check(code, "backward")
        need = ctx.needs_input_grad
        return (
            gm if need[0] else None,
            gc if need[1] else None,
            go if need[2] else None,
            gcol if need[3] else None,
            None, None, None, None, None, None,
        )  # fmt: skip


def _shape_error(name: str, expected: str, t: Tensor) -> ValueError:
    return ValueError(f"composite: {name} must have shape {expected}, got {tuple(t.shape)}")


def composite(
    means2d: Tensor,  # [N, 2] pixel coordinates
    conics: Tensor,  # [N, 3] inverse 2D covariance (a, b, c)
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    depths: Tensor,  # [N] sort key (camera-space z)
    radii: Tensor,  # [N] int, 0 = culled
    width: int,
    height: int,
    groups: Tensor | None = None,  # [N] int in [0, num_groups)
    num_groups: int = 1,
) -> tuple[Tensor, Tensor, Tensor]:
    """Front-to-back compositing with the compiled kernel; same contract as ``_torch._composite``.

    Differentiable w.r.t. ``means2d``, ``conics``, ``opacities`` and ``colors``.

    Returns:
        image ``[G, H, W, D]``, alpha ``[G, H, W]``, contrib ``[N]`` (no gradient), all float32.
    """
    lib = library()
    if lib is None:
        raise RuntimeError(f"moegs CPU kernel unavailable: {load_error()}")
    if colors.dim() != 2 or colors.shape[1] < 1:
        raise ValueError(f"composite: colors must have shape [N, D] with D >= 1, got {tuple(colors.shape)}")
    n = colors.shape[0]
    if n >= 2**31:
        raise ValueError(f"composite: at most 2**31 - 1 Gaussians are supported, got {n}")
    if means2d.shape != (n, 2):
        raise _shape_error("means2d", f"[N, 2] = [{n}, 2]", means2d)
    if conics.shape != (n, 3):
        raise _shape_error("conics", f"[N, 3] = [{n}, 3]", conics)
    if opacities.shape != (n,):
        raise _shape_error("opacities", f"[N] = [{n}]", opacities)
    if depths.shape != (n,):
        raise _shape_error("depths", f"[N] = [{n}]", depths)
    if radii.shape != (n,):
        raise _shape_error("radii", f"[N] = [{n}]", radii)
    if radii.is_floating_point() or radii.is_complex():
        raise TypeError(f"composite: radii must be an integer tensor, got {radii.dtype}")
    if groups is not None:
        if groups.shape != (n,):
            raise _shape_error("groups", f"[N] = [{n}]", groups)
        if groups.is_floating_point() or groups.is_complex():
            raise TypeError(f"composite: groups must be an integer tensor, got {groups.dtype}")
    width, height, num_groups = int(width), int(height), int(num_groups)
    if width < 1 or height < 1:
        raise ValueError(f"composite: width and height must be >= 1, got {width}x{height}")
    if num_groups < 1:
        raise ValueError(f"composite: num_groups must be >= 1, got {num_groups}")
    named = {"means2d": means2d, "conics": conics, "opacities": opacities, "colors": colors}
    named.update(depths=depths, radii=radii, groups=groups)
    for name, t in named.items():
        if t is not None and t.device.type != "cpu":
            raise ValueError(f"composite: {name} must be a CPU tensor, got device {t.device}")
    if groups is not None and n > 0:
        lo, hi = int(groups.min()), int(groups.max())
        if lo < 0 or hi >= num_groups:
            raise ValueError(f"composite: groups must lie in [0, {num_groups}), got values in [{lo}, {hi}]")

    order = torch.argsort(depths.detach(), stable=True).contiguous()
    f32 = torch.float32
    return _Composite.apply(
        means2d.to(f32).contiguous(),
        conics.to(f32).contiguous(),
        opacities.to(f32).contiguous(),
        colors.to(f32).contiguous(),
        # clamping keeps int32 exact; a radius of 2^24 px already covers any image
        radii.clamp(max=1 << 24).to(torch.int32).contiguous(),
        None if groups is None else groups.to(torch.int32).contiguous(),
        order,
        width,
        height,
        num_groups,
    )


# -- projection ---------------------------------------------------------------------------------------
def _camera_record(camera: Camera, eps2d: float) -> Tensor:
    """``project.c``'s camera record ``[21]`` float32: R (9), t (3), fx, fy, cx, cy, the Jacobian clamp
    (4) and eps2d, each the float32 value the reference's operations use."""
    w2c = camera.world_to_camera.to(torch.float32)
    scalars = [camera.fx, camera.fy, camera.cx, camera.cy, *_reference._jacobian_limits(camera), eps2d]
    return torch.cat(
        [w2c[:3, :3].reshape(9), w2c[:3, 3], torch.tensor(scalars, dtype=torch.float32, device="cpu")]
    )


class _Project(torch.autograd.Function):
    """Autograd wrapper; inputs are contiguous float32 CPU tensors."""

    @staticmethod
    def forward(ctx, means, covars, opacities, cam, width, height, near, far, antialiased):
        lib = library()
        n = means.shape[0]
        means2d = torch.empty(n, 2, dtype=torch.float32, device="cpu")
        conics = torch.empty(n, 3, dtype=torch.float32, device="cpu")
        opac_out = torch.empty(n, dtype=torch.float32, device="cpu")
        depths = torch.empty(n, dtype=torch.float32, device="cpu")
        radii = torch.empty(n, dtype=torch.int32, device="cpu")
        code = lib.moegs_project_forward(
            n, torch.get_num_threads(), _ptr(means), _ptr(covars), _ptr(opacities), cam.data_ptr(),
            width, height, near, far, int(antialiased),
            _ptr(means2d), _ptr(conics), _ptr(opac_out), _ptr(depths), _ptr(radii),
        )  # fmt: skip
        _check(code, "project forward")
        ctx.save_for_backward(means, covars, opacities, cam)
        ctx.settings = (near, far, antialiased)
        ctx.mark_non_differentiable(radii)
        return means2d, conics, opac_out, depths, radii

    @staticmethod
    @once_differentiable
    def backward(ctx, g_means2d, g_conics, g_opac_out, g_depths, _g_radii):
        lib = library()
        means, covars, opacities, cam = ctx.saved_tensors
        near, far, antialiased = ctx.settings
        n = means.shape[0]

        # kept in locals: C reads them through raw pointers
        grads_out = [
            torch.zeros(shape, device="cpu") if g is None else g.to(torch.float32).contiguous()
            for g, shape in ((g_means2d, (n, 2)), (g_conics, (n, 3)), (g_opac_out, (n,)), (g_depths, (n,)))
        ]
        g_means = torch.empty(n, 3, dtype=torch.float32, device="cpu")
        g_covars = torch.empty(n, 3, 3, dtype=torch.float32, device="cpu")
        g_opac = torch.empty(n, dtype=torch.float32, device="cpu")
        code = lib.moegs_project_backward(
            n, torch.get_num_threads(), _ptr(means), _ptr(covars), _ptr(opacities), cam.data_ptr(),
            near, far, int(antialiased), *(_ptr(g) for g in grads_out),
            _ptr(g_means), _ptr(g_covars), _ptr(g_opac),
        )  # fmt: skip
        _check(code, "project backward")
        need = ctx.needs_input_grad
        return (
            g_means if need[0] else None,
            g_covars if need[1] else None,
            g_opac if need[2] else None,
            None, None, None, None, None, None,
        )  # fmt: skip


def project(
    means: Tensor,  # [N, 3]
    covars: Tensor,  # [N, 3, 3]
    opacities: Tensor,  # [N]
    camera: Camera,
    *,
    eps2d: float = BLUR_3DGS,
    antialiased: bool = False,
) -> Projection:
    """:func:`moegs.render.projection.project` with the compiled kernel (float32 CPU tensors; other
    dtypes, or a missing library, go to that reference). Differentiable w.r.t. ``means``, ``covars``
    and ``opacities``."""
    tensors = (means, covars, opacities)
    if library() is None or any(t.dtype != torch.float32 or t.device.type != "cpu" for t in tensors):
        return _reference.project(means, covars, opacities, camera, eps2d=eps2d, antialiased=antialiased)
    n = means.shape[0]
    if means.shape != (n, 3) or covars.shape != (n, 3, 3) or opacities.shape != (n,):
        raise ValueError(
            f"project: expected means [N, 3], covars [N, 3, 3] and opacities [N], got "
            f"{tuple(means.shape)}, {tuple(covars.shape)} and {tuple(opacities.shape)}"
        )
    means2d, conics, opac_out, depths, radii = _Project.apply(
        means.contiguous(), covars.contiguous(), opacities.contiguous(), _camera_record(camera, eps2d),
        camera.width, camera.height, camera.near, camera.far, antialiased,
    )  # fmt: skip
    return Projection(means2d=means2d, conics=conics, opacities=opac_out, depths=depths, radii=radii)


class _Covariance(torch.autograd.Function):
    """Autograd wrapper; inputs are contiguous float32 CPU tensors."""

    @staticmethod
    def forward(ctx, quats, scales):
        covars = torch.empty(quats.shape[0], 3, 3, dtype=torch.float32, device="cpu")
        code = library().moegs_covariance_forward(
            quats.shape[0], torch.get_num_threads(), _ptr(quats), _ptr(scales), _ptr(covars)
        )
        _check(code, "covariance forward")
        ctx.save_for_backward(quats, scales)
        return covars

    @staticmethod
    @once_differentiable
    def backward(ctx, g_covars):
        quats, scales = ctx.saved_tensors
        g_covars = g_covars.to(torch.float32).contiguous()
        g_quats, g_scales = torch.empty_like(quats), torch.empty_like(scales)
        code = library().moegs_covariance_backward(
            quats.shape[0], torch.get_num_threads(), _ptr(quats), _ptr(scales), _ptr(g_covars),
            _ptr(g_quats), _ptr(g_scales),
        )  # fmt: skip
        _check(code, "covariance backward")
        need = ctx.needs_input_grad
        return (g_quats if need[0] else None, g_scales if need[1] else None)


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """:func:`moegs.render.projection.covariance_3d` with the compiled kernel (float32 CPU tensors; other
    dtypes, or a missing library, go to that reference): ``[N, 3, 3]`` from quats ``[N, 4]`` and scales
    ``[N, 3]``, differentiable w.r.t. both."""
    if library() is None or any(t.dtype != torch.float32 or t.device.type != "cpu" for t in (quats, scales)):
        return _reference.covariance_3d(quats, scales)
    n = quats.shape[0]
    if quats.shape != (n, 4) or scales.shape != (n, 3):
        raise ValueError(
            f"covariance_3d: expected quats [N, 4] and scales [N, 3], got {tuple(quats.shape)} and "
            f"{tuple(scales.shape)}"
        )
    return _Covariance.apply(quats.contiguous(), scales.contiguous())
