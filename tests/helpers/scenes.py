"""A tiny in-memory dynamic scene for training tests: cameras on a ring around a few coloured
Gaussians that drift along +x with time. Ground truth comes from ``rasterize``; it takes ~0.1 s."""

from __future__ import annotations

import math

import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.data.scene import PointCloud, Scene, View
from moegs.gaussians import GaussianFrame
from moegs.render import rasterize


def _truth(t: float) -> GaussianFrame:
    g = torch.Generator().manual_seed(11)
    n = 40
    means = torch.randn(n, 3, generator=g) * 0.3
    means[:, 0] += 0.4 * t - 0.2
    return GaussianFrame(
        means=means,
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        scales=torch.full((n, 3), 0.15),
        opacities=torch.full((n,), 0.8),
        colors=torch.rand(n, 3, generator=g),
    )


def _camera(index: int, count: int, size: int, t: float, frame: int) -> Camera:
    a = 2 * math.pi * index / count
    eye = torch.tensor([3.0 * math.cos(a), 3.0 * math.sin(a), 1.0])
    return Camera(
        K=intrinsics(size, size, size / 2, size / 2),
        world_to_camera=look_at(eye, torch.zeros(3)),
        width=size,
        height=size,
        time=t,
        camera_id=index,
        frame=frame,
        name=f"cam{index}/{frame}",
    )


def tiny_scene(
    num_frames: int = 3, cameras: int = 4, size: int = 32, num_points: int = 200, background: float = 1.0
) -> Scene:
    """``cameras`` training views per frame plus one test view per frame (between two training cameras)."""
    bg = torch.full((3,), background)
    train, test = [], []
    for f in range(num_frames):
        t = f / max(num_frames - 1, 1)
        for c in range(cameras + 1):
            # the last one is the test camera, halfway between training cameras 0 and 1
            cam = _camera(c, cameras, size, t, f) if c < cameras else _camera(1, 2 * cameras, size, t, f)
            image = rasterize(_truth(t), cam, background=bg).image.clamp(0, 1)
            view = View(camera=cam, load_image=lambda im=image: im, key=f"tiny/{c}/{f}")
            (test if c == cameras else train).append(view)
    g = torch.Generator().manual_seed(5)
    points = PointCloud(
        xyz=(torch.rand(num_points, 3, generator=g) - 0.5) * 1.6,
        rgb=torch.rand(num_points, 3, generator=g),
        source="tiny random",
    )
    return Scene(
        name="tiny",
        dataset="synthetic",
        train=train,
        test=test,
        num_frames=num_frames,
        background=bg,
        bbox=torch.tensor([[-0.8] * 3, [0.8] * 3]),
        extent=3.3,
        points=points,
        multiview=True,
        stand_in="unit-test scene",
    )


def projection_scene(n: int = 300, seed: int = 1):
    """Gaussians around a rotated camera: behind it, far off-axis, off-screen, anisotropic."""
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen, dtype=torch.float64) * torch.tensor([3.0, 3.0, 3.0])
    quats = torch.randn(n, 4, generator=gen, dtype=torch.float64)  # not normalised on purpose
    scales = torch.exp(torch.randn(n, 3, generator=gen, dtype=torch.float64) * 1.2 - 2.5)
    opacities = torch.rand(n, generator=gen, dtype=torch.float64)
    w2c = look_at(torch.tensor([0.3, -6.0, 0.5]), torch.tensor([0.0, 0.0, 0.2]))
    cam = Camera(
        K=intrinsics(50.0, 46.0, 27.0, 19.0), world_to_camera=w2c, width=60, height=40, near=0.5, far=8.0
    )
    return means, quats, scales, opacities, cam


def untrained_experts(scene, names: tuple[str, ...] = ("static", "mcmc")) -> list:
    """Each named expert built on ``scene`` from its quick preset, in eval mode, the ``i``-th with training
    seed ``i`` (two different experts: copies of one would route by symmetry)."""
    from dataclasses import replace

    from moegs.experts import get_expert_class

    out = []
    for seed, name in enumerate(names):
        cls = get_expert_class(name)
        config = cls.config_class.from_preset("quick")
        out.append(cls.from_scene(scene, replace(config, train=replace(config.train, seed=seed))).eval())
    return out
