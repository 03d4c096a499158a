"""Temporal R² of the dynamic region: the direct formula, its anchors (static render 0, exact render 1),
which cameras count, and the evaluation that reports it."""

from __future__ import annotations

import pytest
import torch

from moegs.camera import Camera, intrinsics
from moegs.metrics.motion import MotionCapture


def camera(x: float = 0.0, t: float = 0.0) -> Camera:
    pose = torch.eye(4)
    pose[0, 3] = x
    return Camera(K=intrinsics(32, 32, 16.0, 16.0), world_to_camera=pose, width=32, height=32, time=t)


def sequence(gen, frames: int = 5):
    """Targets and masks ``[T, 32, 32, ...]``: a square moving right on a fixed background (LPIPS needs
    32 px)."""
    background = torch.rand(32, 32, 3, generator=gen)
    targets, masks = [], []
    for t in range(frames):
        image, mask = background.clone(), torch.zeros(32, 32)
        image[8:16, 4 * t : 4 * t + 8] = torch.tensor([1.0, 0.2, 0.1])
        mask[8:16, 4 * t : 4 * t + 8] = 1.0
        targets.append(image)
        masks.append(mask)
    return torch.stack(targets), torch.stack(masks)


def reference_r2(renders, targets, masks) -> float:
    """The definition, computed on the whole stacked sequence of one camera."""
    region = (masks > 0.5).any(0)
    d = renders.double().clamp(0, 1) - targets.double()
    g = targets.double()
    residual = ((d - d.mean(0)) ** 2).sum(-1)[:, region].sum()
    variation = ((g - g.mean(0)) ** 2).sum(-1)[:, region].sum()
    return float(1 - residual / variation)


def score(renders, targets, masks, cameras) -> float | None:
    motion = MotionCapture()
    for r, g, m, c in zip(renders, targets, masks, cameras, strict=True):
        motion.add(c, r, g, m)
    return motion.value()


@pytest.mark.parametrize(
    "flicker, soft", [(False, False), (True, False), (True, True)], ids=["still", "flickering", "soft-mask"]
)
def test_matches_the_definition(gen, flicker, soft):
    """A flickering background (lighting, exposure) is not motion: both sums stay inside the region. A
    soft mask (matting, resampling) counts where it exceeds one half, not wherever it is non-zero."""
    targets, masks = sequence(gen)
    if flicker:
        outside = (masks.sum(0) == 0)[None, ..., None]
        targets = torch.where(outside, targets * torch.linspace(0.6, 1.0, 5)[:, None, None, None], targets)
    if soft:  # a 0.3 halo over the rows the square crosses
        halo = torch.zeros_like(masks)
        halo[:, 6:18] = 0.3
        masks = torch.maximum(masks, halo)
    renders = targets + 0.2 * torch.randn(targets.shape, generator=gen)
    cams = [camera(t=t / 5) for t in range(5)]
    assert score(renders, targets, masks, cams) == pytest.approx(
        reference_r2(renders, targets, masks), abs=1e-9
    )


def test_a_static_render_scores_zero_and_the_truth_one(gen):
    targets, masks = sequence(gen)
    cams = [camera(t=t / 5) for t in range(5)]
    frozen = targets[0].expand_as(targets)  # the first frame shown at every time
    assert score(frozen, targets, masks, cams) == pytest.approx(0.0, abs=1e-9)
    assert score(targets, targets, masks, cams) == pytest.approx(1.0, abs=1e-12)
    backwards = targets.flip(0)  # moves, but the wrong way
    assert score(backwards, targets, masks, cams) < 0.0


def test_only_cameras_seen_at_several_times_count(gen):
    targets, masks = sequence(gen, frames=4)
    moving = [camera(x=0.1 * t, t=t / 4) for t in range(4)]  # a monocular sweep: every view its own camera
    assert score(targets, targets, masks, moving) is None
    two = [camera(t=0.0), camera(t=0.5), camera(x=1.0, t=0.0), camera(x=1.0, t=0.5)]
    assert score(targets, targets, masks, two) is None  # each camera seen twice < MIN_TIMES
    assert score(targets, targets, torch.zeros_like(masks), [camera(t=t) for t in range(4)]) is None


def test_shapes_are_checked(gen):
    targets, masks = sequence(gen)
    with pytest.raises(ValueError, match="must share"):
        MotionCapture().add(camera(), targets[0], targets[0], masks[0][:, :4])


def test_evaluation_reports_it(gen):
    from moegs.data.scene import View
    from moegs.train.evaluate import evaluate_renderer

    targets, masks = sequence(gen)
    views = [
        View(camera(t=t / 5), (lambda i=t: targets[i]), f"v{t}", load_mask=(lambda i=t: masks[i]))
        for t in range(5)
    ]
    frozen = evaluate_renderer(lambda cam: targets[0], views, regions=True)
    exact = evaluate_renderer(lambda cam: targets[round(cam.time * 5)], views, regions=True)
    assert frozen["motion_r2"] == pytest.approx(0.0, abs=1e-9)
    assert exact["motion_r2"] == pytest.approx(1.0)
    first_three = evaluate_renderer(lambda cam: targets[round(cam.time * 5)], views[:3], regions=True)
    assert first_three["motion_r2"] == pytest.approx(1.0)  # every view counts, the one at t = 0 too
    assert evaluate_renderer(lambda cam: targets[0], views, regions=False)["motion_r2"] is None
