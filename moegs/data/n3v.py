"""Neural 3D Video (DyNeRF, Li et al. 2022) scenes in their released layout.

Layout::

    <root>/poses_bounds.npy      [N_cams, 17]: LLFF 3x5 pose (row-major) + near, far; rows follow the
                                 sorted camera names
    <root>/camXX.mp4             2704x2028, 30 fps, 300 frames (flame_salmon_1: 1200)
    optional, pre-extracted frames (used instead of the videos when present, first match wins):
    <root>/camXX/images/NNNN.png (4DGaussians)   <root>/frames/camXX/NNNN.png   <root>/camXX/N.png (STG)
    optional points: <root>/points3D_downsample2.ply (4DGaussians), <root>/colmap_<start>/sparse/0
                     (STG / MoE-GS per-frame COLMAP), <root>/points3D.ply

Conventions chosen (``specs/peers_and_style.md`` C.2, ``specs/official_moegs.md`` 8):
- Test camera ``cam00``, every other camera trains (4DGaussians, E-D3DGS, MoE-GS).
- 300 frames, ``resolution_scale=0.5`` -> 1352x1014 (bicubic: 3DGS ``PILtoTorch`` resizing used by
  MoE-GS/STG/Ex4DGS ``resolution 2``; 4DGaussians pre-resizes with Lanczos: ``resample="lanczos"``).
- Poses: the LLFF rotation columns are (down, right, back); OpenCV columns are (right, down, forward)
  = (col1, col0, -col2). No recentring or rescaling (4DGaussians and the STG COLMAP export keep the
  LLFF world). ``hwf`` gives the focal at (H, W); it is rescaled to the video size; principal point
  at the image centre.
- Time: ``frame / 300`` (``time_mode="global"``, MoE-GS router and 4DGaussians). STG's 150-frame
  segments use ``frames=(150, 300), time_mode="local"`` -> (frame - 150) / 150.
- Decoding: frames come from the videos through ``moegs.data._video`` (frame-accurate seeks, uint8
  frame cache bounded by ``video_cache_gb``; the whole window of a camera is decoded in one pass when
  all windows fit in that budget, else a short read-ahead per miss).
- ``exclude``: cameras to drop with their pose rows (E-D3DGS drops cam13 of coffee_martini).
- Near/far bounds go to ``scene.meta["bounds"]``; cameras keep the library's default clipping planes.
"""

from __future__ import annotations

import re
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera, intrinsics
from moegs.data._init_points import colmap_points, ply_points, shared_volume_points
from moegs.data._io import (
    frame_window,
    image_size,
    load_rgb,
    loaded_scene,
    normalised_time,
    points_bbox,
    read_colmap,
    require_file,
    to_rgb8,
)
from moegs.data._video import FrameCache, VideoReader
from moegs.data.scene import ImageCache, PointCloud, Scene, View

TEST_CAMERA = "cam00"
DURATION = 300
_CAM = re.compile(r"^cam\d+$")
# llff columns (down, right, back) -> OpenCV (right, down, forward)
_LLFF_TO_OPENCV = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], dtype=torch.float64)


def llff_to_w2c(pose: Tensor) -> Tensor:
    """LLFF ``[3, 5]`` (or ``[3, 4]``) camera-to-world -> OpenCV world-to-camera ``[4, 4]`` (float32)."""
    pose = pose.to(torch.float64)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = pose[:, :3] @ _LLFF_TO_OPENCV
    c2w[:3, 3] = pose[:, 3]
    return torch.linalg.inv(c2w).to(torch.float32)


def w2c_to_llff(w2c: Tensor, hwf: tuple[float, float, float]) -> Tensor:
    """Inverse of :func:`llff_to_w2c`: ``[3, 5]`` LLFF pose with ``hwf = (H, W, focal)`` (writes fixtures)."""
    c2w = torch.linalg.inv(w2c.to(torch.float64))
    pose = torch.zeros(3, 5, dtype=torch.float64)
    pose[:, :3] = c2w[:3, :3] @ _LLFF_TO_OPENCV.T
    pose[:, 3] = c2w[:3, 3]
    pose[:, 4] = torch.tensor(hwf, dtype=torch.float64)
    return pose


