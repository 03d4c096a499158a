"""Procedural solid textures for the analytic ray caster.

Textures are *solid*: they are evaluated at the hit point expressed in the object's own (material)
frame, so a texture moves, rotates and stretches with its object. Every pattern is mixed with
multi-octave value noise, so that surfaces carry distinctive blobs that SIFT can match (pure
checkers are repetitive and cause false matches).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch
from torch import Tensor

_GRID = 32  # lattice period of the value noise


@lru_cache(maxsize=64)
def noise_volume(seed: int) -> Tensor:
    """``[1, 1, G+1, G+1, G+1]`` random lattice values, periodic (the last slice repeats the first)."""
    g = torch.Generator().manual_seed(int(seed) & 0x7FFFFFFF)
    v = torch.rand(_GRID, _GRID, _GRID, generator=g)
    v = torch.cat([v, v[:1]], 0)
    v = torch.cat([v, v[:, :1]], 1)
    v = torch.cat([v, v[:, :, :1]], 2)
    return v[None, None]


def value_noise(p: Tensor, volume: Tensor) -> Tensor:
    """Trilinear 3-D value noise in [0, 1], periodic with period 32 lattice cells.

    Args:
        p: points ``[R, 3]`` (lattice spacing 1).
        volume: ``noise_volume(seed)``.
    Returns:
        ``[R]``.
    """
    q = torch.remainder(p, float(_GRID)) / _GRID * 2.0 - 1.0  # [-1, 1) over one period
    grid = q.flip(-1).reshape(1, 1, 1, -1, 3).to(volume.dtype)  # grid_sample wants (x=W, y=H, z=D)
    out = torch.nn.functional.grid_sample(volume.to(p.device), grid, mode="bilinear", align_corners=True)
    return out.reshape(-1).to(p.dtype)


def fbm(p: Tensor, volume: Tensor, octaves: int = 3) -> Tensor:
    """Fractal sum of ``value_noise`` octaves, normalised to [0, 1]. ``p [R, 3]`` -> ``[R]``."""
    total, norm, amp, freq = 0.0, 0.0, 1.0, 1.0
    for o in range(octaves):
        total = total + amp * value_noise(p * freq + 17.0 * o, volume)
        norm += amp
        amp *= 0.5
        freq *= 2.0
    return total / norm


def hue_rotate(rgb: Tensor, angle: float) -> Tensor:
    """Rotate colours ``[..., 3]`` about the grey axis by ``angle`` radians (clamped to [0, 1])."""
    c, s = math.cos(angle), math.sin(angle)
    k = 1.0 / 3.0
    sq = math.sqrt(k)
    a = c + (1 - c) * k
    b = (1 - c) * k - sq * s
    d = (1 - c) * k + sq * s
    M = torch.tensor([[a, b, d], [d, a, b], [b, d, a]], dtype=rgb.dtype, device=rgb.device)
    return (rgb @ M.T).clamp(0.0, 1.0)


@dataclass(frozen=True)
class Texture:
    """A procedural solid texture.

    Attributes:
        kind: ``checker`` | ``stripes`` | ``noise``.
        colors: two or three RGB colours in [0, 1] (pattern value 0 -> first, 1 -> last).
        scale: pattern period in material units (checker cell size, stripe period, noise cell).
        noise_scale: cell size of the modulating noise.
        noise_amp: relative brightness modulation by noise in [0, 1).
        seed: seed of the noise lattice.
        hue_cycles: appearance change: the palette's hue turns ``hue_cycles`` full turns over t in [0, 1].
        scroll: appearance change: the pattern scrolls by ``scroll`` material units along x over t in [0, 1].
    """

    kind: str
    colors: tuple[tuple[float, float, float], ...]
    scale: float = 0.25
    noise_scale: float = 0.12
    noise_amp: float = 0.45
    seed: int = 0
    hue_cycles: float = 0.0
    scroll: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("checker", "stripes", "noise"):
            raise ValueError(f"Texture.kind must be one of checker, stripes, noise; got {self.kind!r}")
        if not 2 <= len(self.colors) <= 3:
            raise ValueError(f"Texture needs 2 or 3 colours, got {len(self.colors)}")

    @property
    def time_varying(self) -> bool:
        return self.hue_cycles != 0.0 or self.scroll != 0.0

    def palette(self, t: float, dtype: torch.dtype = torch.float32) -> Tensor:
        """``[K, 3]`` colours at time ``t``."""
        pal = torch.tensor(self.colors, dtype=dtype)
        if self.hue_cycles:
            pal = hue_rotate(pal, 2.0 * math.pi * self.hue_cycles * t)
        return pal

    def __call__(self, p: Tensor, t: float) -> Tensor:
        """Albedo ``[R, 3]`` at material points ``p [R, 3]`` and time ``t``."""
        table = noise_volume(int(self.seed))
        q = p.clone()
        if self.scroll:
            q[:, 0] = q[:, 0] + self.scroll * t
        if self.kind == "checker":
            c = torch.floor(q / self.scale).to(torch.int64).sum(-1)
            v = torch.remainder(c, 2).to(p.dtype)
        elif self.kind == "stripes":
            v = 0.5 + 0.5 * torch.sin(2.0 * math.pi * q[:, 0] / self.scale)
        else:
            v = fbm(q / self.scale, table, octaves=2)
            v = ((v - 0.5) * 2.2 + 0.5).clamp(0.0, 1.0)  # stretch contrast
        pal = self.palette(t, p.dtype).to(p.device)
        if pal.shape[0] == 2:
            albedo = pal[0] + v[:, None] * (pal[1] - pal[0])
        else:
            lo = (v[:, None] * 2.0).clamp(max=1.0)
            hi = (v[:, None] * 2.0 - 1.0).clamp(min=0.0)
            albedo = torch.where(
                v[:, None] < 0.5, pal[0] + lo * (pal[1] - pal[0]), pal[1] + hi * (pal[2] - pal[1])
            )
        n = fbm(p / self.noise_scale + 101.0, table, octaves=2)
        mod = 1.0 - self.noise_amp + 2.0 * self.noise_amp * n
        return (albedo * mod[:, None]).clamp(0.0, 1.0)
