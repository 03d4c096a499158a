"""Panoptic (Dynamic3DGaussians layout) loader: fixture and the real ``basketball`` sequence."""

from __future__ import annotations

import json

import helpers.data_layouts as fx
import numpy as np
import pytest
import torch

from moegs.data.panoptic import load_panoptic


def test_fixture_splits_times_poses_masks(tmp_path):
    truth = fx.write_panoptic(tmp_path)
    scene = load_panoptic(tmp_path, num_points=200)
    assert (len(scene.train), len(scene.test)) == (4 * 3, 2 * 3)
    assert scene.multiview and scene.num_frames == 3
    assert sorted({v.camera.camera_id for v in scene.test}) == [0, 5]
    assert [v.camera.time for v in scene.train[::4]] == pytest.approx([0.0, 1 / 3, 2 / 3])
    for v in scene.train + scene.test:
        torch.testing.assert_close(
            v.camera.world_to_camera, truth["w2c"][v.camera.camera_id], atol=1e-6, rtol=0
        )
        torch.testing.assert_close(v.camera.K, truth["K"])
        assert (v.camera.width, v.camera.height) == (32, 18)
    img = scene.test[1].image()
    expected = torch.tensor(fx.colour(5, 0), dtype=torch.float32) / 255
    assert (img - expected).abs().max() < 6 / 255  # JPEG
    mask = scene.train[0].mask()
    assert mask.shape == (18, 32) and mask[:, :16].sum() == 0 and mask[:, 16:].min() == 1
    assert scene.test[0].load_mask is None  # no seg/ for test cameras
    torch.testing.assert_close(scene.background, torch.zeros(3))
    # one colour per camera image: nothing to triangulate, so the random shared-volume points, and why
    assert "fallback" in scene.points.source and "init_pt_cld.npz missing" in scene.points.source
    assert "no match between 4 cameras triangulated" in scene.points.source
    assert len(scene.points) == 200
    random = load_panoptic(tmp_path, num_points=200, init="random")
    torch.testing.assert_close(random.points.xyz, scene.points.xyz)


def test_npz_points_window_local_time_and_scale(tmp_path):
    fx.write_panoptic(tmp_path, frames=4, with_npz=True)
    scene = load_panoptic(tmp_path, frames=(1, 3), time_mode="local", resolution_scale=0.5)
    assert scene.num_frames == 2 and len(scene.train) == 8
    assert sorted({v.camera.time for v in scene.train}) == pytest.approx([0.0, 0.5])
    assert sorted({v.camera.frame for v in scene.train}) == [1, 2]
    assert scene.points.source.startswith("init_pt_cld.npz") and len(scene.points) == 50
    torch.testing.assert_close(scene.points.rgb, torch.full((50, 3), 0.25))
    assert scene.train[0].image().shape == (9, 16, 3)
    assert scene.train[0].mask().shape == (9, 16)
    # the default global time keeps each frame's time in the whole sequence (t / T), window or not
    windowed = load_panoptic(tmp_path, frames=(1, 3), num_points=0)
    assert sorted({v.camera.time for v in windowed.train}) == pytest.approx([1 / 4, 2 / 4])


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="train_meta.json"):
        load_panoptic(tmp_path)
    with pytest.raises(ValueError, match=r"init must be one of \('triangulate', 'random'\), got 'sfm'"):
        load_panoptic(tmp_path, init="sfm")
    fx.write_panoptic(tmp_path)
    meta = json.loads((tmp_path / "test_meta.json").read_text())
    del meta["w2c"]
    (tmp_path / "test_meta.json").write_text(json.dumps(meta))
    with pytest.raises(KeyError, match=r"test_meta\.json: missing key 'w2c'"):
        load_panoptic(tmp_path)
    fx.write_panoptic(tmp_path)
    (tmp_path / "ims" / "5" / "000001.jpg").unlink()
    scene = load_panoptic(tmp_path, num_points=0)
    with pytest.raises(FileNotFoundError, match=r"ims/5/000001\.jpg"):
        next(v for v in scene.test if v.camera.name == "cam05/000001").image()
    fx._save(np.zeros((5, 7, 3), np.uint8), tmp_path / "ims" / "5" / "000001.jpg")
    with pytest.raises(ValueError, match=r"000001\.jpg: image is 7x5 but 32x18"):
        next(v for v in scene.test if v.camera.name == "cam05/000001").image()


