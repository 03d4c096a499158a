"""Camera paths of ``moegs render`` (``moegs.render_path``) and the files it and ``moegs train`` leave for
people (``moegs.outputs``): valid poses that look at the centre, closed smooth loops, time advancing."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.outputs import comparison_strip, describe_run, format_scores, pad_even, write_loss_curve
from moegs.render_path import (
    PATHS,
    camera_path,
    is_forward_facing,
    look_at_centre,
    orbit_path,
    path_times,
    spiral_path,
    world_up,
)

CENTRE = torch.tensor([0.5, -0.2, 0.3])


def _camera(eye, target=CENTRE, up=(0.0, 0.0, 1.0), time=0.0) -> Camera:
    w2c = look_at(torch.tensor(eye, dtype=torch.float32), target, torch.tensor(up))
    return Camera(K=intrinsics(40.0, 40.0, 16.0, 12.0), world_to_camera=w2c, width=32, height=24, time=time)


def ring(n: int = 12, radius: float = 3.0, height: float = 1.5) -> list[Camera]:
    """``n`` cameras around ``CENTRE`` (z up) at ``radius`` and ``height``, looking at it (a D-NeRF-like
    rig); heights alternate by +-0.2 so the mean is ``height``."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n + 0.3
        h = height + (0.2 if k % 2 else -0.2)
        eye = CENTRE + torch.tensor([radius * math.cos(a), radius * math.sin(a), h])
        out.append(_camera(eye.tolist(), time=k / (n - 1)))
    return out


def forward_rig() -> list[Camera]:
    """A 3x3 grid of cameras at y = -4 looking at ``CENTRE`` (an N3V-like forward-facing rig)."""
    return [
        _camera([CENTRE[0].item() + dx, -4.0, CENTRE[2].item() + dz])
        for dx in (-0.5, 0, 0.5)
        for dz in (-0.3, 0, 0.3)
    ]


def assert_valid_and_looking_at(cameras: list[Camera], target: torch.Tensor) -> None:
    """Rotations are proper and orthonormal; ``target`` projects to the principal point in front."""
    for cam in cameras:
        R = cam.world_to_camera[:3, :3].double()
        torch.testing.assert_close(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-5, rtol=0)
        assert torch.det(R).item() == pytest.approx(1.0, abs=1e-5)
        p = cam.world_to_camera.double() @ torch.cat([target.double(), torch.ones(1, dtype=torch.float64)])
        assert p[2] > 0
        uv = cam.K.double() @ (p[:3] / p[2])
        torch.testing.assert_close(
            uv[:2], torch.tensor([cam.cx, cam.cy], dtype=torch.float64), atol=1e-2, rtol=0
        )


def steps(cameras: list[Camera], closed: bool) -> torch.Tensor:
    """Distances between consecutive camera centres (and from the last back to the first when ``closed``)."""
    centres = torch.stack([c.center.double() for c in cameras])
    if closed:
        centres = torch.cat([centres, centres[:1]])
    return (centres[1:] - centres[:-1]).norm(dim=-1)


def test_the_look_at_centre_and_up_of_a_rig():
    torch.testing.assert_close(look_at_centre(ring()), CENTRE.double(), atol=1e-2, rtol=0)
    torch.testing.assert_close(look_at_centre(forward_rig()), CENTRE.double(), atol=3e-2, rtol=0)
    torch.testing.assert_close(
        world_up(forward_rig()), torch.tensor([0.0, 0, 1], dtype=torch.float64), atol=1e-6, rtol=0
    )
    assert not is_forward_facing(ring()) and is_forward_facing(forward_rig())


def test_orbit_circles_the_centre_at_the_cameras_radius_and_height_and_closes():
    cams = ring()
    path = orbit_path(cams, cams[0], 24)
    assert len(path) == 24 and all((c.width, c.height) == (32, 24) for c in path)
    assert_valid_and_looking_at(path, look_at_centre(cams))
    offsets = torch.stack([c.center.double() for c in path]) - CENTRE.double()
    torch.testing.assert_close(offsets[:, 2], torch.full((24,), 1.5, dtype=torch.float64), atol=1e-4, rtol=0)
    torch.testing.assert_close(
        offsets[:, :2].norm(dim=-1), torch.full((24,), 3.0, dtype=torch.float64), atol=1e-4, rtol=0
    )
    d = steps(path, closed=True)  # equal steps all round, the last frame back to the first included
    assert d.max() - d.min() < 1e-4 and d.max() < 2 * math.pi * 3.0 / 24 * 1.01
    # it starts at the first camera's bearing
    start, first = offsets[0, :2], cams[0].center.double()[:2] - CENTRE.double()[:2]
    assert torch.nn.functional.cosine_similarity(start, first, dim=0) > 0.999


