"""Technicolor loader: STG (local) and Ex4DGS (absolute) per-frame COLMAP layouts, and the raw layout."""

from __future__ import annotations

import shutil

import helpers.data_layouts as fx
import numpy as np
import pytest
import torch

from moegs.data.technicolor import WINDOWS, camera_number, load_technicolor, quat_to_rotmat


def _check(scene, truth, frames):
    n = frames[1] - frames[0]
    assert (len(scene.train), len(scene.test)) == (11 * n, n)
    assert {v.camera.camera_id for v in scene.test} == {10}
    assert scene.num_frames == n and scene.multiview
    assert sorted({v.camera.time for v in scene.train}) == pytest.approx([k / n for k in range(n)])
    for v in scene.train + scene.test:
        c = v.camera.camera_id
        torch.testing.assert_close(v.camera.world_to_camera, truth["w2c"][c], atol=1e-5, rtol=0)
        f, cx, cy = truth["intr"][c]
        assert (v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy) == pytest.approx((f, f, cx, cy))
        assert (v.camera.width, v.camera.height) == (40, 24)
    v = next(v for v in scene.train if v.camera.camera_id == 3 and v.camera.frame == frames[0] + 1)
    expected = torch.tensor(fx.colour(3, frames[0] + 1), dtype=torch.float32) / 255
    torch.testing.assert_close(v.image(), expected.expand(24, 40, 3))


def test_quaternion_round_trip():
    for w2c in fx.ring_w2c(5):
        R = w2c[:3, :3].double().numpy()
        torch.testing.assert_close(
            quat_to_rotmat(torch.tensor(fx._rotmat_to_quat(R))), torch.from_numpy(R), atol=1e-5, rtol=0
        )
    assert camera_number("cam10.png") == 10 and camera_number("Birthday_undist_00151_10.png") == 10


@pytest.mark.parametrize("naming, names, binary", [("local", "stg", False), ("absolute", "ex4dgs", True)])
def test_colmap_layout(tmp_path, naming, names, binary):
    truth = fx.write_technicolor_colmap(tmp_path, frames=(5, 8), naming=naming, names=names, binary=binary)
    scene = load_technicolor(tmp_path, frames=(5, 8))
    assert scene.meta["layout"] == "colmap" and scene.meta["folder_naming"] == naming
    _check(scene, truth, (5, 8))
    assert len(scene.points) == 2 and scene.points.source.startswith("COLMAP")
    allp = load_technicolor(tmp_path, frames=(5, 8), points_frames="all")
    assert len(allp.points) == 6
    torch.testing.assert_close(allp.points.times, torch.tensor([0.0, 0, 1 / 3, 1 / 3, 2 / 3, 2 / 3]))


def test_raw_layout_and_default_window(tmp_path):
    root = tmp_path / "Birthday"
    truth = fx.write_technicolor_raw(root, frames=(151, 153))
    assert WINDOWS["birthday"] == (151, 201)
    scene = load_technicolor(root, frames=(151, 153), num_points=100)
    assert scene.meta["layout"] == "raw"
    _check(scene, truth, (151, 153))
    assert "fallback" in scene.points.source
    half = load_technicolor(root, frames=(151, 152), resolution_scale=0.5, num_points=0)
    assert half.train[0].image().shape == (12, 20, 3)
    # the protocol window of Birthday (151, 201) is the default; frames missing there are reported
    with pytest.raises(FileNotFoundError, match="camera 0 for frame 153"):
        load_technicolor(root, num_points=0)


