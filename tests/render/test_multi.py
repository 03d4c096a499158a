"""Single-pass multi-expert rendering equals separate renders."""

from __future__ import annotations

import pytest
import torch

from moegs.render import rasterize, rasterize_multi


def _experts(make_frame, cam, counts, **kwargs):
    return [make_frame(n, cam, seed=10 + k, **kwargs) for k, n in enumerate(counts)]


@pytest.mark.parametrize("counts", [(30,), (25, 40), (10, 0, 35)])
def test_single_pass_equals_separate_renders(counts, backend, make_camera, make_frame):
    cam = make_camera(24, 18)
    frames = _experts(make_frame, cam, counts)
    multi = rasterize_multi(frames, cam, return_stats=True, backend=backend)
    k = len(counts)
    assert multi.images.shape == (k, 18, 24, 3) and multi.alphas.shape == (k, 18, 24)
    assert multi.info["expert_id"].tolist() == sum(([i] * n for i, n in enumerate(counts)), [])
    start = 0
    for i, frame in enumerate(frames):
        single = rasterize(frame, cam, return_stats=True, backend=backend)
        torch.testing.assert_close(multi.images[i], single.image, atol=1e-6, rtol=0)
        torch.testing.assert_close(multi.alphas[i], single.alpha, atol=1e-6, rtol=0)
        torch.testing.assert_close(multi.depths[i], single.depth, atol=1e-5, rtol=0)
        part = slice(start, start + len(frame))
        torch.testing.assert_close(multi.info["contrib"][part], single.info["contrib"], atol=1e-5, rtol=0)
        assert torch.equal(multi.info["radii"][part], single.info["radii"])
        start += len(frame)


def _render_and_backprop(frames, camera, weights, *, single_pass: bool, backend: str):
    """Render ``frames`` (``[K, H, W, C]`` images), backprop ``sum(images * weights)`` into fresh
    leaf means; returns ``(images, contrib [N_total], [grad means_k])``."""
    leaves = [f.means.detach().clone().requires_grad_(True) for f in frames]
    for f, m in zip(frames, leaves, strict=True):
        f.means = m
    if single_pass:
        out = rasterize_multi(frames, camera, return_stats=True, backend=backend)
        images, contrib = out.images, out.info["contrib"]
    else:
        outs = [rasterize(f, camera, return_stats=True, backend=backend) for f in frames]
        images = torch.stack([o.image for o in outs])
        contrib = torch.cat([o.info["contrib"] for o in outs])
    (images * weights).sum().backward()
    return images.detach(), contrib, [m.grad for m in leaves]


def test_single_pass_gradients_equal_separate_renders(make_camera, make_frame):
    cam = make_camera(20, 16)
    frames = _experts(make_frame, cam, (15, 20), dtype=torch.float64)
    weights = torch.rand(2, 16, 20, 3, dtype=torch.float64)
    _, _, multi = _render_and_backprop(frames, cam, weights, single_pass=True, backend="torch")
    _, _, separate = _render_and_backprop(frames, cam, weights, single_pass=False, backend="torch")
    for a, b in zip(multi, separate, strict=True):
        torch.testing.assert_close(a, b)


def test_kernel_skips_a_finished_expert_without_changing_anything(
    make_camera, make_frame, require_cpu_kernel
):
    """Expert 0 is a wall of opaque splats in front: it finishes most pixels early, so the compiled
    kernel skips its remaining Gaussians (forward) and those behind its last contributors (backward).
    Single-pass images, contributions and gradients must still equal separate reference renders."""
    cam = make_camera(48, 32)
    wall = make_frame(400, cam, scale=0.4, depth=(2.0, 2.5), opacity=(0.95, 0.99), seed=1)
    scattered = make_frame(300, cam, depth=(1.5, 6.0), seed=2)
    assert (rasterize(wall, cam, backend="torch").alpha > 0.999).float().mean() > 0.5  # T near 1e-4: finished
    weights = torch.rand(2, 32, 48, 3, generator=torch.Generator().manual_seed(0))
    img_m, con_m, grad_m = _render_and_backprop(
        [wall, scattered], cam, weights, single_pass=True, backend="cpu"
    )
    img_s, con_s, grad_s = _render_and_backprop(
        [wall, scattered], cam, weights, single_pass=False, backend="torch"
    )
    torch.testing.assert_close(img_m, img_s, atol=1e-5, rtol=0)
    torch.testing.assert_close(con_m, con_s, atol=1e-4, rtol=1e-5)
    for a, b in zip(grad_m, grad_s, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5 * b.abs().max().item(), rtol=1e-4)  # as test_cpu_kernel


