"""Shared fixtures: real D-NeRF frames (skipped when the staged data is absent) and a seeded RNG."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from moegs.paths import data_root

MUTANT = "dnerf/mutant/test"


def load_mutant(index: int, size: int = 128) -> torch.Tensor:
    """Test frame ``r_<index>.png`` on white (as D-NeRF does), area-resized: ``[size, size, 3]``."""
    from PIL import Image

    root = data_root()
    path = None if root is None else root / MUTANT / f"r_{index:03d}.png"
    if path is None or not path.is_file():
        pytest.skip(f"real D-NeRF frames absent (looked for {path}); set MOEGS_DATA")
    rgba = torch.from_numpy(np.asarray(Image.open(path), dtype=np.float32) / 255.0)
    rgb = rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])
    small = F.interpolate(rgb.permute(2, 0, 1)[None], size=(size, size), mode="area")
    return small[0].permute(1, 2, 0).contiguous()


@pytest.fixture
def load_frame():
    """The ``load_mutant`` loader, for tests that need several frames."""
    return load_mutant


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(0)


@pytest.fixture
def frame() -> torch.Tensor:
    """One real frame ``[128, 128, 3]``."""
    return load_mutant(0)


@pytest.fixture
def degraded(frame: torch.Tensor, gen: torch.Generator) -> dict[str, torch.Tensor]:
    """Render-like degradations of ``frame``: clamped noise, 3x3 box blur, 2 px shift."""
    noisy = (frame + 0.05 * torch.randn(frame.shape, generator=gen)).clamp(0.0, 1.0)
    blur = F.avg_pool2d(frame.permute(2, 0, 1)[None], 3, 1, 1, count_include_pad=False)[0].permute(1, 2, 0)
    return {"noise": noisy, "blur": blur.contiguous(), "shift": torch.roll(frame, 2, dims=1)}
