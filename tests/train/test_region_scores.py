"""Scores per region: the dynamic and static regions of a view's mask, named regions (a stand-in's motion
regimes) pooled over the views that show them, component images, and which views are scored."""

from __future__ import annotations

import math

import pytest
import torch

from moegs.camera import Camera, intrinsics
from moegs.data.scene import View
from moegs.train.evaluate import RegionErrors, eval_views, evaluate_renderer, mean_scores, score_image


def _view(key: str, target: torch.Tensor, regions: dict[str, torch.Tensor], time: float, mask=None) -> View:
    h, w = target.shape[:2]
    camera = Camera(
        K=intrinsics(10.0, 10.0, w / 2, h / 2), world_to_camera=torch.eye(4), width=w, height=h, time=time
    )
    load_mask = None if mask is None else (lambda: mask)
    return View(camera, lambda: target, key, load_mask=load_mask, load_regions=lambda: regions)


def test_region_psnr_pools_the_squared_error_of_every_view():
    errors = RegionErrors()
    target = torch.zeros(4, 4, 3)
    a = torch.zeros(4, 4)
    a[:2] = 1.0  # 8 pixels
    b = torch.zeros(4, 4)
    b[3, 3] = 1.0  # 1 pixel
    errors.add(torch.full((4, 4, 3), 0.1), target, {"a": a, "b": torch.zeros(4, 4)})
    errors.add(torch.full((4, 4, 3), 0.3), target, {"a": a, "b": b})
    psnr = errors.psnr()
    pooled_a = (8 * 3 * 0.01 + 8 * 3 * 0.09) / (16 * 3)  # both views, 8 pixels x 3 channels each
    assert psnr["a"] == pytest.approx(-10 * math.log10(pooled_a))
    assert psnr["b"] == pytest.approx(-10 * math.log10(0.09))  # only the second view shows b
    errors.add(torch.zeros(4, 4, 3), target, {"c": torch.zeros(4, 4)})
    assert errors.psnr()["c"] is None  # a region no view shows has no value


def test_region_mask_of_the_wrong_shape_is_named():
    with pytest.raises(ValueError, match="region 'arm': mask \\[3, 3\\] != image \\[4, 4\\]"):
        RegionErrors().add(torch.zeros(4, 4, 3), torch.zeros(4, 4, 3), {"arm": torch.ones(3, 3)})


def test_evaluation_reports_the_regions_of_its_views():
    target = torch.rand(32, 40, 3, generator=torch.Generator().manual_seed(0))
    left = torch.zeros(32, 40)
    left[:, :20] = 1.0
    views = [_view(f"v{i}", target, {"left": left, "right": 1.0 - left}, i / 2) for i in range(2)]

    def render(camera):  # exact on the left half, off by 0.1 on the right half
        out = target.clone()
        out[:, 20:] += 0.1
        return out

    scores = evaluate_renderer(render, views)
    assert scores["psnr_regions"]["left"] == pytest.approx(120.0)  # error 0: the 1e-12 floor
    assert scores["psnr_regions"]["right"] == pytest.approx(20.0, abs=1e-4)
    assert evaluate_renderer(render, views, regions=False)["psnr_regions"] == {}


def test_component_images_are_scored_like_the_image():
    """A renderer may return named component images (a mixture's experts): each is scored against the same
    targets and masks as the main image, exactly as if it were rendered alone."""
    g = torch.Generator().manual_seed(1)
    targets = [torch.rand(32, 40, 3, generator=g) for _ in range(3)]
    mask = torch.zeros(32, 40)
    mask[8:24, 10:30] = 1.0
    views = [_view(f"v{i}", t, {}, i / 2, mask) for i, t in enumerate(targets)]
    noisy = {
        round(v.camera.time * 2): (t + 0.05 * torch.rand(t.shape, generator=g)).clamp(0, 1)
        for v, t in zip(views, targets, strict=True)
    }

    def part(camera):
        return noisy[round(camera.time * 2)]

    mixed = evaluate_renderer(lambda cam: (targets[round(cam.time * 2)], {"expert": part(cam)}), views)
    alone = evaluate_renderer(part, views)
    assert set(mixed["components"]) == {"expert"}
    assert mixed["components"]["expert"]["psnr"] == alone["psnr"]
    assert mixed["components"]["expert"]["ssim"] == alone["ssim"]
    assert mixed["components"]["expert"]["psnr_dynamic"] == alone["psnr_dynamic"] is not None
    assert mixed["psnr"] > alone["psnr"] + 20  # the main image is the exact target
    assert "components" not in alone


def test_the_dynamic_region_is_where_the_mask_is_set():
    target = 0.8 * torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    mask = torch.zeros(32, 32)
    mask[:, :12] = 1.0  # the dynamic region: off by 0.01
    mask[:, 12:16] = 0.3  # a soft edge under one half: static
    image = target.clone()
    image[:, :12] += 0.01
    image[:, 12:] += 0.1  # the static region: off by 0.1
    scores = score_image(image, target, mask)
    assert scores["psnr_dynamic"] == pytest.approx(40.0, abs=1e-3)
    assert scores["psnr_static"] == pytest.approx(20.0, abs=1e-3)
    assert scores["ssim_dynamic"] > scores["ssim_static"]
    everywhere = score_image(image, target, torch.ones(32, 32))
    assert everywhere["psnr_dynamic"] is not None and everywhere["psnr_static"] is None  # no static pixel


def test_a_view_without_a_full_image_score_leaves_the_mean_open_and_regions_average_where_present():
    """LPIPS missing on one view (no weights) has no mean; a region only some views have is their mean."""
    rows = [
        {"psnr": 20.0, "ssim": 0.9, "lpips": None, "psnr_dynamic": 10.0},
        {"psnr": 30.0, "ssim": 0.7, "lpips": 0.1},
    ]
    means = mean_scores(rows)
    assert means["psnr"] == 25.0 and means["ssim"] == pytest.approx(0.8) and means["lpips"] is None
    assert means["psnr_dynamic"] == 10.0 and means["psnr_static"] is None


def test_one_masked_view_makes_a_run_report_region_masks():
    target = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(2))
    mask = torch.zeros(32, 32)
    mask[:16] = 1.0
    views = [_view("a", target, {}, 0.0), _view("b", target, {}, 0.5, mask)]
    scores = evaluate_renderer(lambda camera: target, views)
    assert scores["region_masks"] and [("psnr_dynamic" in v) for v in scores["per_view"]] == [False, True]


def test_evaluation_views_are_evenly_spaced():
    views = list(range(10))
    assert eval_views(views, 4) == [0, 3, 6, 9] and eval_views(views, None) == views == eval_views(views, 20)
    with pytest.raises(ValueError, match="max_views must be >= 1, got 0"):
        eval_views(views, 0)