def test_backgrounds_shared_or_per_expert(make_camera, make_frame):
    cam = make_camera(16, 12)
    frames = _experts(make_frame, cam, (10, 12), channels=2)
    plain = rasterize_multi(frames, cam, backend="torch")
    per_expert = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    for backgrounds, expected in (
        (torch.tensor([0.5, 0.25]), torch.tensor([[0.5, 0.25]] * 2)),
        (per_expert, per_expert),
    ):
        out = rasterize_multi(frames, cam, backgrounds=backgrounds, backend="torch")
        torch.testing.assert_close(
            out.images, plain.images + (1 - plain.alphas)[..., None] * expected[:, None, None]
        )
    with pytest.raises(ValueError, match=r"backgrounds must have shape \[2, 2\]"):
        rasterize_multi(frames, cam, backgrounds=torch.zeros(3, 2), backend="torch")


def test_extras_give_per_expert_weight_maps_in_the_same_pass(make_camera, make_frame):
    """Routing weights splatted with the experts' geometry, as the router needs them."""
    cam = make_camera(20, 14)
    frames = _experts(make_frame, cam, (12, 18, 9))
    weights = [torch.rand(len(f), 4) for f in frames]
    out = rasterize_multi(frames, cam, extras=weights, backgrounds=torch.ones(3), backend="torch")
    assert out.extras.shape == (3, 14, 20, 4)
    as_colors = rasterize_multi(
        [f.with_colors(w) for f, w in zip(frames, weights, strict=True)], cam, backend="torch"
    )
    torch.testing.assert_close(out.extras, as_colors.images)
    with pytest.raises(ValueError, match="one tensor per frame"):
        rasterize_multi(frames, cam, extras=weights[:2], backend="torch")
    with pytest.raises(ValueError, match=r"extras\[1\] must have shape \[18, 4\]"):
        rasterize_multi(frames, cam, extras=[weights[0], weights[2], weights[1]], backend="torch")


@pytest.mark.parametrize("antialiased", [False, True])
def test_sh_experts_and_antialiasing(antialiased, make_camera, make_frame):
    cam = make_camera(16, 12)
    frames = _experts(make_frame, cam, (8, 14), sh_degree=3)
    multi = rasterize_multi(frames, cam, sh_degree=1, antialiased=antialiased, backend="torch")
    for i, f in enumerate(frames):
        single = rasterize(f, cam, sh_degree=1, antialiased=antialiased, backend="torch")
        torch.testing.assert_close(multi.images[i], single.image, atol=1e-6, rtol=0)


def test_errors_name_the_frame(make_camera, make_frame):
    cam = make_camera(8, 8)
    frames = _experts(make_frame, cam, (3, 4))
    frames[1].opacities[0] = float("nan")
    with pytest.raises(FloatingPointError, match=r"frames\[1\]\.opacities"):
        rasterize_multi(frames, cam)
    mixed = [make_frame(3, cam), make_frame(3, cam, sh_degree=1)]
    with pytest.raises(ValueError, match="mixes `sh` and `colors`"):
        rasterize_multi(mixed, cam)
    with pytest.raises(ValueError, match="at least one"):
        rasterize_multi([], cam)
