"""``GaussianFrame``: the activated Gaussians of one expert at one time.

Every expert answers ``frame(t)`` with one of these; the rasterizer, the routers and the metrics
consume nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor


@dataclass
class GaussianFrame:
    """Activated Gaussian parameters, ``N`` Gaussians.

    Attributes:
        means: centres ``[N, 3]`` in world space.
        quats: unit quaternions ``[N, 4]`` in (w, x, y, z) order.
        scales: standard deviations along the local axes ``[N, 3]`` (only their squares enter the covariance).
        opacities: ``[N]`` in (0, 1).
        colors: per-Gaussian channels ``[N, D]`` (RGB, features, routing weights ...), or ``None``.
        sh: spherical-harmonic coefficients ``[N, B, C]`` with ``B = (degree + 1) ** 2``, or ``None``.
            Exactly one of ``colors`` and ``sh`` is set.
    """

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    colors: Tensor | None = None
    sh: Tensor | None = None

    def __post_init__(self) -> None:
        self.validate()

    # -- checks -------------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise ``ValueError`` naming the field when a shape or the colour choice is wrong."""
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expected = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,)}
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape or n < 0:
                raise ValueError(f"GaussianFrame.{name} must have shape {list(shape)}, got {list(got)}")
        if (self.colors is None) == (self.sh is None):
            raise ValueError("GaussianFrame needs exactly one of `colors` [N, D] or `sh` [N, B, C]")
        if self.colors is not None and (self.colors.ndim != 2 or self.colors.shape[0] != n):
            raise ValueError(f"GaussianFrame.colors must have shape [{n}, D], got {list(self.colors.shape)}")
        if self.sh is not None:
            if self.sh.ndim != 3 or self.sh.shape[0] != n:
                raise ValueError(f"GaussianFrame.sh must have shape [{n}, B, C], got {list(self.sh.shape)}")
            bases = self.sh.shape[1]
            if bases not in (1, 4, 9, 16):
                raise ValueError(f"GaussianFrame.sh has {bases} bases; expected 1, 4, 9 or 16 (degree 0-3)")

    def check_values(self, what: str = "GaussianFrame") -> None:
        """Raise ``ValueError`` naming the field when a dtype or a value is outside its domain: float32 or
        float64 throughout, opacities in [0, 1], quaternions of non-zero norm. The sign of a scale is not
        checked: the covariance depends on its square, as in the 3DGS rasterizer, and DeformableGS adds
        its scale offsets after the activation, so a scale may legitimately be negative there."""
        dtype = self.means.dtype
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"{what}.means must be float32 or float64, got {dtype}")
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None and value.dtype != dtype:
                raise ValueError(f"{what}.{f.name} is {value.dtype} but means are {dtype}; use one dtype")
        checks = {
            "opacities must be in [0, 1]": ((self.opacities < 0) | (self.opacities > 1)).any(),
            "quats must have a non-zero norm": (self.quats.square().sum(-1) == 0).any(),
        }
        flags = torch.stack(list(checks.values())).tolist()  # one device sync for all checks
        for (message, _), bad in zip(checks.items(), flags, strict=True):
            if bad:
                raise ValueError(f"{what}: {message}")

    def check_finite(self, what: str = "GaussianFrame") -> None:
        """Raise ``FloatingPointError`` naming the first field holding NaN or Inf."""
        present = [(f.name, v) for f in fields(self) if (v := getattr(self, f.name)) is not None]
        finite = torch.stack([torch.isfinite(v).all() for _, v in present]).tolist()  # one device sync
        for (name, _), ok in zip(present, finite, strict=True):
            if not ok:
                raise FloatingPointError(f"{what}.{name} contains NaN or Inf")

    # -- properties -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_channels(self) -> int:
        return self.colors.shape[1] if self.colors is not None else self.sh.shape[2]

    @property
    def sh_degree(self) -> int | None:
        return None if self.sh is None else int(round(self.sh.shape[1] ** 0.5)) - 1

    @property
    def device(self) -> torch.device:
        return self.means.device

    # -- transforms -----------------------------------------------------------------------------
    def _map(self, fn) -> GaussianFrame:
        return replace(
            self,
            **{
                f.name: None if getattr(self, f.name) is None else fn(getattr(self, f.name))
                for f in fields(self)
            },
        )

    def detach(self) -> GaussianFrame:
        return self._map(Tensor.detach)

    def to(self, device: torch.device | str) -> GaussianFrame:
        return self._map(lambda t: t.to(device))

    def select(self, index: Tensor) -> GaussianFrame:
        """Subset by boolean mask or integer index over ``N``."""
        return self._map(lambda t: t[index])

    def with_colors(self, colors: Tensor) -> GaussianFrame:
        """Same geometry with other per-Gaussian channels ``[N, D]`` (e.g. routing weights)."""
        return replace(self, colors=colors, sh=None)


def cat(frames: list[GaussianFrame]) -> tuple[GaussianFrame, Tensor]:
    """Concatenate expert frames for single-pass rendering.

    Returns:
        the joint frame and ``expert_id [N_total]`` (int64) giving each Gaussian's source frame.
        All frames must use the same colour representation (all ``colors`` with equal D, or all
        ``sh`` with equal bases and channels).
    """
    if not frames:
        raise ValueError("cat() needs at least one GaussianFrame")
    use_sh = frames[0].sh is not None
    for k, f in enumerate(frames):
        if (f.sh is not None) != use_sh:
            raise ValueError(f"frame {k} mixes `sh` and `colors` with frame 0; convert one of them first")
        ref, got = (frames[0].sh, f.sh) if use_sh else (frames[0].colors, f.colors)
        if ref.shape[1:] != got.shape[1:]:
            raise ValueError(
                f"frame {k} has colour shape {list(got.shape[1:])}, frame 0 has {list(ref.shape[1:])}"
            )
    joined = {}
    for f in fields(GaussianFrame):
        parts = [getattr(fr, f.name) for fr in frames]
        joined[f.name] = None if parts[0] is None else torch.cat(parts, dim=0)
    ids = torch.cat(
        [torch.full((len(fr),), k, dtype=torch.long, device=fr.device) for k, fr in enumerate(frames)]
    )
    return GaussianFrame(**joined), ids
