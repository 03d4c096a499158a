"""The compiled CPU projection (`moegs.render._cpu.project`, `covariance_3d`) against its torch reference
(`moegs.render.projection`): the forward equal to the bit (radii included), the gradients of
means, covariances and opacities to rtol 2e-3 with an absolute floor of 1e-5 x the largest reference
gradient (the kernel's chain rule runs in double, the reference's autograd in float32, which on a few
ill-conditioned Gaussians is itself ~1e-3 off a float64 evaluation). Scenes with Gaussians behind the
camera, beyond the far plane, off-screen, far off-axis (clamped Jacobian) and degenerate; determinism
across thread counts; the dtype fallback."""

from __future__ import annotations

import pytest
import torch
from helpers.scenes import projection_scene

from moegs.render import _cpu
from moegs.render.projection import BLUR_3DGS, DILATION_ANTIALIASED, covariance_3d, project

pytestmark = pytest.mark.skipif(not _cpu.is_available(), reason=f"compiled CPU kernel: {_cpu.load_error()}")

OUTPUTS = ("means2d", "conics", "opacities", "depths", "radii")


def _inputs(n=2000, seed=1, degenerate=0.05):
    """float32 leaves: means, covariances (some of rank 1) and opacities, and the camera."""
    means, quats, scales, opacities, cam = projection_scene(n=n, seed=seed)
    scales = scales.clone()
    scales[: int(degenerate * n), 1:] = 0.0  # needles: the blur alone keeps det > 0
    covars = covariance_3d(quats, scales)
    leaves = [t.float().detach().requires_grad_(True) for t in (means, covars, opacities)]
    return leaves, cam


def _loss(proj, weights):
    return sum((getattr(proj, k) * w).sum() for k, w in weights.items())


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("seed", [1, 2])
def test_forward_bit_identical_and_gradients_match(antialiased, seed):
    (means, covars, opacities), cam = _inputs(seed=seed)
    eps2d = DILATION_ANTIALIASED if antialiased else BLUR_3DGS
    ours = _cpu.project(means, covars, opacities, cam, eps2d=eps2d, antialiased=antialiased)
    ref = project(means, covars, opacities, cam, eps2d=eps2d, antialiased=antialiased)
    for name in OUTPUTS:
        assert torch.equal(getattr(ours, name), getattr(ref, name)), name
    kept = ref.radii > 0
    assert 0.2 < kept.float().mean() < 0.9  # the scene culls and keeps

    gen = torch.Generator().manual_seed(seed)
    weights = {k: torch.randn(getattr(ref, k).shape, generator=gen) for k in OUTPUTS if k != "radii"}
    got = torch.autograd.grad(_loss(ours, weights), (means, covars, opacities))
    want = torch.autograd.grad(_loss(ref, weights), (means, covars, opacities))
    for name, g, w in zip(("means", "covars", "opacities"), got, want, strict=True):
        scale = float(w.abs().max())
        torch.testing.assert_close(g, w, rtol=2e-3, atol=1e-5 * scale, msg=lambda m, n=name: f"grad {n}: {m}")


def test_clamped_jacobian_and_depth_limits_are_exercised():
    (means, covars, opacities), cam = _inputs()
    points = means.detach() @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    z = points[:, 2]
    assert (z < cam.near).any() and (z > cam.far).any() and ((z > cam.near) & (z < cam.far)).any()
    off_axis = (points[:, 0] / z).abs() > 2.0 * cam.width / (2 * cam.fx)
    assert (off_axis & (z > cam.near)).any()  # some Jacobians are evaluated at the clamp


def test_deterministic_across_thread_counts():
    (means, covars, opacities), cam = _inputs(n=20000)
    threads = torch.get_num_threads()
    runs = []
    try:
        for t in (1, 2):
            torch.set_num_threads(t)
            proj = _cpu.project(means, covars, opacities, cam)
            grads = torch.autograd.grad(proj.means2d.sum() + proj.conics.sum(), (means, covars, opacities))
            runs.append([proj.means2d, proj.conics, proj.radii, *grads])
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(*runs, strict=True):
        assert torch.equal(a, b)


def test_other_dtypes_go_to_the_reference():
    (means, covars, opacities), cam = _inputs(n=50)
    args = [t.detach().double() for t in (means, covars, opacities)]
    ours, ref = _cpu.project(*args, cam), project(*args, cam)
    assert ours.means2d.dtype == torch.float64
    for name in OUTPUTS:
        assert torch.equal(getattr(ours, name), getattr(ref, name)), name
    _, quats, scales, _, _ = projection_scene(n=50)
    assert torch.equal(_cpu.covariance_3d(quats, scales), covariance_3d(quats, scales))  # float64


def test_shapes_are_checked():
    (means, covars, opacities), cam = _inputs(n=10)
    with pytest.raises(ValueError, match=r"covars \[N, 3, 3\]"):
        _cpu.project(means, covars[:, :2], opacities, cam)
    with pytest.raises(ValueError, match=r"scales \[N, 3\]"):
        _cpu.covariance_3d(torch.ones(4, 4), torch.ones(4, 2))


@pytest.mark.parametrize("seed", [1, 2])
def test_covariance_bit_identical_and_gradients_match(seed):
    _, quats, scales, _, _ = projection_scene(n=2000, seed=seed)  # quaternions not normalised
    quats, scales = (t.float().requires_grad_(True) for t in (quats, scales))
    ours, ref = _cpu.covariance_3d(quats, scales), covariance_3d(quats, scales)
    assert torch.equal(ours, ref)
    weights = torch.randn(ref.shape, generator=torch.Generator().manual_seed(seed))
    got = torch.autograd.grad((ours * weights).sum(), (quats, scales))
    want = torch.autograd.grad((ref * weights).sum(), (quats, scales))
    for name, g, w in zip(("quats", "scales"), got, want, strict=True):
        torch.testing.assert_close(
            g, w, rtol=1e-4, atol=1e-5 * float(w.abs().max()), msg=lambda m, n=name: f"{n}: {m}"
        )
