"""N3V loader: LLFF pose conversion, frame-accurate lazy video decoding, windows, extracted frames."""

from __future__ import annotations

import pickle

import helpers.data_layouts as fx
import numpy as np
import pytest
import torch

from moegs.data._video import FrameCache, VideoReader
from moegs.data.n3v import llff_to_w2c, load_n3v, w2c_to_llff


def _close_to(img: torch.Tensor, cam: int, frame: int, tol: float = 8 / 255) -> bool:
    expected = torch.tensor(fx.colour(cam, frame), dtype=torch.float32) / 255
    return bool((img.reshape(-1, 3).mean(0) - expected).abs().max() < tol)


def test_llff_round_trip_and_axes():
    for w2c in fx.ring_w2c(4):
        torch.testing.assert_close(llff_to_w2c(w2c_to_llff(w2c, (2.0, 3.0, 4.0))), w2c, atol=1e-5, rtol=0)
    # LLFF columns are (down, right, back): a camera with identity LLFF rotation looks along world -z,
    # its image right is world +y and image down is world +x
    pose = torch.zeros(3, 5)
    pose[:, :3] = torch.eye(3)
    w2c = llff_to_w2c(pose)
    R = w2c[:3, :3]
    torch.testing.assert_close(R[0], torch.tensor([0.0, 1.0, 0.0]))  # camera x (right) = world y
    torch.testing.assert_close(R[1], torch.tensor([1.0, 0.0, 0.0]))  # camera y (down) = world x
    torch.testing.assert_close(R[2], torch.tensor([0.0, 0.0, -1.0]))  # camera z (forward) = world -z


def test_video_reader_is_frame_accurate(tmp_path):
    path = tmp_path / "cam03.mp4"
    fx.write_video(path, 3, 20, (32, 24), gop=4)
    reader = VideoReader(path, FrameCache(), readahead=0)
    assert (reader.width, reader.height, reader.num_frames) == (32, 24, 20)
    rng = np.random.default_rng(0)
    order = [19, 0, 13, 14, 2, 7, 7, 18, 1, *rng.permutation(20).tolist()]
    for j in order:
        arr = reader.frame(int(j))
        assert arr.dtype == np.uint8 and arr.shape == (24, 32, 3)
        assert np.abs(arr.reshape(-1, 3).mean(0) - fx.colour(3, int(j))).max() < 8, j
    with pytest.raises(IndexError, match="frame 20"):
        reader.frame(20)


def test_video_reader_window_decoded_once(tmp_path):
    path = tmp_path / "cam00.mp4"
    fx.write_video(path, 0, 12, (16, 16), gop=12)
    cache = FrameCache()
    reader = VideoReader(path, cache, readahead=12, stop=10)
    reader.frame(2)
    assert len(cache) == 8  # frames 2..9: the window read ahead in one pass
    reader.frame(0)
    assert len(cache) == 10  # 0, 1 decoded, then stopped at the cached frame 2
    small = FrameCache(max_bytes=3 * 16 * 16 * 3)
    r2 = VideoReader(path, small, readahead=12)
    r2.frame(5)
    assert len(small) == 3 and small.nbytes <= small.max_bytes


def test_fixture_scene(tmp_path):
    truth = fx.write_n3v(tmp_path, cams=4, frames=12)
    scene = load_n3v(tmp_path, resolution_scale=1.0, frames=None, duration=12, num_points=300)
    assert (len(scene.train), len(scene.test)) == (3 * 12, 12)
    assert {v.camera.camera_id for v in scene.test} == {0}
    assert scene.num_frames == 12 and scene.multiview
    for v in scene.train + scene.test:
        torch.testing.assert_close(
            v.camera.world_to_camera, truth["w2c"][v.camera.camera_id], atol=1e-5, rtol=0
        )
        assert v.camera.fx == pytest.approx(truth["focal"]) and v.camera.cx == pytest.approx(16.0)
        assert v.camera.time == pytest.approx(v.camera.frame / 12)
    view = next(v for v in scene.train if v.camera.name == "cam02/0007")
    img = view.image()
    assert img.shape == (24, 32, 3) and img.dtype == torch.float32
    assert _close_to(img, 2, 7)
    assert scene.meta["source"] == "video" and scene.meta["bounds"]["cam01"] == [3.0, 51.0]
    assert "fallback" in scene.points.source


def test_window_half_resolution_local_time(tmp_path):
    fx.write_n3v(tmp_path, cams=3, frames=12)
    scene = load_n3v(tmp_path, frames=(6, 12), time_mode="local", num_points=0)
    cam = scene.train[0].camera
    assert (cam.width, cam.height) == (16, 12) and cam.fx == pytest.approx(15.0)
    assert sorted({v.camera.frame for v in scene.train}) == list(range(6, 12))
    assert sorted({v.camera.time for v in scene.train}) == pytest.approx([k / 6 for k in range(6)])
    assert all(_close_to(v.image(), v.camera.camera_id, v.camera.frame, 12 / 255) for v in scene.test)
    glob = load_n3v(tmp_path, frames=(6, 12), duration=12, num_points=0)
    assert min(v.camera.time for v in glob.train) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="exceeds duration"):
        load_n3v(tmp_path, frames=(0, 12), duration=10, num_points=0)
    ex = load_n3v(tmp_path, frames=(0, 2), exclude=("cam02",), num_points=0)
    assert {v.camera.camera_id for v in ex.train} == {1}


