"""Initial point clouds: pycolmap triangulation with known poses, random samplers, kNN scales."""

from __future__ import annotations

import math

import numpy as np
import pycolmap
import pytest
import torch

from moegs.camera import Camera, intrinsics, look_at
from moegs.data.points import (
    TriangulationError,
    initial_scales,
    knn_mean_distance,
    point_colors,
    random_colors,
    random_in_box,
    random_in_frusta,
    triangulate,
)
from moegs.data.scene import View


@pytest.fixture(scope="module")
def static_frame():
    """Frame 0 of the n3v_like scene's geometry from the 7 training cameras of the quick rig (128x96), every
    surface with a feature-rich noise texture (the stand-in's own backdrop is deliberately smooth, and
    SIFT needs texture to match)."""
    from dataclasses import replace

    from moegs.data.synthetic.generate import torch_threads
    from moegs.data.synthetic.raycast import render
    from moegs.data.synthetic.rigs import forward_facing_rig
    from moegs.data.synthetic.scenes import build_scene
    from moegs.data.synthetic.textures import Texture

    desc = build_scene("n3v_like", 0)
    cams = forward_facing_rig(8, desc.target, 128, 96, 65.0, seed=0)[1:]
    rich = Texture("noise", ((0.8, 0.7, 0.5), (0.3, 0.5, 0.6), (0.2, 0.2, 0.3)), 0.3, 0.12, 0.35, seed=1)
    prims = [replace(p, texture=rich) for p in desc.primitives(0.0)]
    with torch_threads(1):
        images = [render(prims, c, 0.0, supersample=2).rgb for c in cams]
    return desc, prims, cams, images


