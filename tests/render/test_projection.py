"""EWA projection and SH colours against straightforward float64 re-implementations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.scenes import projection_scene

from moegs import Camera
from moegs.camera import intrinsics, look_at
from moegs.render.projection import (
    BLUR_3DGS,
    DILATION_ANTIALIASED,
    SH_C0,
    SH_C1,
    SH_C2,
    SH_C3,
    covariance_3d,
    eval_sh,
    project,
    sh_basis,
    view_dirs,
)


# -- a per-Gaussian float64 reference, written from the formulas --------------------------------------
def _rotation(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def project_one(mean, quat, scale, opacity, cam: Camera, eps2d, antialiased):
    """``(mean2d, conic, opacity, depth, radius)`` of one Gaussian, or radius 0 when culled."""
    K, w2c = cam.K.double().numpy(), cam.world_to_camera.double().numpy()
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    W, H = cam.width, cam.height
    p = w2c[:3, :3] @ mean + w2c[:3, 3]
    if not cam.near < p[2] < cam.far:
        return None
    u, v = p[0] / p[2], p[1] / p[2]
    mean2d = np.array([fx * u + cx, fy * v + cy])
    tan_x, tan_y = W / (2 * fx), H / (2 * fy)  # half FoV; the Jacobian sees at most 1.3x of it
    uc = np.clip(u, -cx / fx - 0.3 * tan_x, (W - cx) / fx + 0.3 * tan_x)
    vc = np.clip(v, -cy / fy - 0.3 * tan_y, (H - cy) / fy + 0.3 * tan_y)
    J = np.array([[fx / p[2], 0, -fx * uc / p[2]], [0, fy / p[2], -fy * vc / p[2]]])
    M = _rotation(quat) @ np.diag(scale)
    cov = J @ w2c[:3, :3] @ (M @ M.T) @ w2c[:3, :3].T @ J.T
    blurred = cov + eps2d * np.eye(2)
    det = np.linalg.det(blurred)
    if not det > 0:
        return None
    inv = np.linalg.inv(blurred)
    mid = 0.5 * np.trace(blurred)
    radius = math.ceil(3 * math.sqrt(mid + math.sqrt(max(0.1, mid * mid - det))))  # 3DGS, gap floor 0.1
    if (
        mean2d[0] + radius <= 0
        or mean2d[0] - radius >= W
        or mean2d[1] + radius <= 0
        or mean2d[1] - radius >= H
    ):
        return None
    if antialiased:
        opacity = opacity * math.sqrt(max(np.linalg.det(cov), 0.0) / det)
    return mean2d, np.array([inv[0, 0], inv[0, 1], inv[1, 1]]), opacity, p[2], radius


@pytest.mark.parametrize("antialiased", [False, True])
def test_project_matches_per_gaussian_float64_reference(antialiased):
    means, quats, scales, opacities, cam = projection_scene()
    eps2d = DILATION_ANTIALIASED if antialiased else BLUR_3DGS
    proj = project(means, covariance_3d(quats, scales), opacities, cam, eps2d=eps2d, antialiased=antialiased)
    kinds = {"culled": 0, "kept": 0}
    for i in range(len(means)):
        ref = project_one(
            means[i].numpy(),
            quats[i].numpy(),
            scales[i].numpy(),
            float(opacities[i]),
            cam,
            eps2d,
            antialiased,
        )
        if ref is None:
            assert proj.radii[i] == 0, i
            kinds["culled"] += 1
            continue
        mean2d, conic, opacity, depth, radius = ref
        kinds["kept"] += 1
        assert int(proj.radii[i]) == radius, i
        np.testing.assert_allclose(proj.means2d[i].numpy(), mean2d, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(proj.conics[i].numpy(), conic, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(float(proj.opacities[i]), opacity, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(float(proj.depths[i]), depth, rtol=1e-12)
    assert kinds["culled"] > 30 and kinds["kept"] > 100, kinds  # the scene exercises both paths


def test_jacobian_is_clamped_off_axis():
    """Beyond 1.3x the half FoV the 2D covariance stops growing with the angle (3DGS)."""
    cam = Camera(K=intrinsics(20.0, 20.0, 10.0, 10.0), world_to_camera=torch.eye(4), width=20, height=20)
    covars = covariance_3d(torch.tensor([[1.0, 0, 0, 0]] * 2), torch.full((2, 3), 3.0))
    lim = 1.3 * 0.5  # 1.3 * tan(half FoV) for a centred principal point
    means = torch.tensor([[lim * 4.0, 0.0, 4.0], [lim * 4.0 * 2.0, 0.0, 4.0]])  # at and at twice the limit
    proj = project(means, covars, torch.ones(2), cam)
    torch.testing.assert_close(proj.conics[0], proj.conics[1])
    assert (proj.radii > 0).all()  # huge splats centred off-screen still reach the image


def test_culling_rules():
    cam = Camera(
        K=intrinsics(20.0, 20.0, 10.0, 8.0),
        world_to_camera=torch.eye(4),
        width=20,
        height=16,
        near=0.5,
        far=10.0,
    )
    means = torch.tensor(
        [
            [0.0, 0.0, 3.0],  # visible
            [0.0, 0.0, -3.0],  # behind the camera
            [0.0, 0.0, 0.4],  # in front of the near plane
            [0.0, 0.0, 12.0],  # beyond far
            [30.0, 0.0, 3.0],  # far off-screen to the right
            [0.0, 0.0, 3.0],  # degenerate: zero scale and no blur
        ]
    )
    scales = torch.full((6, 3), 0.05)
    scales[5] = 0.0
    covars = covariance_3d(torch.tensor([[1.0, 0, 0, 0]]).expand(6, 4), scales)
    radii = project(means, covars, torch.ones(6), cam).radii
    assert radii.tolist()[:5] == [radii[0].item(), 0, 0, 0, 0] and radii[0] > 0
    assert project(means[5:], covars[5:], torch.ones(1), cam, eps2d=0.0).radii.item() == 0
    assert project(means[5:], covars[5:], torch.ones(1), cam).radii.item() == 3  # the 0.3 blur alone: 3 px


def test_culled_gaussians_get_finite_values_and_zero_gradients():
    cam = Camera(K=intrinsics(20.0, 20.0, 10.0, 8.0), world_to_camera=torch.eye(4), width=20, height=16)
    means = torch.tensor([[0.1, 0.2, 3.0], [0.0, 0.0, 0.0], [0.5, 0.1, -2.0]], requires_grad=True)
    scales = torch.full((3, 3), 0.1, requires_grad=True)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 3, requires_grad=True)
    opacities = torch.full((3,), 0.5, requires_grad=True)
    proj = project(means, covariance_3d(quats, scales), opacities, cam, antialiased=True)
    assert proj.radii.tolist()[1:] == [0, 0]
    loss = sum(t.sum() for t in (proj.means2d, proj.conics, proj.opacities))
    loss.backward()
    for t in (means, scales, quats, opacities):
        assert torch.isfinite(t.grad).all()
    assert (scales.grad[1:] == 0).all() and (opacities.grad[1:] == 0).all()  # conics/compensation zeroed


def test_antialiased_compensation():
    """Opacity scales by sqrt(det(cov) / det(cov + 0.1 I)): ~1 for large splats, small for tiny ones."""
    cam = Camera(K=intrinsics(50.0, 50.0, 25.0, 25.0), world_to_camera=torch.eye(4), width=50, height=50)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]], dtype=torch.float64)
    scales = torch.tensor([[0.5, 0.5, 0.5], [1e-4, 1e-4, 1e-4]], dtype=torch.float64)
    covars = covariance_3d(torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64), scales)
    opacities = torch.tensor([0.8, 0.8], dtype=torch.float64)
    classic = project(means, covars, opacities, cam)
    aa = project(means, covars, opacities, cam, eps2d=DILATION_ANTIALIASED, antialiased=True)
    var = (50.0 / 2.0 * scales[:, 0]) ** 2  # isotropic screen variance
    expected = 0.8 * var / (var + DILATION_ANTIALIASED)
    torch.testing.assert_close(aa.opacities, expected)
    torch.testing.assert_close(classic.opacities, opacities)
    assert aa.opacities[0] > 0.79 and aa.opacities[1] < 1e-4
    torch.testing.assert_close(aa.conics[:, 0], 1.0 / (var + DILATION_ANTIALIASED))


# -- spherical harmonics --------------------------------------------------------------------------
def test_sh_basis_hand_values():
    x, y, z = 1 / 3, 2 / 3, 2 / 3
    got = sh_basis(torch.tensor([[x, y, z]], dtype=torch.float64), 3)[0]
    expected = [
        0.28209479177387814,
        -0.4886025119029199 * y,
        0.4886025119029199 * z,
        -0.4886025119029199 * x,
        1.0925484305920792 * x * y,
        -1.0925484305920792 * y * z,
        0.31539156525252005 * (2 * z * z - x * x - y * y),
        -1.0925484305920792 * x * z,
        0.5462742152960396 * (x * x - y * y),
        -0.5900435899266435 * y * (3 * x * x - y * y),
        2.890611442640554 * x * y * z,
        -0.4570457994644658 * y * (4 * z * z - x * x - y * y),
        0.3731763325901154 * z * (2 * z * z - 3 * x * x - 3 * y * y),
        -0.4570457994644658 * x * (4 * z * z - x * x - y * y),
        1.445305721320277 * z * (x * x - y * y),
        -0.5900435899266435 * x * (x * x - 3 * y * y),
    ]
    torch.testing.assert_close(got, torch.tensor(expected, dtype=torch.float64))
    # +z: only the zonal bases are non-zero; hand-evaluated numbers
    zonal = sh_basis(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), 3)[0]
    nonzero = {0: SH_C0, 2: SH_C1, 6: 2 * SH_C2[2], 12: 2 * SH_C3[3]}
    torch.testing.assert_close(
        zonal, torch.tensor([nonzero.get(i, 0.0) for i in range(16)], dtype=torch.float64)
    )
    assert abs(2 * SH_C2[2] - 0.6307831305050401) < 1e-15 and abs(2 * SH_C3[3] - 0.7463526651802308) < 1e-15


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_basis_is_orthonormal(degree):
    """Quadrature on a Fibonacci sphere: the 3DGS constants give an orthonormal real SH basis."""
    m = 20000
    k = torch.arange(m, dtype=torch.float64) + 0.5
    z = 1 - 2 * k / m
    phi = math.pi * (3 - math.sqrt(5)) * k
    r = torch.sqrt(1 - z * z)
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)
    basis = sh_basis(dirs, degree)
    gram = 4 * math.pi * basis.T @ basis / m
    torch.testing.assert_close(gram, torch.eye((degree + 1) ** 2, dtype=torch.float64), atol=1e-3, rtol=0)


def test_eval_sh_offset_clamp_and_degree_truncation():
    dirs = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    sh = torch.zeros(1, 16, 2, dtype=torch.float64)
    sh[0, 0] = torch.tensor([1.0, -5.0])  # DC: 0.5 + C0 * c, clamped at 0
    sh[0, 2, 0] = 1.0  # degree 1, z
    sh[0, 6, 0] = 1.0  # degree 2, zonal
    sh[0, 12, 0] = 1.0  # degree 3, zonal
    expected_0 = [
        0.5 + SH_C0,
        0.5 + SH_C0 + SH_C1,
        0.5 + SH_C0 + SH_C1 + 2 * SH_C2[2],
        0.5 + SH_C0 + SH_C1 + 2 * SH_C2[2] + 2 * SH_C3[3],
    ]
    for degree, value in enumerate(expected_0):
        got = eval_sh(sh, dirs, degree)[0]
        torch.testing.assert_close(got, torch.tensor([value, 0.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="needs 16 bases"):
        eval_sh(sh[:, :9], dirs, 3)


def test_view_direction_points_from_camera_centre_to_mean():
    w2c = look_at(
        torch.tensor([1.0, 2.0, 3.0]), torch.tensor([1.0, 2.0, 10.0]), up=torch.tensor([0.0, -1.0, 0.0])
    )
    cam = Camera(K=intrinsics(10.0, 10.0, 5.0, 5.0), world_to_camera=w2c, width=10, height=10)
    dirs = view_dirs(torch.tensor([[1.0, 2.0, 7.0], [4.0, 6.0, 3.0]]), cam)
    torch.testing.assert_close(dirs, torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]]), atol=1e-6, rtol=0)
