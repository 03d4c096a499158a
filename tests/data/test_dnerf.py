"""D-NeRF loader: native layout fixture (poses, times, background) and the real ``mutant`` scene."""

from __future__ import annotations

import json
import math

import helpers.data_layouts as fx
import numpy as np
import pytest
import torch

from moegs.data.dnerf import blender_to_w2c, load_dnerf, w2c_to_blender


def test_blender_round_trip():
    for w2c in fx.ring_w2c(5):
        torch.testing.assert_close(blender_to_w2c(w2c_to_blender(w2c)), w2c, atol=1e-5, rtol=0)
    # Blender camera looks down its -z: the camera-to-world z column points away from the target
    w2c = fx.ring_w2c(1)[0]
    c2w_gl = w2c_to_blender(w2c)
    centre = c2w_gl[:3, 3]
    assert torch.dot(c2w_gl[:3, 2], -centre) < 0


def test_fixture_counts_sizes_times_poses(tmp_path):
    truth = fx.write_dnerf(tmp_path)
    scene = load_dnerf(tmp_path, num_points=100)
    assert (len(scene.train), len(scene.test)) == (6, 3)
    assert scene.dataset == "dnerf" and not scene.multiview and scene.is_real
    cam = scene.train[0].camera
    assert (cam.width, cam.height) == (16, 16)
    focal = 0.5 * 16 / math.tan(0.5 * truth["angle"])
    assert cam.fx == pytest.approx(focal) and cam.cx == pytest.approx(8.0)
    for view, w2c, t in zip(scene.train, truth["train"]["w2c"], truth["train"]["times"], strict=True):
        torch.testing.assert_close(view.camera.world_to_camera, w2c, atol=1e-5, rtol=0)
        assert view.camera.time == pytest.approx(t)
    assert scene.num_frames == 6
    assert len(scene.points) == 100 and (scene.points.xyz.abs() <= 1.3).all()
    torch.testing.assert_close(scene.bbox, torch.tensor([[-1.3] * 3, [1.3] * 3]))
    # extent = 1.1 x max distance of the ring cameras from their centroid (radius 4 ring)
    assert scene.extent == pytest.approx(1.1 * 4.0, rel=1e-4)


@pytest.mark.parametrize("background, value", [("white", 1.0), ("black", 0.0)])
def test_background_composite(tmp_path, background, value):
    fx.write_dnerf(tmp_path, counts={"train": 2, "test": 1})
    scene = load_dnerf(tmp_path, background=background, num_points=0)
    img = scene.train[1].image()
    assert img.shape == (16, 16, 3) and img.dtype == torch.float32
    torch.testing.assert_close(img[:, :8], torch.full((16, 8, 3), value))  # alpha 0: background only
    expected = torch.tensor(fx.colour(1, 1), dtype=torch.float32) / 255
    torch.testing.assert_close(img[:, 8:], expected.expand(16, 8, 3))
    assert scene.points is None


def test_a_wide_image_centres_its_principal_point_and_masks_the_object(tmp_path):
    """``cx = W / 2``, ``cy = H / 2``, the focal from the width; the dynamic mask is the object (alpha)."""
    truth = fx.write_dnerf(tmp_path, counts={"train": 2, "test": 1}, size=24, height=16)
    scene = load_dnerf(tmp_path, num_points=0)
    view = scene.train[0]
    cam = view.camera
    assert (cam.width, cam.height) == (24, 16) and view.image().shape == (16, 24, 3)
    assert (cam.cx, cam.cy) == pytest.approx((12.0, 8.0))
    assert cam.fx == pytest.approx(0.5 * 24 / math.tan(0.5 * truth["angle"])) and cam.fy == pytest.approx(
        cam.fx
    )
    mask = view.mask()
    assert mask.shape == (16, 24)
    assert (mask[:, :12] == 0).all() and (mask[:, 12:] == 1).all()  # alpha 0 on the left half


def test_half_resolution_and_val_split(tmp_path):
    fx.write_dnerf(tmp_path)
    scene = load_dnerf(tmp_path, resolution_scale=0.5, test_split="val", num_points=0)
    assert len(scene.test) == 2
    cam = scene.test[0].camera
    assert (cam.width, cam.height) == (8, 8)
    img = scene.test[0].image()
    assert img.shape == (8, 8, 3)
    torch.testing.assert_close(img[:, :4], torch.ones(8, 4, 3))