def test_spiral_stays_near_a_forward_rig_looks_at_the_centre_and_closes():
    cams = forward_rig()
    path = spiral_path(cams, cams[4], 40)
    target = look_at_centre(cams).float()
    assert_valid_and_looking_at(path, target)
    centres = torch.stack([c.center for c in path])
    mean = torch.stack([c.center for c in cams]).mean(0)
    assert ((centres - mean).abs() <= torch.tensor([0.51, 0.31, 0.31])).all()  # within the rig's extent
    d = steps(path, closed=True)
    assert d.max() < 0.25 and d.max() < 3 * d.median()  # smooth, no jump anywhere (the closing step too)


@pytest.mark.parametrize("kind", ["orbit", "spiral", "auto"])
def test_time_advances_uniformly_over_the_range(kind):
    cams = forward_rig() if kind == "spiral" else ring()
    name, path = camera_path(kind, cams, cams[0], 9, (0.2, 0.6))
    assert name == ("orbit" if kind == "auto" else kind)
    times = [c.time for c in path]
    assert times == pytest.approx([0.2 + 0.05 * k for k in range(9)])
    assert path_times(1) == [0.0] and path_times(3) == [0.0, 0.5, 1.0]


def test_auto_picks_spiral_for_a_forward_facing_rig():
    assert camera_path("auto", forward_rig(), forward_rig()[0], 4)[0] == "spiral"


def test_bad_paths_are_refused_naming_the_argument():
    with pytest.raises(ValueError, match="--path: expected one of auto, orbit, spiral, got 'zigzag'"):
        camera_path("zigzag", ring(), ring()[0], 4)
    with pytest.raises(ValueError, match="frames must be >= 1, got 0"):
        path_times(0)
    eye = torch.zeros(3)  # a panorama: one centre looking all round, nothing to orbit around
    panorama = [_camera(eye.tolist(), torch.tensor([math.cos(a), math.sin(a), 0.0])) for a in (0, 2, 4)]
    with pytest.raises(ValueError, match="use --path spiral or test"):
        orbit_path(panorama, panorama[0], 4)


def test_the_cli_names_every_path_and_synthetic_scene():
    """``moegs.cli`` names them without importing torch; they must be the modules' own."""
    from moegs.cli import RENDER_PATHS, SYNTHETIC_SCENES
    from moegs.data.synthetic import list_synthetic

    assert RENDER_PATHS == PATHS and list(SYNTHETIC_SCENES) == list_synthetic()


def test_strip_is_truth_render_error_and_pad_makes_sizes_even():
    truth = np.full((5, 7, 3), 100, np.uint8)
    render = truth.copy()
    render[1, 2] = 200
    strip = comparison_strip(render, truth)
    assert strip.shape == (5, 21, 3)
    assert (strip[:, :7] == truth).all() and (strip[:, 7:14] == render).all()
    error = strip[:, 14:].astype(int)
    assert error[1, 2].sum() > 3 * 200 and (error[0, 0] == error[4, 6]).all() and error[0, 0].sum() < 30
    padded = pad_even(strip)
    assert (
        padded.shape == (6, 22, 3)
        and (padded[5] == padded[4]).all()
        and (padded[:, 21] == padded[:, 20]).all()
    )
    assert pad_even(padded).shape == padded.shape
    with pytest.raises(ValueError, match=r"render \[5, 7, 3\] and ground truth \[4, 7, 3\] differ in shape"):
        comparison_strip(render, truth[:4])


def test_loss_curve_run_listing_and_scores(tmp_path):
    import json

    paths = write_loss_curve({"static": [0.5, 0.4, 0.3, 0.35, 0.2]}, tmp_path, "static on x")
    assert paths == [tmp_path / "loss.json", tmp_path / "loss.png"]
    assert json.loads(paths[0].read_text()) == {
        "curves": {"static": {"first_step": 1, "loss": [0.5, 0.4, 0.3, 0.35, 0.2]}}
    }
    assert paths[1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "extra").mkdir()
    lines = describe_run(tmp_path)
    assert [name for name, _ in lines] == ["config.json", "loss.json", "loss.png", "extra/"]
    assert lines[0][1].startswith("what trained") and lines[-1] == ("extra/", "")
    scores = {"psnr": 24.125, "ssim": 0.81234, "lpips": None, "lpips_unavailable": "no weights\nmore"}
    assert format_scores(scores) == "PSNR 24.12  SSIM 0.8123  LPIPS n/a (no weights)"
    assert format_scores({**scores, "lpips": 0.12345}) == "PSNR 24.12  SSIM 0.8123  LPIPS 0.1235"
    assert format_scores(None) == "not evaluated (the scene has no test views)"
