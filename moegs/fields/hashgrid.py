"""Multiresolution hash encoding in pure PyTorch, as Grid4D's CUDA ``hashencoder`` computes it.

Facts from ``JiaweiXu8/Grid4D`` (``hashencoder/``, torch-ngp style; ``specs/experts_canonical.md`` §3.1):

* Input ``u [N, D]`` in [0, 1]; a point with **any** coordinate outside [0, 1] gets zero features
  at every level (and no gradient).
* Per dimension ``d``: growth ``s_d = (desired_d / base_d) ** (1 / (L - 1))``. At level ``l``:
  ``scale_d = base_d * s_d**l - 1``, ``res_d = ceil(scale_d) + 1``, ``pos_d = u_d * scale_d``, computed
  in **float32** as the kernel does (``exp2f(l * log2(s)) * base - 1``, ``hashencoder.cu:157-158``;
  Python passes float32 ``s`` and ``base``, ``hashgrid.py:33,154-155``). Table sizes come from the
  Python side in float64 (``ceil(base * s**l)``, ``hashgrid.py:145-151``), so a level whose float32
  resolution rounds up past its table is hashed: the finest D-NeRF temporal level (33 x 33 x 16 >
  32 x 32 x 16 rows).
* The 2^D corners of the cell ``floor(pos)`` are blended with **smoothstep** weights
  ``w(f) = f^2 (3 - 2 f)`` of the fractional part ``f`` (not linear).
* Table size ``T_l = min(2^log2_hashmap_size, prod_d ceil(base * s^l))`` (the float64 sizes above; the
  kernel's float32 ``res_d`` can exceed them). If ``prod_d res_d <= T_l`` the level is
  **dense**: ``index = sum_d c_d * stride_d`` with ``stride_0 = 1, stride_{d+1} = stride_d * res_d``;
  otherwise ``index = XOR_d (c_d * p_d mod 2^32)`` with primes ``p = (1, 2654435761, 805459861)``.
  Either way the index is taken ``mod T_l``.
* Table init ``U(-1e-4, 1e-4)``; output is level-major ``[N, L * F]``.

On CPU, :class:`HashGrid` runs the compiled kernel of ``moegs/kernels/hashgrid.c`` (same float32
operations in the same order: the forward is bit-identical to :meth:`HashGrid.encode_reference`, the
table gradient equal up to the order of its sums) unless the input needs a gradient, which only the
reference computes; elsewhere, or without the compiled library, the reference runs.

:class:`DecomposedHashGrid4D` is Grid4D's 4D encoder: one spatial grid over xyz and three
spatio-temporal 3D grids over (x, y, t), (y, z, t), (x, z, t).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from moegs import kernels

PRIMES = (1, 2654435761, 805459861)
UINT32_MASK = 0xFFFFFFFF


def smoothstep(f: Tensor) -> Tensor:
    """``f^2 (3 - 2 f)``: the interpolation weight of the upper corner for fractional position ``f``."""
    return f * f * (3.0 - 2.0 * f)


def _per_dim(value: int | float | Sequence[int | float], dim: int, name: str) -> tuple[float, ...]:
    values = (value,) * dim if isinstance(value, int | float) else tuple(value)
    if len(values) != dim or min(values) <= 0:
        raise ValueError(f"{name} must be a positive number or {dim} positive numbers, got {value!r}")
    return tuple(float(v) for v in values)


class HashGrid(nn.Module):
    """``u [N, D] in [0, 1] -> [N, num_levels * level_dim]`` (rules in the module docstring).

    Args:
        input_dim: ``D`` (1 to 3; the prime list has three entries).
        num_levels: ``L``.
        level_dim: ``F`` features per level.
        base_resolution, desired_resolution: per-dimension (or shared) coarsest / finest resolution.
        log2_hashmap_size: ``log2`` of the largest per-level table.
    """

    def __init__(
        self,
        input_dim: int = 3,
        num_levels: int = 16,
        level_dim: int = 2,
        base_resolution: int | Sequence[int] = 16,
        desired_resolution: int | Sequence[int] = 2048,
        log2_hashmap_size: int = 19,
    ) -> None:
        super().__init__()
        if not 1 <= input_dim <= len(PRIMES):
            raise ValueError(f"input_dim must be 1..{len(PRIMES)}, got {input_dim}")
        if num_levels < 1 or level_dim < 1:
            raise ValueError(f"num_levels and level_dim must be >= 1, got {num_levels}, {level_dim}")
        self.input_dim, self.num_levels, self.level_dim = input_dim, num_levels, level_dim
        self.log2_hashmap_size = log2_hashmap_size
        self.base = _per_dim(base_resolution, input_dim, "base_resolution")
        self.desired = _per_dim(desired_resolution, input_dim, "desired_resolution")
        growth = [
            1.0 if num_levels == 1 else (h / b) ** (1.0 / (num_levels - 1))
            for b, h in zip(self.base, self.desired, strict=True)
        ]
        max_size = 2**log2_hashmap_size
        log2_growth = np.log2(np.array(growth, dtype=np.float32))  # float32, as the kernel receives it
        base32 = np.array(self.base, dtype=np.float32)
        scales, res, sizes = [], [], []
        for level in range(num_levels):
            scale = np.exp2(np.float32(level) * log2_growth) * base32 - np.float32(1.0)
            scales.append(scale.tolist())
            res.append([math.ceil(s) + 1 for s in scale.tolist()])
            table = math.prod(math.ceil(b * g**level) for b, g in zip(self.base, growth, strict=True))
            sizes.append(min(max_size, table))
        res_t = torch.tensor(res, dtype=torch.long)  # [L, D]
        strides = torch.cumprod(torch.cat([torch.ones(num_levels, 1, dtype=torch.long), res_t[:, :-1]], 1), 1)
        self.register_buffer("scales", torch.tensor(scales, dtype=torch.float32), persistent=False)  # [L, D]
        self.register_buffer("resolutions", res_t, persistent=False)  # [L, D]
        self.register_buffer("strides", strides, persistent=False)  # [L, D]
        self.register_buffer("sizes", torch.tensor(sizes, dtype=torch.long), persistent=False)  # [L]
        dense = res_t.prod(1) <= self.sizes
        self.dense = tuple(dense.tolist())  # per level; decided on the host, so a call never reads the device
        self.register_buffer("dense_mask", dense, persistent=False)  # [L] bool
        offsets = torch.cumsum(torch.tensor([0, *sizes], dtype=torch.long), 0)
        self.register_buffer("offsets", offsets, persistent=False)  # [L + 1]
        self.register_buffer("primes", torch.tensor(PRIMES[:input_dim], dtype=torch.long), persistent=False)
        corners = [[(c >> d) & 1 for d in range(input_dim)] for c in range(2**input_dim)]
        self.register_buffer("corners", torch.tensor(corners, dtype=torch.long), persistent=False)  # [2^D, D]
        self.embeddings = nn.Parameter(torch.empty(int(offsets[-1]), level_dim).uniform_(-1e-4, 1e-4))

    @property
    def out_dim(self) -> int:
        return self.num_levels * self.level_dim

    def level_index(self, cell: Tensor) -> Tensor:
        """Table row of the integer vertices ``cell [N, L, D]`` at each level: ``[N, L]`` in ``[0, T_l)``."""
        index = None
        if any(self.dense):
            index = (cell * self.strides).sum(-1)
        if not all(self.dense):
            hashed = (cell[..., 0] * self.primes[0]) & UINT32_MASK
            for d in range(1, self.input_dim):
                hashed = hashed ^ ((cell[..., d] * self.primes[d]) & UINT32_MASK)
            index = hashed if index is None else torch.where(self.dense_mask, index, hashed)
        return index % self.sizes

    def forward(self, u: Tensor) -> Tensor:
        if u.ndim != 2 or u.shape[1] != self.input_dim:
            raise ValueError(f"HashGrid expects u [N, {self.input_dim}], got {list(u.shape)}")
        compiled = (
            u.device.type == "cpu"
            and u.dtype == torch.float32
            and self.embeddings.dtype == torch.float32
            and not (u.requires_grad and torch.is_grad_enabled())
            and kernels.is_available()
        )
        if compiled:
            return _CompiledEncoding.apply(u.contiguous(), self.embeddings, self)
        return self.encode_reference(u)

    def encode_reference(self, u: Tensor) -> Tensor:
        """Pure-torch encoding ``u [N, D] -> [N, L * F]``, differentiable w.r.t. ``u`` and the tables."""
        n = u.shape[0]
        inside = ((u >= 0.0) & (u <= 1.0)).all(-1)  # [N]
        pos = u.clamp(0.0, 1.0)[:, None, :] * self.scales  # [N, L, D]
        cell = pos.detach().floor()
        w_hi = smoothstep(pos - cell)  # [N, L, D]
        cell = cell.long()
        out = None
        for corner in range(2**self.input_dim):
            bits = [(corner >> d) & 1 for d in range(self.input_dim)]
            weight = torch.stack(
                [w_hi[..., d] if b else 1.0 - w_hi[..., d] for d, b in enumerate(bits)]
            ).prod(0)  # [N, L]
            rows = self.level_index(cell + self.corners[corner]) + self.offsets[:-1]  # [N, L]
            # index_select: its backward is an index_add, much faster on CPU than advanced indexing
            feats = self.embeddings.index_select(0, rows.flatten()).view(n, self.num_levels, self.level_dim)
            term = weight[..., None] * feats
            out = term if out is None else out + term
        return (out * inside[:, None, None]).flatten(1)

    def kernel_arguments(self) -> list[int]:
        """Pointers to the level constants, in the order of ``moegs_hashgrid_forward``'s arguments."""
        if not hasattr(self, "_constants") or self._constants[0].device != self.scales.device:
            self._constants = (
                self.scales.contiguous(),
                self.strides.contiguous(),
                self.sizes.contiguous(),
                self.offsets[:-1].contiguous(),
                self.dense_mask.to(torch.uint8).contiguous(),
            )
        return [t.data_ptr() for t in self._constants]

    def extra_repr(self) -> str:
        hashed = self.dense.count(False)
        return (
            f"input_dim={self.input_dim}, levels={self.num_levels} ({hashed} hashed), "
            f"level_dim={self.level_dim}, base={self.base}, desired={self.desired}, "
            f"log2_T={self.log2_hashmap_size}, params={self.embeddings.numel()}"
        )