# -- frame sources ------------------------------------------------------------------------------------
class _FrameDir:
    """Pre-extracted PNG/JPEG frames of one camera; ``index -> path`` (frame 0 = the lowest number)."""

    def __init__(self, folder: Path) -> None:
        files = [
            p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg") and p.stem.isdigit()
        ]
        if not files:
            raise FileNotFoundError(f"N3V frames: no numbered images in {folder}")
        numbered = sorted(files, key=lambda p: int(p.stem))
        self.offset = int(numbered[0].stem)  # ffmpeg's %04d starts at 1, python extractors at 0
        self.paths = {int(p.stem) - self.offset: p for p in numbered}
        self.folder = folder
        self.num_frames = max(self.paths) + 1
        self.width, self.height = image_size(numbered[0])

    def path(self, index: int) -> Path:
        if index not in self.paths:
            raise FileNotFoundError(
                f"N3V frames: expected frame {index} (file number {index + self.offset}) in {self.folder}"
            )
        return self.paths[index]


def _frame_dir(root: Path, cam: str) -> Path | None:
    for folder in (root / cam / "images", root / "frames" / cam, root / cam):
        if folder.is_dir() and any(p.stem.isdigit() for p in folder.iterdir()):
            return folder
    return None


def _video_image(reader: VideoReader, index: int, bg: Tensor) -> Tensor:
    return torch.from_numpy(to_rgb8(reader.frame(index), bg))


# -- loader -------------------------------------------------------------------------------------------
def _camera_names(root: Path) -> list[str]:
    names = {p.stem for p in root.glob("cam*.mp4") if _CAM.match(p.stem)}
    if not names:
        names = {c for c in (p.name for p in root.glob("cam*")) if _CAM.match(c) and _frame_dir(root, c)}
        names |= {p.name for p in (root / "frames").glob("cam*") if _CAM.match(p.name)}
    return sorted(names, key=lambda n: int(n[3:]))


POINT_SOURCES = ("auto", "mvs40k", "mvs100k", "sparse", "frames")
"""``load_n3v(points=...)``: ``auto`` the first cloud found (below); ``mvs40k`` 4DGaussians' and Grid4D's
dense cloud of at most 40k points (``points3D_downsample2.ply``), ``mvs100k`` E-D3DGS's of at most 100k
(``points3D_downsample.ply``), ``sparse`` the window's first frame's COLMAP points (Ex4DGS), ``frames``
every frame's COLMAP points of the window, each tagged with its frame's time (STG,
``dataset_readers.py:816-836``). A named source that is missing is an error."""


def _named_points(
    root: Path, points: str, window: tuple[int, int], duration: int, time_mode: str
) -> PointCloud:
    """The cloud ``points`` names (``POINT_SOURCES`` other than ``auto``)."""
    files = {"mvs40k": "points3D_downsample2.ply", "mvs100k": "points3D_downsample.ply"}
    if points in files:
        return ply_points(require_file(root / files[points], f"N3V points={points!r}"))
    frames = range(window[0], window[0] + 1 if points == "sparse" else window[1])
    clouds, times = [], []
    for j in frames:
        sparse = root / f"colmap_{j}" / "sparse" / "0"
        if not sparse.is_dir():
            raise FileNotFoundError(f"N3V points={points!r}: expected COLMAP points in {sparse}")
        clouds.append(colmap_points(read_colmap(sparse), sparse))
        times.append(torch.full((len(clouds[-1]),), normalised_time(j, *window, duration, time_mode)))
    if points == "sparse":
        return clouds[0]
    return PointCloud(
        xyz=torch.cat([c.xyz for c in clouds]),
        rgb=torch.cat([c.rgb for c in clouds]),
        times=torch.cat(times),
        source=f"COLMAP points of frames {window[0]}-{window[1] - 1}, each at its time (STG style)",
    )


