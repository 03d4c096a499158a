"""Small seeded scenes for the rendering tests: a camera at the origin looking down +z and Gaussians in
its frustum."""

from __future__ import annotations

import pytest
import torch

from moegs import Camera, GaussianFrame
from moegs.camera import intrinsics
from moegs.render.pipeline import _cpu_kernel


def _make_camera(width: int = 24, height: int = 18, *, focal: float | None = None) -> Camera:
    """Pinhole camera at the origin looking down +z, principal point slightly off-centre."""
    f = float(width) if focal is None else focal
    K = intrinsics(f, f, 0.47 * width, 0.53 * height)
    return Camera(K=K, world_to_camera=torch.eye(4), width=width, height=height)


def _make_frame(
    n: int,
    camera: Camera,
    *,
    channels: int = 3,
    sh_degree: int | None = None,
    scale: float = 0.08,
    depth: tuple[float, float] = (2.0, 5.0),
    opacity: tuple[float, float] = (0.2, 0.8),
    seed: int = 0,
    dtype=torch.float32,
) -> GaussianFrame:
    """``n`` random Gaussians inside ``camera``'s frustum (colours or SH of ``sh_degree``)."""
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    z = depth[0] + (depth[1] - depth[0]) * rand(n)
    px = camera.width * (0.05 + 0.9 * rand(n))
    py = camera.height * (0.05 + 0.9 * rand(n))
    means = torch.stack([(px - camera.cx) / camera.fx * z, (py - camera.cy) / camera.fy * z, z], dim=-1)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen, dtype=torch.float64), dim=-1)
    scales = scale * (0.5 + rand(n, 3))
    opacities = opacity[0] + (opacity[1] - opacity[0]) * rand(n)
    if sh_degree is None:
        appearance = {"colors": 0.1 + 0.8 * rand(n, channels)}
    else:
        appearance = {
            "sh": 0.3 * torch.randn(n, (sh_degree + 1) ** 2, channels, generator=gen, dtype=torch.float64)
        }
    fields = {"means": means, "quats": quats, "scales": scales, "opacities": opacities, **appearance}
    return GaussianFrame(**{k: v.to(dtype) for k, v in fields.items()})


@pytest.fixture
def make_camera():
    """``make_camera(width, height, *, focal=None) -> Camera``."""
    return _make_camera


@pytest.fixture
def make_frame():
    """``make_frame(n, camera, *, channels, sh_degree, scale, depth, opacity, seed, dtype)``."""
    return _make_frame


@pytest.fixture
def require_cpu_kernel():
    """Skip the test, with the reason, unless the compiled CPU kernel can run."""
    kernel, reason = _cpu_kernel()
    if kernel is None:
        pytest.skip(f"{reason}; build it with `python -m moegs.kernels build`")


@pytest.fixture(params=["torch", "cpu"])
def backend(request):
    """Each CPU-side backend; ``cpu`` is skipped, with the reason, while the kernel is unavailable."""
    if request.param == "cpu":
        request.getfixturevalue("require_cpu_kernel")
    return request.param
