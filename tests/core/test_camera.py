import pytest
import torch

from moegs.camera import Camera, intrinsics, look_at


def _camera(**kw):
    eye = torch.tensor([0.0, -4.0, 1.0])
    return Camera(
        K=intrinsics(50.0, 50.0, 32.0, 24.0),
        world_to_camera=look_at(eye, torch.zeros(3)),
        width=64,
        height=48,
        **kw,
    )


def test_look_at_is_opencv_and_rigid():
    cam = _camera()
    R = cam.world_to_camera[:3, :3]
    torch.testing.assert_close(R @ R.T, torch.eye(3), atol=1e-6, rtol=0)
    assert torch.det(R) == pytest.approx(1.0, abs=1e-6)
    # the target projects to the principal point, world up (+z) points to image up (-y)
    target = cam.world_to_camera @ torch.tensor([0.0, 0.0, 0.0, 1.0])
    assert target[2] > 0
    uv = cam.K @ (target[:3] / target[2])
    torch.testing.assert_close(uv[:2], torch.tensor([32.0, 24.0]), atol=1e-4, rtol=0)
    up = cam.world_to_camera[:3, :3] @ torch.tensor([0.0, 0.0, 1.0])
    assert up[1] < 0


def test_center_and_inverse():
    cam = _camera()
    torch.testing.assert_close(cam.center, torch.tensor([0.0, -4.0, 1.0]), atol=1e-5, rtol=0)
    torch.testing.assert_close(cam.camera_to_world @ cam.world_to_camera, torch.eye(4), atol=1e-5, rtol=0)


def test_rays_pass_through_pixel_centres():
    cam = _camera()
    origins, dirs = cam.rays()
    assert origins.shape == dirs.shape == (48, 64, 3)
    torch.testing.assert_close(dirs.norm(dim=-1), torch.ones(48, 64), atol=1e-6, rtol=0)
    # a point along the ray of pixel (x=10, y=7) projects back to its centre (10.5, 7.5)
    p = origins[7, 10] + 3.0 * dirs[7, 10]
    pc = cam.world_to_camera[:3, :3] @ p + cam.world_to_camera[:3, 3]
    uv = cam.K @ (pc / pc[2])
    torch.testing.assert_close(uv[:2], torch.tensor([10.5, 7.5]), atol=1e-4, rtol=0)


def test_scaled_keeps_rays():
    cam = _camera()
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (32, 24)
    assert half.fx == pytest.approx(25.0)
    # pixel centre (x+0.5) scales with the image, so the ray through a corner of the image is preserved
    _, d_full = cam.rays()
    _, d_half = half.rays()
    corner_full = (d_full[0, 0] + d_full[1, 1]) / 2
    torch.testing.assert_close(
        torch.nn.functional.normalize(corner_full, dim=0), d_half[0, 0], atol=1e-3, rtol=0
    )


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"K": torch.eye(2)}, r"Camera.K must have shape \[3, 3\]"),
        ({"world_to_camera": torch.eye(3)}, r"world_to_camera must have shape \[4, 4\]"),
        ({"width": 0}, "size must be positive"),
        ({"near": 2.0, "far": 1.0}, "0 < near < far"),
        ({"K": torch.full((3, 3), float("nan"))}, "non-finite"),
    ],
)
def test_bad_camera_errors(kw, message):
    args = dict(K=intrinsics(1.0, 1.0, 0.5, 0.5), world_to_camera=torch.eye(4), width=4, height=4)
    args.update(kw)
    with pytest.raises(ValueError, match=message):
        Camera(**args)
