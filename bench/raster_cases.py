"""The rasterizer benchmark's scenes and render calls, shared by ``tests/benchmarks`` (pytest-benchmark)
and ``bench.single_pass`` (paired timing).

Scenes follow ``specs/cpu_feasibility.md``: N Gaussians in the frustum at depth 2-5, log-normal scales
proportional to N^-1/2 (about the same per-pixel depth complexity for every N), opacity
sigmoid(randn), fx = width, RGB.
"""

from __future__ import annotations

import torch

from moegs import Camera, GaussianFrame
from moegs.camera import intrinsics
from moegs.render import rasterize, rasterize_multi


def make_scene(n: int, res: int, *, seed: int = 0, device: str = "cpu") -> tuple[GaussianFrame, Camera]:
    """The feasibility-study scene: ``n`` Gaussians seen by a ``res x res`` camera."""
    gen = torch.Generator().manual_seed(seed)
    camera = Camera(
        K=intrinsics(res, res, res / 2, res / 2), world_to_camera=torch.eye(4), width=res, height=res
    )
    z = 2 + 3 * torch.rand(n, generator=gen)
    xy = (torch.rand(n, 2, generator=gen) - 0.5) * z[:, None]  # inside the 2 x atan(0.5) FoV
    frame = GaussianFrame(
        means=torch.cat([xy, z[:, None]], dim=1),
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1),
        scales=torch.exp(torch.randn(n, 3, generator=gen) * 0.3) * 3.0 / n**0.5,
        opacities=torch.sigmoid(torch.randn(n, generator=gen)),
        colors=torch.rand(n, 3, generator=gen),
    )
    return frame.to(device), camera.to(device)


def leaves(frame: GaussianFrame) -> GaussianFrame:
    """The same frame with fresh leaf tensors that require grad."""
    names = ("means", "quats", "scales", "opacities", "colors")
    return GaussianFrame(**{k: getattr(frame, k).detach().clone().requires_grad_(True) for k in names})


def run_once(render, frame: GaussianFrame, backward: bool) -> None:
    """One render (and backward), synchronised on CUDA."""
    if backward:
        render(frame).sum().backward()
    else:
        with torch.no_grad():
            render(frame)
    if frame.device.type == "cuda":
        torch.cuda.synchronize()


def case_renderer(
    *,
    n: int,
    res: int,
    backend: str,
    backward: bool,
    experts: int = 1,
    single_pass: bool = True,
    device="cpu",
):
    """``(render, frame)``: ``render(frame)`` returns a tensor to sum for the backward.

    With ``experts = K > 1`` the frame holds K experts of ``n`` Gaussians each, rendered either by one
    ``rasterize_multi`` (``single_pass``) or by K ``rasterize`` calls.
    """
    frame, camera = make_scene(n * experts, res, device=device)
    if backward:
        frame = leaves(frame)
    bounds = [(k * n, (k + 1) * n) for k in range(experts)]

    def render(f: GaussianFrame) -> torch.Tensor:
        if experts == 1:
            return rasterize(f, camera, backend=backend).image
        parts = [f.select(slice(a, b)) for a, b in bounds]
        if single_pass:
            return rasterize_multi(parts, camera, backend=backend).images
        return torch.stack([rasterize(p, camera, backend=backend).image for p in parts])

    return render, frame