def test_errors_name_file_key_and_size(tmp_path):
    with pytest.raises(FileNotFoundError, match="transforms_train.json"):
        load_dnerf(tmp_path)
    fx.write_dnerf(tmp_path, counts={"train": 2, "test": 1})
    # missing key: names the key and the file
    path = tmp_path / "transforms_test.json"
    meta = json.loads(path.read_text())
    del meta["frames"][0]["time"]
    path.write_text(json.dumps(meta))
    with pytest.raises(KeyError, match=r"transforms_test\.json.*'time'.*frames\[0\]"):
        load_dnerf(tmp_path, num_points=0)
    del meta["camera_angle_x"]
    path.write_text(json.dumps(meta))
    with pytest.raises(KeyError, match="camera_angle_x"):
        load_dnerf(tmp_path, num_points=0)
    # missing image: the loader is lazy, the read names the path
    fx.write_dnerf(tmp_path, counts={"train": 2, "test": 1})
    (tmp_path / "train" / "r_001.png").unlink()
    scene = load_dnerf(tmp_path, num_points=0)
    with pytest.raises(FileNotFoundError, match=r"train/r_001\.png"):
        scene.train[1].image()
    # wrong size: names the file, expected and found
    fx._save(np.zeros((10, 12, 4), np.uint8), tmp_path / "train" / "r_001.png")
    with pytest.raises(ValueError, match=r"r_001\.png: image is 12x10 but 16x16"):
        scene.train[1].image()
    with pytest.raises(ValueError, match="background"):
        load_dnerf(tmp_path, background="green")


def test_times_out_of_range_repeated_times_and_a_test_image_of_another_size(tmp_path):
    """A time outside [0, 1] is refused; views sharing a time are one frame; a test image must have the
    training images' size (one camera model for the whole scene)."""
    fx.write_dnerf(tmp_path, counts={"train": 4, "test": 1})
    path = tmp_path / "transforms_train.json"
    meta = json.loads(path.read_text())
    for i, frame in enumerate(meta["frames"]):
        frame["time"] = [0.0, 0.0, 0.5, 1.0][i]
    path.write_text(json.dumps(meta))
    assert load_dnerf(tmp_path, num_points=0).num_frames == 3
    meta["frames"][2]["time"] = 1.5
    path.write_text(json.dumps(meta))
    with pytest.raises(
        ValueError, match=r"transforms_train\.json: frames\[2\]\.time = 1\.5 is outside \[0, 1\]"
    ):
        load_dnerf(tmp_path, num_points=0)

    fx.write_dnerf(tmp_path, counts={"train": 2, "test": 1})
    fx._save(np.zeros((12, 12, 4), np.uint8), tmp_path / "test" / "r_000.png")
    with pytest.raises(ValueError, match=r"r_000\.png: image is 12x12 but 16x16"):
        load_dnerf(tmp_path, num_points=0).test[0].image()


# -- real data --------------------------------------------------------------------------------------
@pytest.mark.realdata
def test_mutant(mutant_root):
    scene = load_dnerf(mutant_root, num_points=1000)
    assert (len(scene.train), len(scene.test)) == (150, 20)
    val = load_dnerf(mutant_root, test_split="val", num_points=0)
    assert len(val.test) == 20
    cams = [v.camera for v in scene.train + scene.test]
    assert {(c.width, c.height) for c in cams} == {(800, 800)}
    meta = json.loads((mutant_root / "transforms_test.json").read_text())
    assert [v.camera.time for v in scene.test] == pytest.approx([f["time"] for f in meta["frames"]])
    assert all(0.0 <= c.time <= 1.0 for c in cams)
    assert min(c.time for c in cams) == 0.0 and max(c.time for c in cams) == 1.0
    # the object sits at the origin: the origin projects inside every image, near the centre
    for c in cams:
        p = c.world_to_camera @ torch.tensor([0.0, 0.0, 0.0, 1.0])
        assert p[2] > 0
        uv = (c.K @ (p[:3] / p[2]))[:2]
        assert ((uv - 400).abs() < 200).all(), (c.name, uv)
    # white background: where alpha == 0 the composite is exactly white; elsewhere it is rgb*a + (1-a)
    # truncated to 8 bits, the ground truth 4DGaussians / DeformableGS / Grid4D train on
    view = scene.test[0]
    from PIL import Image

    rgba = np.asarray(Image.open(mutant_root / "test" / "r_000.png")).astype(np.float64) / 255
    img = view.image().numpy()
    transparent = rgba[..., 3] == 0
    assert transparent.mean() > 0.3
    assert (img[transparent] == 1.0).all()
    composite = rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])
    np.testing.assert_array_equal(img, (np.floor(composite * 255) / 255).astype(np.float32))
    partial = (rgba[..., 3] > 0) & (rgba[..., 3] < 1)
    assert partial.sum() > 1000  # the edge pixels where truncating differs from the exact composite
    assert view.cache.get(view.key, view.load_image).dtype == torch.uint8  # resident at a byte a value