# -- real data --------------------------------------------------------------------------------------
def _ray_intersection(origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Least-squares point closest to rays ``[N, 3]`` (unit ``dirs``)."""
    eye = torch.eye(3, dtype=torch.float64)
    P = eye - dirs[:, :, None] * dirs[:, None, :]
    return torch.linalg.solve(P.sum(0), (P @ origins[:, :, None]).sum(0))[:, 0]


def _project(cam, x: torch.Tensor) -> tuple[torch.Tensor, float]:
    p = cam.world_to_camera.double() @ torch.cat([x, torch.ones(1, dtype=x.dtype)])
    return (cam.K.double() @ (p[:3] / p[2]))[:2], float(p[2])


@pytest.mark.realdata
def test_basketball(basketball_root):
    train_meta = json.loads((basketball_root / "train_meta.json").read_text())
    test_meta = json.loads((basketball_root / "test_meta.json").read_text())
    scene = load_panoptic(basketball_root, num_points=2000, init="random")
    T = len(train_meta["fn"])
    assert scene.num_frames == T == 150
    assert len(scene.train) == T * len(train_meta["cam_id"][0]) == 150 * 27
    assert len(scene.test) == T * len(test_meta["cam_id"][0]) == 150 * 4
    assert scene.meta["test_cameras"] == sorted(test_meta["cam_id"][0])
    assert {(v.camera.width, v.camera.height) for v in scene.train + scene.test} == {(640, 360)}
    assert max(v.camera.time for v in scene.train) == pytest.approx(149 / 150)
    img = scene.test[0].image()
    assert img.shape == (360, 640, 3) and 0.05 < img.mean() < 0.95

    # geometry: triangulate the foreground (seg mask) centroid at frame 0 from the training cameras,
    # then it must project inside the foreground's bounding box in most training cameras and inside
    # every test image (the test cameras have no masks). A wrong w2c/K convention fails this.
    first = [v for v in scene.train if v.camera.frame == 0]
    origins, dirs, boxes = [], [], []
    for v in first:
        m = v.mask()
        ys, xs = torch.nonzero(m, as_tuple=True)
        assert len(xs) > 50, v.camera.name
        c = v.camera
        pix = torch.tensor([xs.double().mean() + 0.5, ys.double().mean() + 0.5, 1.0], dtype=torch.float64)
        d_cam = torch.linalg.solve(c.K.double(), pix)
        R = c.world_to_camera[:3, :3].double()
        origins.append(c.center.double())
        dirs.append(torch.nn.functional.normalize(R.T @ d_cam, dim=0))
        boxes.append((xs.min().item(), xs.max().item() + 1, ys.min().item(), ys.max().item() + 1))
    x = _ray_intersection(torch.stack(origins), torch.stack(dirs))
    inside = 0
    for v, (x0, x1, y0, y1) in zip(first, boxes, strict=True):
        uv, depth = _project(v.camera, x)
        assert depth > 0
        inside += bool(x0 <= uv[0] <= x1 and y0 <= uv[1] <= y1)
    assert inside >= 0.9 * len(first), f"{inside}/{len(first)}"
    for v in scene.test[:4]:
        uv, depth = _project(v.camera, x)
        assert depth > 0 and 0 <= uv[0] < 640 and 0 <= uv[1] < 360, (v.camera.name, uv)
    # the random fallback points lie in the shared volume: most project inside most training images
    pts = scene.points.xyz[:500].double()
    seen = torch.zeros(len(pts))
    for v in first:
        c = v.camera
        p = pts @ c.world_to_camera[:3, :3].double().T + c.world_to_camera[:3, 3].double()
        uv = p @ c.K.double().T
        u, w = uv[:, 0] / p[:, 2], uv[:, 1] / p[:, 2]
        seen += ((p[:, 2] > 0) & (u >= 0) & (u < 640) & (w >= 0) & (w < 360)).double()
    assert (seen >= len(first) / 2).all()