def _project(cam: Camera, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    pc = X @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    uv = pc @ cam.K.T
    return uv[:, :2] / pc[:, 2:3], pc[:, 2]


def test_triangulation_recovers_surface_points(static_frame, tmp_path):
    from moegs.data.synthetic.raycast import cast

    desc, prims, cams, images = static_frame
    cloud = triangulate(images, cams, workdir=tmp_path)
    assert len(cloud) >= 50 and cloud.times is None
    assert cloud.rgb.shape == cloud.xyz.shape and (cloud.rgb >= 0).all() and (cloud.rgb <= 1).all()
    # reprojection with OUR cameras against the SIFT keypoints of every observation (pose conventions)
    rec = pycolmap.Reconstruction(str(tmp_path / "group_0000" / "sparse"))
    errors, rel = [], []
    for p in rec.points3D.values():
        if p.error > 2.0:
            continue
        X = torch.tensor(p.xyz, dtype=torch.float32)[None]
        for el in p.track.elements:
            image = rec.image(el.image_id)
            cam = cams[int(image.name[:5])]
            uv, _ = _project(cam, X)
            errors.append(
                float(np.linalg.norm(uv[0].numpy() - np.asarray(image.points2D[el.point2D_idx].xy)))
            )
        # the ray from an observing camera towards the point first hits a surface at the point's depth
        cam = cams[int(rec.image(p.track.elements[0].image_id).name[:5])]
        _, z = _project(cam, X)
        hit = cast(prims, cam.center[None], (X - cam.center) / z[:, None])
        rel.append(abs(float(hit.t[0] - z[0])) / float(z[0]))
    errors, rel = np.asarray(errors), np.asarray(rel)
    assert len(rel) == len(cloud)
    assert np.mean(errors) < 1.0 and np.percentile(errors, 95) < 2.0
    # points on the analytic surfaces: median depth error < 1% (scene depth 2-8 m), 80% within 3%
    assert np.median(rel) < 0.01 and (rel < 0.03).mean() > 0.8


def test_triangulation_per_frame_merged_and_views(static_frame):
    desc, prims, cams, images = static_frame
    from dataclasses import replace

    from moegs.data.synthetic.generate import torch_threads
    from moegs.data.synthetic.raycast import render

    sub = cams[:4]
    t1 = 0.5
    with torch_threads(1):
        imgs1 = [render(desc.primitives(t1), c, t1, supersample=2).rgb for c in sub]
    views = [
        View(camera=replace(c, time=0.0), load_image=lambda im=im: im, key=f"a{i}")
        for i, (c, im) in enumerate(zip(sub, images[:4], strict=True))
    ]
    views += [
        View(camera=replace(c, time=t1), load_image=lambda im=im: im, key=f"b{i}")
        for i, (c, im) in enumerate(zip(sub, imgs1, strict=True))
    ]
    cloud = triangulate(views, frames="all")
    assert cloud.times is not None and set(cloud.times.unique().tolist()) == {0.0, t1}
    assert cloud.times.shape == (len(cloud),)
    with pytest.raises(ValueError, match="different times"):
        triangulate(views)
    views = [
        View(camera=replace(v.camera, frame=int(v.key[0] == "b")), load_image=v.load_image, key=v.key)
        for v in views
    ]
    one = triangulate(views, frames=1)  # only frame 1 (t = 0.5) is read
    assert one.times is None and len(one) >= 10
    with pytest.raises(ValueError, match="frames present: \\[0, 1\\]"):
        triangulate(views, frames=7)


def test_triangulation_errors(static_frame):
    _, _, cams, images = static_frame
    with pytest.raises(ValueError, match="at least 2 views"):
        triangulate(images[:1], cams[:1])
    with pytest.raises(ValueError, match="cameras"):
        triangulate(images[:2])
    flat = [torch.full_like(images[0], 0.5) for _ in range(3)]
    with pytest.raises(TriangulationError, match="random_in_frusta"):
        triangulate(flat, cams[:3])
    mono = [
        View(camera=c, load_image=lambda im=im: im, key=str(i))
        for i, (c, im) in enumerate(zip([cams[0]], images[:1], strict=True))
    ]
    with pytest.raises(ValueError, match="monocular"):
        triangulate(mono, frames="all")


# -- kNN ------------------------------------------------------------------------------------------------
def _brute(points: torch.Tensor, k: int) -> torch.Tensor:
    d = ((points[:, None, :].double() - points[None, :, :].double()) ** 2).sum(-1)
    d.fill_diagonal_(float("inf"))
    return d.sort(dim=1).values[:, : min(k, points.shape[0] - 1)]


@pytest.mark.parametrize("method", ["torch", "kdtree"])
def test_knn_matches_brute_force(method):
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(600, 3, generator=g)
    pts = torch.cat([pts, pts[:20]])  # exact duplicates: distance 0 to the twin
    d2 = _brute(pts, 3)
    got_sq = knn_mean_distance(pts, 3, squared=True, method=method, max_elements=5000)  # many small chunks
    got = knn_mean_distance(pts, 3, method=method, max_elements=5000)
    assert torch.allclose(got_sq.double(), d2.mean(1), rtol=1e-5, atol=1e-7)
    assert torch.allclose(got.double(), d2.sqrt().mean(1), rtol=1e-5, atol=1e-7)
    assert torch.allclose(
        knn_mean_distance(pts, 5, method=method).double(), _brute(pts, 5).sqrt().mean(1), rtol=1e-5
    )


def test_knn_edge_cases_and_initial_scales():
    assert knn_mean_distance(torch.zeros(1, 3)).shape == (1,)
    two = torch.tensor([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]])
    assert torch.allclose(knn_mean_distance(two, 3), torch.tensor([5.0, 5.0]))  # k clipped to P - 1
    assert torch.allclose(knn_mean_distance(two, 3, squared=True), torch.tensor([25.0, 25.0]))
    pts = torch.rand(300, 3, generator=torch.Generator().manual_seed(1))
    pts[5] = pts[6]
    pts[7] = pts[6]
    pts[8] = pts[6]  # four coincident points: mean sq distance 0 -> clamped to 1e-7
    ls = initial_scales(pts)
    assert ls.shape == (300, 3) and torch.equal(ls[:, 0], ls[:, 1]) and torch.equal(ls[:, 0], ls[:, 2])
    want = torch.log(torch.sqrt(_brute(pts, 3).mean(1).clamp_min(1e-7))).float()
    assert torch.allclose(ls[:, 0], want, atol=1e-5)
    assert math.isclose(float(ls[6, 0]), math.log(math.sqrt(1e-7)), rel_tol=1e-5)
    with pytest.raises(ValueError, match="\\[P, D\\]"):
        knn_mean_distance(torch.zeros(3))
    big = torch.rand(5000, 3, generator=torch.Generator().manual_seed(2))  # auto -> kdtree, same numbers
    idx = torch.arange(0, 5000, 97)
    a = knn_mean_distance(big, method="auto")[idx]
    b = knn_mean_distance(big, method="torch")[idx]
    assert torch.allclose(a, b, rtol=1e-5)


def test_initial_scales_are_the_float64_values_rounded_once():
    """Every process must start from the same scales: they are computed in float64 (numpy's log, no torch
    sqrt or log, see moegs.threads) and rounded to float32 once, on both kNN paths."""
    pts = torch.rand(300, 3, generator=torch.Generator().manual_seed(3))
    want = (0.5 * torch.log(_brute(pts, 3).mean(1).clamp_min(1e-7))).float()
    assert torch.equal(initial_scales(pts)[:, 0], want)
    big = torch.rand(5000, 3, generator=torch.Generator().manual_seed(2))  # auto -> kdtree
    idx = torch.arange(0, 5000, 97)
    got = initial_scales(big)[idx, 0]
    assert got.dtype == torch.float32
    ref = (0.5 * torch.log(knn_mean_distance(big.double(), 3, squared=True, method="torch")[idx])).float()
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-7)


