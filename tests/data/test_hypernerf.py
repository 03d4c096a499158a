"""HyperNeRF loader: vrig/interp splits, Nerfies camera convention with scene normalisation, 2x images."""

from __future__ import annotations

import json

import helpers.data_layouts as fx
import numpy as np
import pytest
import torch

from moegs.data.hypernerf import load_hypernerf


def test_vrig_split_poses_times(tmp_path):
    truth = fx.write_hypernerf(tmp_path, steps=5)
    scene = load_hypernerf(tmp_path, num_points=0)
    assert scene.meta["split"] == "vrig" and scene.meta["rgb_folder"] == "2x"
    assert (len(scene.train), len(scene.test)) == (5, 5)
    assert {v.camera.camera_id for v in scene.train} == {0} and {v.camera.camera_id for v in scene.test} == {
        1
    }
    # time = warp_id / max(warp_id): warp ids 0, 2, .., 8 -> 0, .25, .., 1
    assert [v.camera.time for v in scene.train] == pytest.approx([0.0, 0.25, 0.5, 0.75, 1.0])
    assert scene.num_frames == 5 and not scene.multiview
    for v in scene.train + scene.test:
        torch.testing.assert_close(v.camera.world_to_camera, truth["w2c"][v.camera.name], atol=1e-5, rtol=0)
        assert (v.camera.width, v.camera.height) == (32, 20)
        assert v.camera.fx == pytest.approx(25.0)
        assert (v.camera.cx, v.camera.cy) == pytest.approx((16.0, 10.0))  # centred (GS convention)
    img = scene.test[2].image()
    torch.testing.assert_close(
        img, (torch.tensor(fx.colour(1, 2), dtype=torch.float32) / 255).expand(20, 32, 3)
    )
    # points.npy is normalised like the cameras: (x - center) * scale
    torch.testing.assert_close(scene.points.xyz, torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    assert scene.meta["ignored_distortion_max"] == pytest.approx(0.01)


def test_calibrated_principal_point_interp_and_time_id(tmp_path):
    fx.write_hypernerf(tmp_path, steps=8, val=False)
    scene = load_hypernerf(tmp_path, principal_point="calibrated", time_key="time_id", num_points=0)
    assert scene.meta["split"] == "interp"
    assert len(scene.train) == 4 and len(scene.test) == 4  # ids[::4] and ids[2::4] of 16 ids
    cam = scene.train[0].camera
    assert (cam.cx, cam.cy) == pytest.approx(((32 + 3) / 2, (20 - 2) / 2))
    assert max(v.camera.time for v in scene.test) == pytest.approx(7 / 7)


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="dataset.json"):
        load_hypernerf(tmp_path)
    fx.write_hypernerf(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"rgb/4x .*found \['2x'\]"):
        load_hypernerf(tmp_path, resolution_scale=0.25)
    path = tmp_path / "camera" / "1_00003.json"
    cj = json.loads(path.read_text())
    del cj["focal_length"]
    path.write_text(json.dumps(cj))
    with pytest.raises(KeyError, match=r"1_00003\.json: missing key 'focal_length'"):
        load_hypernerf(tmp_path)
    fx.write_hypernerf(tmp_path)
    md = json.loads((tmp_path / "metadata.json").read_text())
    del md["0_00002"]["warp_id"]
    (tmp_path / "metadata.json").write_text(json.dumps(md))
    with pytest.raises(KeyError, match=r"metadata\.json: missing key 'warp_id' in metadata\['0_00002'\]"):
        load_hypernerf(tmp_path)
    fx.write_hypernerf(tmp_path)
    (tmp_path / "rgb" / "2x" / "0_00001.png").unlink()
    scene = load_hypernerf(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"rgb/2x/0_00001\.png"):
        scene.train[1].image()
    fx._save(np.zeros((7, 9, 3), np.uint8), tmp_path / "rgb" / "2x" / "0_00001.png")
    with pytest.raises(ValueError, match=r"0_00001\.png: image is 9x7 but 32x20"):
        scene.train[1].image()
    cj = json.loads((tmp_path / "camera" / "0_00000.json").read_text())
    cj["image_size"] = [640, 400]
    (tmp_path / "camera" / "0_00000.json").write_text(json.dumps(cj))
    with pytest.raises(ValueError, match=r"images are 32x20 but .*0_00000\.json says 640x400"):
        load_hypernerf(tmp_path)
