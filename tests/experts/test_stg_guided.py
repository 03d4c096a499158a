"""STG's error-guided sampling: where new Gaussians go (pixel rays at the census depth), which pixels seed
them (flagged 16x16 patches, odd rows or columns, off the border), and the census depth."""

from __future__ import annotations

import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.experts.stg_guided import error_pixels, far_depth, pixel_points
from moegs.render.projection import camera_points


def test_new_points_lie_on_the_rays_of_their_pixels_at_the_census_depth():
    """A non-square image with an off-centre principal point and fx != fy: each point projects back to its
    pixel's centre, at camera z within +-5 % of ``depth x ratio``."""
    camera = Camera(
        K=intrinsics(50.0, 60.0, 30.0, 17.0),
        world_to_camera=look_at(torch.tensor([1.0, -4.0, 0.5]), torch.zeros(3)),
        width=64,
        height=40,
        time=0.0,
    )
    pixels = torch.tensor([[3, 50], [20, 7], [39, 63]])  # (row, col)
    ratios = (0.7, 7.5)
    points = pixel_points(camera, pixels, 2.0, ratios, torch.Generator().manual_seed(0))
    assert points.shape == (6, 3)
    cam = camera_points(points, camera)
    col = camera.fx * cam[:, 0] / cam[:, 2] + camera.cx
    row = camera.fy * cam[:, 1] / cam[:, 2] + camera.cy
    centres = pixels.to(torch.float32).repeat(len(ratios), 1) + 0.5  # ratio-major
    torch.testing.assert_close(torch.stack([row, col], -1), centres, atol=1e-3, rtol=0)
    depth = torch.tensor([2.0 * r for r in ratios]).repeat_interleave(len(pixels))
    assert ((cam[:, 2] - depth).abs() <= 0.05 * depth + 1e-5).all()


def test_seed_pixels_are_the_odd_rows_or_columns_of_a_badly_fitted_patch():
    target = torch.full((48, 64, 3), 0.5)
    rgb = target.clone()
    rgb[16:32, 16:24] += 0.3  # one 16x16 patch wrong, its mean unchanged: the rest has no error
    rgb[16:32, 24:32] -= 0.3
    got = {tuple(p) for p in error_pixels(rgb, target, quantile=0.6).tolist()}
    expected = {(r, c) for r in range(16, 32) for c in range(16, 32) if r % 2 == 1 or c % 2 == 1}
    assert got == expected and len(got) == 256 - 64
    # the same patch inside the 10 % border (4 rows, 6 columns) seeds nothing there
    rgb = target.clone()
    rgb[0:16, 0:8] += 0.3
    rgb[0:16, 8:16] -= 0.3
    got = error_pixels(rgb, target, quantile=0.6)
    assert len(got) and (got[:, 0] >= 4).all() and (got[:, 1] >= 6).all()


def test_the_census_depth_is_the_farthest_covered_pixel():
    depth = torch.tensor([[1.0, 9.0], [3.0, 2.0]])
    alpha = torch.tensor([[1.0, 0.4], [0.5, 0.9]])
    assert far_depth(depth, alpha) == 3.0  # 9.0 is not covered (alpha < 0.5)
    assert far_depth(depth, torch.zeros(2, 2)) == 0.0