# -- random samplers ------------------------------------------------------------------------------------
def test_random_in_box():
    bbox = torch.tensor([[-1.0, 0.0, 2.0], [1.0, 0.5, 3.0]])
    p = random_in_box(bbox, 2000, seed=3)
    assert p.shape == (2000, 3) and p.dtype == torch.float32
    assert (p >= bbox[0]).all() and (p <= bbox[1]).all()
    assert torch.equal(p, random_in_box(bbox, 2000, seed=3)) and not torch.equal(
        p, random_in_box(bbox, 2000, 4)
    )
    assert (p.mean(0) - bbox.mean(0)).abs().max() < 0.05
    with pytest.raises(ValueError, match="\\[2, 3\\]"):
        random_in_box(torch.zeros(3), 5)


def _cams() -> list[Camera]:
    K = intrinsics(40.0, 40.0, 32.0, 24.0)
    eyes = [torch.tensor([-1.0, -4.0, 0.5]), torch.tensor([1.0, -4.0, 0.5]), torch.tensor([0.0, -4.0, 1.5])]
    return [
        Camera(K=K, world_to_camera=look_at(e, torch.zeros(3)), width=64, height=48, name=f"c{i}")
        for i, e in enumerate(eyes)
    ]


def _inside(cam: Camera, p: torch.Tensor, near: float, far: float) -> torch.Tensor:
    pc = p @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    uv = pc @ cam.K.T
    u, v = uv[:, 0] / pc[:, 2], uv[:, 1] / pc[:, 2]
    eps = 1e-3
    return (
        (pc[:, 2] >= near - eps)
        & (pc[:, 2] <= far + eps)
        & (u >= -eps)
        & (u <= cam.width + eps)
        & (v >= -eps)
        & (v <= cam.height + eps)
    )


def test_random_in_frusta_union_and_intersection():
    cams = _cams()
    p = random_in_frusta(cams, 3000, near=1.0, far=6.0, seed=0)
    assert p.shape == (3000, 3)
    seen = torch.stack([_inside(c, p, 1.0, 6.0) for c in cams])
    assert seen.any(0).all()  # union: every point in at least one frustum
    assert (~seen.all(0)).any()  # ... not all of them in every frustum
    assert torch.equal(p, random_in_frusta(cams, 3000, 1.0, 6.0, seed=0))
    assert (seen[0] & ~seen[1] & ~seen[2]).sum() > 50  # every camera contributes its own region
    q = random_in_frusta(cams, 500, near=2.0, far=5.0, seed=1, mode="all")
    assert all(_inside(c, q, 2.0, 5.0).all() for c in cams)
    # uniform in volume: depth density grows like z^2 -> median depth = cbrt((1 + 6^3) / 2) ~ 4.77
    z_single = random_in_frusta(cams[:1], 4000, 1.0, 6.0, seed=2)
    zz = (z_single @ cams[0].world_to_camera[:3, :3].T + cams[0].world_to_camera[:3, 3])[:, 2]
    assert abs(float(zz.median()) - ((1 + 6**3) / 2) ** (1 / 3)) < 0.1
    with pytest.raises(ValueError, match="near < far"):
        random_in_frusta(cams, 10, 2.0, 1.0)
    far_apart = [
        cams[0],
        Camera(
            K=cams[0].K,
            world_to_camera=look_at(torch.tensor([0.0, 4.0, 0.5]), torch.tensor([0.0, 9.0, 0.5])),
            width=64,
            height=48,
        ),
    ]
    with pytest.raises(ValueError, match="barely"):
        random_in_frusta(far_apart, 100, 1.0, 3.0, mode="all", max_rounds=3)


def test_point_colors():
    cams = _cams()
    red = torch.zeros(48, 64, 3)
    red[..., 0] = 1.0
    views = [View(camera=c, load_image=lambda: red, key=c.name) for c in cams]
    pts = torch.cat([random_in_frusta(cams, 50, 1.0, 6.0, seed=0), torch.tensor([[0.0, 50.0, 50.0]])])
    col = point_colors(pts, views, default=torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(col[:50], torch.tensor([1.0, 0.0, 0.0]))
    assert torch.allclose(col[50], torch.tensor([0.0, 0.0, 1.0]))  # seen by nobody -> default
    rnd = point_colors(pts, seed=5)
    assert torch.equal(rnd, random_colors(51, 5)) and (rnd >= 0).all() and (rnd <= 1).all()