def test_raw_calibration_is_read_as_stg_reads_the_undistorted_set(tmp_path):
    """``f cu cv ar sk qw qx qy qz tx ty tz`` (STG ``script/pre_technicolor.py:79-87``: q = row[5:9],
    t = row[9:12]); the distorted set's 14 columns (d1 d2 after sk) are refused by name."""
    root = tmp_path / "Birthday"
    fx.write_technicolor_raw(root, frames=(151, 152), cams=2)
    rows = [
        "f cu cv ar sk qw qx qy qz tx ty tz",
        "30 21 11 1 0 1 0 0 0 0.1 0.2 0.3",
        "30 19 13 1 0 0 0 0 1 1 2 3",
    ]
    (root / "cameras_parameters.txt").write_text("\n".join(rows) + "\n")
    cams = [
        v.camera for v in load_technicolor(root, frames=(151, 152), num_points=0, test_cameras=(1,)).train
    ]
    assert torch.equal(cams[0].K, torch.tensor([[30.0, 0, 21], [0, 30, 11], [0, 0, 1]]))
    torch.testing.assert_close(
        cams[0].world_to_camera[:3], torch.tensor([[1.0, 0, 0, 0.1], [0, 1, 0, 0.2], [0, 0, 1, 0.3]])
    )
    rows[1] = "30 21 11 1 0 0.01 -0.02 1 0 0 0 0.1 0.2 0.3"
    (root / "cameras_parameters.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(
        ValueError, match=r"cameras_parameters.txt: row 2 has 14 columns, expected 12 .*distorted"
    ):
        load_technicolor(root, frames=(151, 152), num_points=0)


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="colmap_<frame>"):
        load_technicolor(tmp_path)
    fx.write_technicolor_colmap(tmp_path, frames=(0, 2))
    with pytest.raises(FileNotFoundError, match="colmap_0..colmap_4"):
        load_technicolor(tmp_path, frames=(10, 15))
    (tmp_path / "colmap_1" / "images" / "cam04.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"camera 4 for frame 1 in .*colmap_1"):
        load_technicolor(tmp_path, frames=(0, 2))
    fx.write_technicolor_colmap(tmp_path, frames=(0, 2))
    fx._save(np.zeros((3, 3, 3), np.uint8), tmp_path / "colmap_1" / "images" / "cam04.png")
    scene = load_technicolor(tmp_path, frames=(0, 2))
    with pytest.raises(ValueError, match=r"cam04\.png: image is 3x3 but 40x24"):
        next(v for v in scene.train if v.camera.name == "cam04/00001").image()
    shutil.rmtree(tmp_path / "colmap_0" / "sparse")
    with pytest.raises(FileNotFoundError, match=r"colmap_0/sparse/0/images\.bin or images\.txt"):
        load_technicolor(tmp_path, frames=(0, 2))


def test_each_experts_initial_cloud_by_name(tmp_path):
    """``points=`` as in load_n3v: ``mvs100k`` E-D3DGS's ``<root>/points3D_downsample.ply``
    (``scene/dataset_readers.py:352``), ``sparse`` the window's first frame's COLMAP points (Ex4DGS
    ``scene/dataset_readers.py:492-501``), ``frames`` every frame's, each at its frame's time (STG
    ``dataset_readers.py:913-932``); ``auto`` the COLMAP points first, then the PLY. A named cloud that is
    missing or empty is an error naming where it was expected."""
    from moegs.data.synthetic.writers import write_ply

    fx.write_technicolor_colmap(tmp_path, frames=(5, 8))  # colmap_0..2, two points at z = 3 + k, 4 + k
    with pytest.raises(FileNotFoundError, match=r"points='mvs100k'.*points3D_downsample\.ply"):
        load_technicolor(tmp_path, frames=(5, 8), points="mvs100k")
    dense = torch.tensor([[0.0, 0.0, 5.0 + i] for i in range(7)])
    write_ply(tmp_path / "points3D_downsample.ply", dense, torch.full((7, 3), 0.5))
    mvs = load_technicolor(tmp_path, frames=(5, 8), points="mvs100k")
    assert mvs.meta["points"] == "mvs100k" and mvs.points.times is None
    torch.testing.assert_close(mvs.points.xyz, dense)
    sparse = load_technicolor(tmp_path, frames=(5, 8), points="sparse").points
    assert sparse.times is None and sorted(sparse.xyz[:, 2].tolist()) == pytest.approx([3.0, 4.0])
    frames = load_technicolor(tmp_path, frames=(5, 8), points="frames").points
    assert sorted(frames.xyz[:, 2].tolist()) == pytest.approx([3.0, 4, 4, 5, 5, 6])
    torch.testing.assert_close(frames.times, torch.tensor([0.0, 0, 1 / 3, 1 / 3, 2 / 3, 2 / 3]))
    # auto keeps its former meaning (points_frames over the COLMAP points) before the dense cloud
    assert len(load_technicolor(tmp_path, frames=(5, 8)).points) == 2
    assert len(load_technicolor(tmp_path, frames=(5, 8), points_frames="all").points) == 6
    with pytest.raises(ValueError, match="points_frames='all' chooses the COLMAP points of points='auto'"):
        load_technicolor(tmp_path, frames=(5, 8), points="sparse", points_frames="all")
    with pytest.raises(ValueError, match="Technicolor points: expected one of auto, mvs100k, sparse, frames"):
        load_technicolor(tmp_path, frames=(5, 8), points="dense")
    # the first frame triangulated nothing: 'sparse' refuses it, 'frames' merges the others, 'auto' falls
    # back to the dense cloud
    (tmp_path / "colmap_0" / "sparse" / "0" / "points3D.txt").write_text("")
    empty = r"points='sparse': expected 3D points .*colmap_0/sparse/0; found none"
    with pytest.raises(ValueError, match=empty):
        load_technicolor(tmp_path, frames=(5, 8), points="sparse")
    later = load_technicolor(tmp_path, frames=(5, 8), points="frames").points
    torch.testing.assert_close(later.times, torch.tensor([1 / 3, 1 / 3, 2 / 3, 2 / 3]))
    assert len(load_technicolor(tmp_path, frames=(5, 8)).points) == 7


def test_raw_layout_takes_the_dense_cloud_and_refuses_colmap_points(tmp_path):
    """E-D3DGS's preprocessing runs in the distributed folder and leaves its cloud there
    (``script/pre_technicolor.py:160-169``, README.md:59-61): the raw layout reads it by name or as
    ``auto``'s choice before random points; it has no per-frame COLMAP points to name."""
    from moegs.data.synthetic.writers import write_ply

    root = tmp_path / "Birthday"
    fx.write_technicolor_raw(root, frames=(151, 153))
    for points in ("sparse", "frames"):
        expected = rf"points='{points}': expected COLMAP points in .*colmap_<frame>/sparse/0"
        with pytest.raises(FileNotFoundError, match=expected):
            load_technicolor(root, frames=(151, 153), points=points)
    with pytest.raises(FileNotFoundError, match=r"points='mvs100k'.*Birthday/points3D_downsample\.ply"):
        load_technicolor(root, frames=(151, 153), points="mvs100k")
    assert "fallback" in load_technicolor(root, frames=(151, 153), num_points=100).points.source
    write_ply(root / "points3D_downsample.ply", torch.rand(9, 3), torch.rand(9, 3))
    assert len(load_technicolor(root, frames=(151, 153), points="mvs100k").points) == 9
    auto = load_technicolor(root, frames=(151, 153), num_points=100).points
    assert len(auto) == 9 and auto.source.startswith("points3D_downsample.ply")
