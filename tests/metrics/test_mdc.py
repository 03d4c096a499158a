"""MDC on analytic depth: a plane seen by three cameras is consistent; a depth offset shows up as its size."""

from __future__ import annotations

import math

import pytest
import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.metrics.mdc import mdc, mdc_pairs

SIZE = 48


def camera(angle: float) -> Camera:
    eye = torch.tensor([2.0 * math.sin(angle), 0.3, -3.0 * math.cos(angle)], dtype=torch.float64)
    return Camera(
        K=intrinsics(40.0, 40.0, SIZE / 2, SIZE / 2).double(),
        world_to_camera=look_at(eye, torch.zeros(3, dtype=torch.float64)).double(),
        width=SIZE,
        height=SIZE,
    )


def plane_depth(cam: Camera, z_plane: float = 0.5) -> torch.Tensor:
    """Camera z of the world plane z = z_plane along every pixel ray (0 where the ray misses it)."""
    origins, dirs = cam.rays()
    s = (z_plane - origins[..., 2]) / dirs[..., 2]
    points = origins + s[..., None] * dirs
    w2c = cam.world_to_camera
    z = (points @ w2c[:3, :3].T + w2c[:3, 3])[..., 2]
    return torch.where(s > 0, z, torch.zeros_like(z))


def test_a_plane_is_consistent_across_views():
    cams = [camera(a) for a in (-0.3, 0.0, 0.35)]
    depths = [plane_depth(c) for c in cams]
    assert all((d > 0).float().mean() > 0.9 for d in depths)
    assert mdc(depths, cams) < 2e-3
    assert len(mdc_pairs(depths, cams)) == 6


def test_samples_next_to_a_hole_are_not_counted():
    """Bilinear samples need all four neighbouring depths: a hole in one map (no Gaussian there) must not
    blend its zeros into the samples around it."""
    cams = [camera(-0.3), camera(0.3)]
    depths = [plane_depth(c) for c in cams]
    holed = depths[1].clone()
    holed[16:32, 16:32] = 0.0
    assert mdc_pairs([depths[0], holed], cams)[(0, 1)] < 2e-3


def test_an_offset_depth_map_is_measured():
    cams = [camera(-0.3), camera(0.3)]
    depths = [plane_depth(c) for c in cams]
    shifted = [depths[0], torch.where(depths[1] > 0, depths[1] + 0.1, depths[1])]
    pairs = mdc_pairs(shifted, cams)
    # (1 -> 0): the lifted points of the pushed-back map land behind plane 0 by ~0.1 along the ray
    assert 0.07 < pairs[(0, 1)] < 0.13 and 0.07 < pairs[(1, 0)] < 0.13
    assert mdc(shifted, cams) == pytest.approx(sum(pairs.values()) / 2)


def test_empty_maps_and_bad_input():
    cams = [camera(-0.3), camera(0.3)]
    assert math.isnan(mdc([torch.zeros(SIZE, SIZE, dtype=torch.float64)] * 2, cams))
    with pytest.raises(ValueError, match="at least two views"):
        mdc([plane_depth(cams[0])], cams[:1])
    with pytest.raises(ValueError, match=r"depths\[1\] must have shape \[48, 48\]"):
        mdc([plane_depth(cams[0]), torch.zeros(3, 3)], cams)
    with pytest.raises(ValueError, match="2 depth maps but 1 cameras"):
        mdc([plane_depth(cams[0])] * 2, cams[:1])