def _points(
    root: Path, start: int, cameras: list[Camera], bounds: np.ndarray, n: int, seed: int
) -> PointCloud | None:
    for ply in (root / "points3D_downsample2.ply", root / "points3D_downsample.ply"):
        if ply.is_file():
            return ply_points(ply)
    sparse = root / f"colmap_{start}" / "sparse" / "0"
    if sparse.is_dir():
        return colmap_points(read_colmap(sparse), sparse)
    if (root / "points3D.ply").is_file():
        return ply_points(root / "points3D.ply")
    if n <= 0:
        return None
    near, far = float(bounds[:, 0].min()), float(np.median(bounds[:, 1]))
    return shared_volume_points(cameras, n, near, far, seed, "no COLMAP/PLY points in the scene folder")


def load_n3v(
    root: str | Path,
    resolution_scale: float = 0.5,
    frames: tuple[int, int] | None = (0, DURATION),
    time_mode: str = "global",
    duration: int = DURATION,
    test_cameras: tuple[str, ...] = (TEST_CAMERA,),
    exclude: tuple[str, ...] = (),
    source: str = "auto",
    video_cache_gb: float = 2.0,
    readahead: int | None = None,
    num_points: int = 100_000,
    seed: int = 0,
    resample: str = "bicubic",
    name: str | None = None,
    points: str = "auto",
) -> Scene:
    """Load an N3V/DyNeRF scene.

    Args:
        root: folder holding ``poses_bounds.npy`` and ``camXX.mp4`` (or extracted frames).
        resolution_scale: 0.5 (default) -> 1352x1014.
        frames: half-open window ``(start, stop)``; default the protocol's first 300 frames.
        time_mode: ``"global"`` (frame / duration) or ``"local"`` ((frame - start) / (stop - start)).
        duration: the global time normaliser (300).
        test_cameras: held-out cameras (``cam00``).
        exclude: cameras dropped with their pose rows (e.g. ``("cam13",)`` for coffee_martini in E-D3DGS).
        source: ``"auto"`` (extracted frames when present, else videos), ``"video"`` or ``"frames"``.
        video_cache_gb: byte budget of the decoded-frame cache shared by all cameras.
        readahead: frames decoded after each cache miss; default the whole window if every camera's
            window fits in the budget, else 8.
        num_points: fallback random points when no COLMAP/PLY cloud is in the folder (0: none).
        points: which initial cloud (``POINT_SOURCES``; each expert's original takes its own).
    """
    root = Path(root)
    pb_path = root / "poses_bounds.npy"
    if not pb_path.is_file():
        raise FileNotFoundError(f"N3V scene: expected {pb_path} (layout: poses_bounds.npy + camXX.mp4)")
    try:
        pb = np.load(pb_path)
    except ValueError as err:
        raise ValueError(f"cannot read {pb_path}: {err}") from err
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise ValueError(
            f"{pb_path}: expected an [N_cams, 17] array (3x5 pose + near, far), got {list(pb.shape)}"
        )
    names = _camera_names(root)
    if not names:
        raise FileNotFoundError(f"N3V scene: no camXX.mp4 videos or extracted frame folders in {root}")
    if len(names) != pb.shape[0]:
        raise ValueError(
            f"{pb_path}: {pb.shape[0]} pose rows but {len(names)} cameras ({names[0]}..{names[-1]}) "
            "in the folder; rows must follow the sorted camera names"
        )
    if source not in ("auto", "video", "frames"):
        raise ValueError(f"N3V source must be 'auto', 'video' or 'frames', got {source!r}")
    keep = [i for i, n in enumerate(names) if n not in set(exclude)]
    names, pb = [names[i] for i in keep], pb[keep]

    # frame sources, probed from headers only
    cache = FrameCache(int(video_cache_gb * (1 << 30)))
    sources: dict[str, _FrameDir | VideoReader] = {}
    for cam in names:
        folder = _frame_dir(root, cam) if source != "video" else None
        if folder is not None:
            sources[cam] = _FrameDir(folder)
        elif source == "frames":
            raise FileNotFoundError(
                f"N3V frames: expected {root / cam / 'images'} or {root / 'frames' / cam}"
            )
        else:
            sources[cam] = VideoReader(root / f"{cam}.mp4", cache, resample=resample)
    available = min(s.num_frames for s in sources.values())
    window = frame_window(frames, available, f"N3V {root}")
    if time_mode == "global" and window[1] > duration:
        raise ValueError(
            f"N3V: window {window} exceeds duration {duration}; use time_mode='local' or a larger duration"
        )

    native = (sources[names[0]].width, sources[names[0]].height)
    cams: dict[str, Camera] = {}
    for i, cam in enumerate(names):
        src = sources[cam]
        if (src.width, src.height) != native:
            raise ValueError(
                f"N3V: {cam} is {src.width}x{src.height} but {names[0]} is {native[0]}x{native[1]}"
            )
        pose = torch.from_numpy(pb[i, :15].reshape(3, 5))
        H, W, f = (float(x) for x in pose[:, 4])
        ratio_w, ratio_h = native[0] / W, native[1] / H
        if abs(ratio_w - ratio_h) > 0.01 * ratio_w:
            raise ValueError(
                f"{pb_path}: hwf {H:g}x{W:g} of row {i} ({cam}) does not match the frame aspect "
                f"{native[1]}x{native[0]}"
            )
        base = Camera(
            K=intrinsics(f * ratio_w, f * ratio_w, native[0] / 2, native[1] / 2),
            world_to_camera=llff_to_w2c(pose),
            width=native[0],
            height=native[1],
            camera_id=int(cam[3:]),
            name=cam,
        )
        cams[cam] = base.scaled(resolution_scale) if resolution_scale != 1.0 else base
    size = (cams[names[0]].width, cams[names[0]].height)

    window_bytes = len(names) * (window[1] - window[0]) * size[0] * size[1] * 3
    ahead = (
        readahead
        if readahead is not None
        else (window[1] - window[0] if window_bytes <= cache.max_bytes else 8)
    )
    bg = torch.zeros(3)
    train, test = [], []
    for cam in names:
        src = sources[cam]
        if isinstance(src, VideoReader):
            src.size, src.readahead, src.stop = size, ahead, window[1]
        for j in range(*window):
            camera = replace(
                cams[cam],
                time=normalised_time(j, *window, duration, time_mode),
                frame=j,
                name=f"{cam}/{j:04d}",
            )
            if isinstance(src, VideoReader):
                load = partial(_video_image, src, j, bg)
            else:
                load = partial(load_rgb, src.path(j), native, size, bg, resample)
            view = View(camera=camera, load_image=load, key=f"n3v:{root.name}/{cam}/{j}@{size[0]}x{size[1]}")
            (test if cam in test_cameras else train).append(view)
    if not test:
        raise ValueError(f"N3V: test cameras {test_cameras} not among {names}")

    train_cams = [cams[c] for c in names if c not in test_cameras]
    if points not in POINT_SOURCES:
        raise ValueError(f"N3V points: expected one of {', '.join(POINT_SOURCES)}, got {points!r}")
    if points == "auto":
        cloud = _points(root, window[0], train_cams, pb[:, 15:], num_points, seed)
    else:
        cloud = _named_points(root, points, window, duration, time_mode)
    meta = {
        "frames": list(window),
        "duration": duration,
        "time_mode": time_mode,
        "test_cameras": list(test_cameras),
        "excluded": list(exclude),
        "points": points,
        "readahead": ahead,
        "source": "frames" if any(isinstance(s, _FrameDir) for s in sources.values()) else "video",
        "bounds": {c: [float(x) for x in pb[i, 15:]] for i, c in enumerate(names)},
    }
    return loaded_scene(
        "n3v",
        root.name,
        name,
        train,
        test,
        cameras=train_cams,
        points=cloud,
        bbox=_bbox_from_bounds(train_cams, pb[:, 15:]) if cloud is None else None,
        num_frames=window[1] - window[0],
        background=bg,
        multiview=True,
        meta=meta,
        cache=ImageCache(max_items=32),
    )


def _bbox_from_bounds(cameras: list[Camera], bounds: np.ndarray) -> Tensor:
    """Bounds of the camera centres pushed forward by the median near bound (no points available)."""
    near = float(np.median(bounds[:, 0]))
    pts = torch.stack(
        [c.center + near * c.world_to_camera[2, :3] for c in cameras] + [c.center for c in cameras]
    )
    return points_bbox(pts)
