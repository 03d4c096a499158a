"""The compiled CPU compositing kernel (`moegs.render._cpu`) against the torch oracle `_torch._composite`.

Images/alphas to 1e-5 (abs), contrib to 1e-4 (rel), gradients of all four inputs to rtol 1e-4 with an
absolute floor of 1e-5 x the largest reference gradient; determinism (bit-identical across runs and
thread counts); empty, off-screen, behind-camera inputs; argument validation.
"""

from __future__ import annotations

import math

import pytest
import torch

from moegs import kernels
from moegs.render import _cpu
from moegs.render._torch import ALPHA_MAX, _composite

pytestmark = pytest.mark.skipif(
    not _cpu.is_available(),
    reason=f"compiled CPU kernel not available ({_cpu.load_error()}); "
    "build it with `pip install -e .` or `python -m moegs.kernels build`",
)


def make_scene(
    n: int,
    width: int,
    height: int,
    channels: int = 3,
    groups: int = 1,
    *,
    radius: tuple[float, float] = (2.0, 12.0),
    opaque: float = 0.0,
    tiny: float = 0.0,
    huge: float = 0.0,
    culled: float = 0.1,
    thin: bool = False,
    seed: int = 0,
) -> dict:
    """Projected Gaussians: ``means2d`` partly off-screen (10% margin), radii from random 2D covariances.

    ``opaque``: fraction with opacity 0.995 (triggers the ALPHA_MAX clamp and early termination);
    ``tiny``: fraction with sub-pixel footprints (radius 1); ``huge``: fraction with radii up to 3x the
    image size; ``culled``: fraction with radius 0 (behind the camera); ``thin``: needle-like splats
    (minor axis 2-10% of the major one; most of the bounding box is empty).
    """
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=gen)

    size = torch.tensor([width, height], dtype=torch.float32)
    means2d = (rand(n, 2) * 1.2 - 0.1) * size
    sigma = (radius[0] + (radius[1] - radius[0]) * rand(n)) / 3.0
    pick = rand(n)
    sigma = torch.where(pick < tiny, 0.2 + 0.1 * rand(n), sigma)
    sigma = torch.where((pick >= tiny) & (pick < tiny + huge), max(width, height) * rand(n), sigma)
    theta = math.pi * rand(n)
    s_major, s_minor = sigma, sigma * ((0.02 + 0.08 * rand(n)) if thin else (0.3 + 0.7 * rand(n)))
    c, s = torch.cos(theta), torch.sin(theta)
    # covariance R diag(s_major^2, s_minor^2) R^T, plus the usual 0.3 px^2 low-pass blur
    blur = 0.01 if thin else 0.3
    cxx = c * c * s_major**2 + s * s * s_minor**2 + blur
    cyy = s * s * s_major**2 + c * c * s_minor**2 + blur
    cxy = c * s * (s_major**2 - s_minor**2)
    det = cxx * cyy - cxy * cxy
    conics = torch.stack([cyy / det, -cxy / det, cxx / det], dim=1)
    mid = 0.5 * (cxx + cyy)
    lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
    radii = torch.ceil(3.0 * torch.sqrt(lam)).to(torch.int32)
    radii[rand(n) < culled] = 0
    opacities = torch.sigmoid(torch.randn(n, generator=gen))
    opacities = torch.where(rand(n) < opaque, torch.full_like(opacities, 0.995), opacities)
    depths = 1.0 + 4.0 * rand(n)
    depths[: n // 10] = depths[n // 10 : 2 * (n // 10)]  # exact ties: order must fall back to the index
    return {
        "means2d": means2d,
        "conics": conics,
        "opacities": opacities,
        "colors": rand(n, channels),
        "depths": depths,
        "radii": radii,
        "width": width,
        "height": height,
        "groups": torch.randint(0, groups, (n,), generator=gen),
        "num_groups": groups,
    }


DIFF = ("means2d", "conics", "opacities", "colors")


def run(fn, scene: dict, seed: int = 1):
    """Forward, then backward of a random linear loss of image and alpha; returns outputs and gradients."""
    inputs = {k: (v.detach().clone().requires_grad_(True) if k in DIFF else v) for k, v in scene.items()}
    image, alpha, contrib = fn(**inputs)
    gen = torch.Generator().manual_seed(seed)
    weights_image = torch.randn(image.shape, generator=gen)
    weights_alpha = torch.randn(alpha.shape, generator=gen)
    loss = (image * weights_image).sum() + (alpha * weights_alpha).sum()
    loss.backward()
    return image.detach(), alpha.detach(), contrib, {k: inputs[k].grad for k in DIFF}


def assert_matches_reference(scene: dict) -> None:
    ref_image, ref_alpha, ref_contrib, ref_grads = run(_composite, scene)
    image, alpha, contrib, grads = run(_cpu.composite, scene)
    torch.testing.assert_close(image, ref_image, rtol=0, atol=1e-5)
    torch.testing.assert_close(alpha, ref_alpha, rtol=0, atol=1e-5)
    contrib_scale = max(ref_contrib.abs().max().item(), 1e-12)
    torch.testing.assert_close(contrib, ref_contrib, rtol=1e-4, atol=1e-4 * contrib_scale)
    for name in DIFF:
        scale = max(ref_grads[name].abs().max().item(), 1e-12)
        torch.testing.assert_close(
            grads[name], ref_grads[name], rtol=1e-4, atol=1e-5 * scale, msg=lambda m, n=name: f"grad {n}: {m}"
        )


CASES = {
    # name: (n, width, height, channels, groups, extra)
    "single": (1, 31, 17, 3, 1, {"culled": 0.0}),
    "mono-31x17": (60, 31, 17, 1, 1, {}),
    "rgb-2groups-64": (400, 64, 64, 3, 2, {}),
    "9ch-3groups-opaque": (1500, 64, 64, 9, 3, {"opaque": 0.3}),
    "16ch-2groups-128x96": (3000, 128, 96, 16, 2, {}),
    "rgb-opaque-128x96": (3000, 128, 96, 3, 1, {"opaque": 0.5}),
    "tiny-splats": (2000, 64, 48, 3, 1, {"tiny": 0.7}),
    "huge-splats": (40, 31, 17, 3, 2, {"huge": 0.5}),
    "needles": (1500, 64, 64, 3, 2, {"thin": True, "opaque": 0.2}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_matches_torch_reference(case):
    n, width, height, channels, groups, extra = CASES[case]
    assert_matches_reference(make_scene(n, width, height, channels, groups, **extra))


def test_scene_exercises_clamp_and_early_termination():
    """The opaque scene really hits the ALPHA_MAX clamp and finishes pixels (T below T_MIN)."""
    scene = make_scene(3000, 128, 96, 3, 1, opaque=0.5)
    _, alpha, _ = _cpu.composite(**scene)  # equal to the reference (test above); cheaper
    assert alpha.max() > 1 - 2e-4  # some pixel reached T ~ T_MIN: later Gaussians were not composited
    d = scene["means2d"] - (scene["means2d"].floor() + 0.5)  # offset from the nearest pixel centre
    a, b, c = scene["conics"].unbind(1)
    power = -0.5 * (a * d[:, 0] ** 2 + c * d[:, 1] ** 2) - b * d[:, 0] * d[:, 1]
    assert (scene["opacities"] * torch.exp(power) > ALPHA_MAX).any()


def test_deterministic_across_runs_and_thread_counts():
    scene = make_scene(2000, 64, 64, 3, 2, opaque=0.2)
    threads = torch.get_num_threads()
    try:
        first = run(_cpu.composite, scene)
        again = run(_cpu.composite, scene)
        torch.set_num_threads(1)
        single = run(_cpu.composite, scene)
    finally:
        torch.set_num_threads(threads)
    for other in (again, single):
        for x, y in zip(first[:3], other[:3], strict=True):
            assert torch.equal(x, y)
        for name in DIFF:
            assert torch.equal(first[3][name], other[3][name])


def test_empty_input():
    scene = make_scene(0, 31, 17, 4, 2)
    image, alpha, contrib, grads = run(_cpu.composite, scene)
    assert image.shape == (2, 17, 31, 4) and alpha.shape == (2, 17, 31) and contrib.shape == (0,)
    assert not image.any() and not alpha.any()
    assert grads["means2d"].shape == (0, 2) and grads["colors"].shape == (0, 4)


def test_off_screen_and_culled_only():
    scene = make_scene(50, 31, 17, 3, 1, culled=0.0)
    scene["means2d"] = scene["means2d"] + torch.tensor([1000.0, -1000.0])  # far outside the image
    scene["radii"][:10] = 0
    image, alpha, contrib, grads = run(_cpu.composite, scene)
    assert not image.any() and not alpha.any() and not contrib.any()
    for name in DIFF:
        assert not grads[name].any()
    assert_matches_reference(scene)


def test_default_groups_float64_inputs_and_no_grad():
    """groups=None means one group; float64 inputs give float32 outputs and float64 gradients."""
    scene = make_scene(300, 40, 30, 3, 1)
    scene.pop("groups"), scene.pop("num_groups")
    scene64 = {k: (v.double() if k in DIFF else v) for k, v in scene.items()}
    ref = run(_composite, scene)
    out = run(_cpu.composite, scene64)
    assert out[0].dtype == torch.float32 and out[3]["means2d"].dtype == torch.float64
    torch.testing.assert_close(out[0], ref[0], rtol=0, atol=1e-5)
    with torch.no_grad():
        image, _, _ = _cpu.composite(**scene)
    torch.testing.assert_close(image, ref[0], rtol=0, atol=1e-5)


def test_contrib_has_no_grad():
    scene = make_scene(20, 16, 16)
    scene["opacities"].requires_grad_(True)
    _, _, contrib = _cpu.composite(**scene)
    assert not contrib.requires_grad


@pytest.mark.parametrize(
    "name, value, match",
    [
        ("means2d", torch.zeros(5, 3), "means2d"),
        ("conics", torch.zeros(4, 3), "conics"),
        ("opacities", torch.zeros(5, 1), "opacities"),
        ("colors", torch.zeros(5), "colors"),
        ("depths", torch.zeros(6), "depths"),
        ("radii", torch.zeros(5), "radii"),
        ("groups", torch.full((5,), 2), "groups"),
        ("width", 0, "width"),
        ("num_groups", 0, "num_groups"),
    ],
)
def test_validation_names_the_argument(name, value, match):
    scene = make_scene(5, 16, 16, 3, 2)
    scene[name] = value
    with pytest.raises((ValueError, TypeError), match=match):
        _cpu.composite(**scene)


def test_loader_reports_why_when_disabled(monkeypatch):
    """MOEGS_DISABLE_CPU_KERNEL forces the fallback and load_error() says so."""
    assert _cpu.library_path() is not None and _cpu.load_error() is None
    monkeypatch.setenv("MOEGS_DISABLE_CPU_KERNEL", "1")
    kernels.reset()
    try:
        assert not _cpu.is_available()
        assert "MOEGS_DISABLE_CPU_KERNEL" in _cpu.load_error()
        with pytest.raises(RuntimeError, match="unavailable"):
            _cpu.composite(**make_scene(3, 8, 8))
    finally:
        monkeypatch.delenv("MOEGS_DISABLE_CPU_KERNEL")
        kernels.reset()
    assert _cpu.is_available()