class _CompiledEncoding(torch.autograd.Function):
    """``u [N, D]`` (no gradient), ``table [T, F]`` -> ``[N, L * F]`` with the compiled kernel."""

    @staticmethod
    def forward(ctx, u: Tensor, table: Tensor, grid: HashGrid) -> Tensor:
        lib = kernels.library()
        out = torch.empty(u.shape[0], grid.out_dim, dtype=torch.float32, device=u.device)
        dims = (u.shape[0], grid.input_dim, grid.num_levels, grid.level_dim, torch.get_num_threads())
        rows = table.detach().contiguous()  # bound to a name: it must outlive the call
        code = lib.moegs_hashgrid_forward(
            *dims, *grid.kernel_arguments(), u.data_ptr(), rows.data_ptr(), out.data_ptr()
        )
        kernels.check(code, "hash encoding forward")
        ctx.save_for_backward(u)
        ctx.grid, ctx.dims, ctx.table_shape = grid, dims, table.shape
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out: Tensor) -> tuple[None, Tensor | None, None]:
        if not ctx.needs_input_grad[1]:
            return None, None, None
        (u,) = ctx.saved_tensors
        grad_out = grad_out.to(torch.float32).contiguous()  # bound to a name: it must outlive the call
        grad_table = torch.zeros(ctx.table_shape, dtype=torch.float32, device=u.device)
        code = kernels.library().moegs_hashgrid_backward(
            *ctx.dims, *ctx.grid.kernel_arguments(), u.data_ptr(), grad_out.data_ptr(), grad_table.data_ptr()
        )
        kernels.check(code, "hash encoding backward")
        return None, grad_table, None