@pytest.mark.parametrize("style", ["4dgs", "stg", "ffmpeg"])
def test_extracted_frames(tmp_path, style):
    fx.write_n3v(tmp_path, cams=3, frames=4, extracted=style)
    scene = load_n3v(tmp_path, resolution_scale=1.0, frames=(1, 4), num_points=0)
    assert scene.meta["source"] == "frames" and len(scene.train) == 6
    view = next(v for v in scene.train if v.camera.name == "cam01/0002")
    assert _close_to(view.image(), 1, 2, 1 / 255)


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="poses_bounds.npy"):
        load_n3v(tmp_path)
    fx.write_n3v(tmp_path, cams=3, frames=4)
    np.save(tmp_path / "poses_bounds.npy", np.load(tmp_path / "poses_bounds.npy")[:2])
    with pytest.raises(ValueError, match="2 pose rows but 3 cameras"):
        load_n3v(tmp_path, frames=None, num_points=0)
    fx.write_n3v(tmp_path, cams=3, frames=4)
    (tmp_path / "cam01.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 4)
    with pytest.raises(ValueError, match=r"cam01\.mp4"):
        load_n3v(tmp_path, frames=None, num_points=0)
    fx.write_n3v(tmp_path, cams=3, frames=4)
    with pytest.raises(ValueError, match="frame window"):
        load_n3v(tmp_path, frames=(0, 300), num_points=0)
    # truncated video: the index (moov, written first) opens, the frames are missing -> decoding names it
    fx.write_video(tmp_path / "cam02.mp4", 2, 4, (32, 24), faststart=True)
    data = (tmp_path / "cam02.mp4").read_bytes()
    (tmp_path / "cam02.mp4").write_bytes(data[: len(data) * 2 // 3])
    scene = load_n3v(tmp_path, frames=None, duration=4, num_points=0)
    with pytest.raises(ValueError, match=r"cam02\.mp4"):
        for v in scene.train:
            if v.camera.camera_id == 2:
                v.image()


def test_views_pickle_for_worker_processes(tmp_path):
    fx.write_n3v(tmp_path, cams=2, frames=6)
    scene = load_n3v(tmp_path, frames=None, duration=6, num_points=0)
    view = scene.train[3]
    view.image()  # opens a decoder in this process
    copy = pickle.loads(pickle.dumps(view))
    torch.testing.assert_close(copy.image(), view.image())


def test_load_decodes_no_frame(tmp_path, monkeypatch):
    """Loading reads each video's index only; frames are decoded when a view's image is asked for."""
    from moegs.data._video import VideoReader

    fx.write_n3v(tmp_path, cams=3, frames=30)
    decode = VideoReader._decode

    def refuse(self, index):
        raise AssertionError(f"decoded frame {index} of {self.path} while loading")

    monkeypatch.setattr(VideoReader, "_decode", refuse)
    scene = load_n3v(tmp_path, frames=None, duration=30, num_points=0)
    assert len(scene.cache) == 0
    monkeypatch.setattr(VideoReader, "_decode", decode)
    assert scene.train[0].image().shape[-1] == 3 and len(scene.cache) > 0


def test_each_experts_initial_cloud_by_name(tmp_path):
    """``points=``: the dense clouds by file, the window's first frame's COLMAP points (Ex4DGS), or every
    frame's points tagged with its frame's time (STG); a named source that is missing is an error."""
    from moegs.data.synthetic.writers import write_ply

    fx.write_n3v(tmp_path, cams=3, frames=6)
    fx.write_technicolor_colmap(tmp_path, frames=(0, 6))  # colmap_<j>/sparse/0, two points at z = 3 + j
    with pytest.raises(FileNotFoundError, match="points='mvs40k'.*points3D_downsample2.ply"):
        load_n3v(tmp_path, frames=(2, 5), points="mvs40k")
    write_ply(tmp_path / "points3D_downsample2.ply", torch.rand(5, 3), torch.rand(5, 3))
    assert len(load_n3v(tmp_path, frames=(2, 5), points="mvs40k").points) == 5
    sparse = load_n3v(tmp_path, frames=(2, 5), points="sparse").points
    assert sparse.times is None and sorted(sparse.xyz[:, 2].tolist()) == pytest.approx([5.0, 6.0])
    frames = load_n3v(tmp_path, frames=(2, 5), time_mode="local", points="frames")
    cloud = frames.points
    assert len(cloud) == 6 and cloud.times is not None
    times = sorted({v.camera.time for v in frames.train})
    assert sorted(set(cloud.times.tolist())) == pytest.approx(times)  # each point at its frame's time
    assert load_n3v(tmp_path, frames=(2, 5), points="auto").points is not None
    with pytest.raises(ValueError, match="N3V points: expected one of auto, mvs40k"):
        load_n3v(tmp_path, frames=(2, 5), points="dense")