class DecomposedHashGrid4D(nn.Module):
    """Grid4D's 4D decomposed encoding: ``h_xyz`` from a 3D grid over xyz and ``h_t`` from three
    3D grids over (x, y, t), (y, z, t), (x, z, t), concatenated in that order.

    Coordinates are in Grid4D's bound units: space as given (times ``scale_xyz`` by the caller), time as
    :meth:`time_coordinate` ``= 0.9 (2 t - 1) bound``; each is mapped ``(v + bound) / (2 bound)`` onto [0, 1].

    Args:
        bound: half-size of the encoded cube.
        spatial_levels, spatial_level_dim, spatial_base, spatial_desired, spatial_log2_size: the xyz grid.
        temporal_levels, temporal_level_dim, temporal_base, temporal_desired, temporal_log2_size: each of
            the three space-time grids; base/desired are per (space, space, time) axis.
    """

    PAIRS = ((0, 1), (1, 2), (0, 2))  # xyt, yzt, xzt

    def __init__(
        self,
        bound: float = 1.6,
        spatial_levels: int = 16,
        spatial_level_dim: int = 2,
        spatial_base: int = 16,
        spatial_desired: int = 2048,
        spatial_log2_size: int = 19,
        temporal_levels: int = 32,
        temporal_level_dim: int = 2,
        temporal_base: int | Sequence[int] = (8, 8, 8),
        temporal_desired: int | Sequence[int] = (32, 32, 16),
        temporal_log2_size: int = 19,
    ) -> None:
        super().__init__()
        if bound <= 0:
            raise ValueError(f"bound must be positive, got {bound}")
        self.bound = float(bound)
        self.spatial = HashGrid(
            3, spatial_levels, spatial_level_dim, spatial_base, spatial_desired, spatial_log2_size
        )
        self.temporal = nn.ModuleList(
            HashGrid(
                3, temporal_levels, temporal_level_dim, temporal_base, temporal_desired, temporal_log2_size
            )
            for _ in self.PAIRS
        )

    @property
    def spatial_dim(self) -> int:
        return self.spatial.out_dim

    @property
    def temporal_dim(self) -> int:
        return sum(g.out_dim for g in self.temporal)

    def time_coordinate(self, t: Tensor) -> Tensor:
        """Normalised ``t`` in [0, 1] to Grid4D's ``0.9 (2 t - 1) bound`` (then [0.05, 0.95] on the grid)."""
        return 0.9 * (2.0 * t - 1.0) * self.bound

    def _unit(self, v: Tensor) -> Tensor:
        return (v + self.bound) / (2.0 * self.bound)

    def encode_spatial(self, xyz: Tensor) -> Tensor:
        """``xyz [N, 3]`` (bound units) -> ``h_xyz [N, spatial_dim]``."""
        return self.spatial(self._unit(xyz))

    def encode_temporal(self, xyzt: Tensor) -> Tensor:
        """``xyzt [N, 4]`` (bound units, t from :meth:`time_coordinate`) -> ``h_t [N, temporal_dim]``."""
        if xyzt.ndim != 2 or xyzt.shape[1] != 4:
            raise ValueError(f"encode_temporal expects xyzt [N, 4], got {list(xyzt.shape)}")
        u = self._unit(xyzt)
        pairs = zip(self.temporal, self.PAIRS, strict=True)
        return torch.cat([grid(u[:, [a, b, 3]]) for grid, (a, b) in pairs], dim=-1)
