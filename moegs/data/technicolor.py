"""Technicolor light-field video (Sabater et al. 2017), as prepared by STG / Ex4DGS, or raw.

Layouts (detected in this order):

``colmap`` -- the output of STG's ``script/pre_technicolor.py`` (also Ex4DGS's)::

    <root>/colmap_<k>/images/<name>.png   one undistorted 2048x1088 PNG per camera (``input/`` if
                                          ``images/`` is absent); <name> ends in the camera number:
                                          ``cam10.png`` (both scripts' ``imagecopy`` rename
                                          ``<Scene>_undist_00151_10.png`` so) or the distributed name
    <root>/colmap_<k>/sparse/0/           COLMAP model (cameras, images, points3D; .bin or .txt)

  ``<k>`` is the absolute frame number (Ex4DGS: ``colmap_151`` ...) or the index inside the window
  (STG: ``colmap_0`` .. ``colmap_49`` for frames 151..200); both are recognised. As in STG and
  Ex4DGS, the cameras are read from the model of the window's first frame (the rig is fixed).

``raw`` -- the dataset as distributed::

    <root>/<Scene>_undist_<frame:05d>_<cam:02d>.png
    <root>/cameras_parameters.txt         header + one row per camera (the undistorted set's file):
                                          f cu cv ar sk qw qx qy qz tx ty tz

  read as STG and Ex4DGS read it (``pre_technicolor.py``: STG ``script/`` :79-87, Ex4DGS
  ``scripts/`` :72-80): fx = fy = f, principal point (cu, cv), (q, t) = columns 5-8 and 9-11, COLMAP
  world-to-camera. The distorted set's file has two more columns (d1 d2 after sk) and is refused.

Initial clouds (``points=``, ``POINT_SOURCES``; each expert's original takes its own)::

    <root>/colmap_<k>/sparse/0/points3D.*  ``sparse``: the window's first frame's (Ex4DGS); ``frames``:
                                           every frame's, each point at its frame's time (STG)
    <root>/points3D_downsample.ply         ``mvs100k``: E-D3DGS's dense cloud of the window's first
                                           frame, at most 100k points (its ``script/pre_technicolor.py``
                                           and ``downsample_point.py``, run in the raw folder, write it)

  All of them lie in the world of ``cameras_parameters.txt`` (each script triangulates with those poses
  held), so either layout takes any of them.

Conventions chosen (``specs/official_moegs.md`` 8, ``specs/experts_noncanonical.md`` 1.4, 2.4):
- 50-frame windows, half-open in the file numbering: Birthday and Train (151, 201), Fabien and
  Theater (51, 101), Painter (100, 150) (STG ``range(151, 201)``; MoE-GS writes "151-201").
- Test camera 10; full resolution 2048x1088; calibrated (off-centre) principal point.
- Time: ``(frame - start) / (stop - start)`` (STG j/50, MoE-GS Technicolor); background black.
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
    colmap_w2c,
    image_size,
    load_rgb,
    loaded_scene,
    normalised_time,
    read_colmap,
    require_file,
)
from moegs.data.scene import PointCloud, Scene, View

WINDOWS = {
    "birthday": (151, 201),
    "train": (151, 201),
    "fabien": (51, 101),
    "theater": (51, 101),
    "painter": (100, 150),
}
TEST_CAMERA = 10
MVS100K = "points3D_downsample.ply"
_TRAILING_INT = re.compile(r"(\d+)$")
_RAW = re.compile(r"^(?P<scene>.+)_undist_(?P<frame>\d+)_(?P<cam>\d+)$")

POINT_SOURCES = ("auto", "mvs100k", "sparse", "frames")
"""``load_technicolor(points=...)``, named as ``moegs.data.n3v.POINT_SOURCES``:

- ``auto``: the COLMAP points ``points_frames`` chooses (the first frame's by default), else
  ``points3D_downsample.ply``, else random points in the cameras' shared view (``num_points``).
- ``mvs100k``: E-D3DGS's dense cloud ``<root>/points3D_downsample.ply`` (E-D3DGS
  ``scene/dataset_readers.py:352-355`` reads it and ``scene/__init__.py:59`` opens it: a missing file
  stops its training). Its preprocessing triangulates the window's first frame only
  (``script/pre_technicolor.py:160-169`` copies frame ``offsetlist[0]`` into ``colmap/input``, ``:257-259``
  build the database and run ``script/thirdparty/helper3dg.py:192-252``: ``point_triangulator`` with the
  given poses, ``patch_match_stereo``, ``stereo_fusion`` into ``colmap/dense/workspace/fused.ply``), and
  ``script/downsample_point.py:7-11`` voxel-downsamples that to at most 100k points (README.md:59-61).
- ``sparse``: the window's first frame's COLMAP points (Ex4DGS ``scene/dataset_readers.py:445, 492-501``:
  ``colmap_<start_timestamp>/sparse/0``).
- ``frames``: every frame's COLMAP points of the window, frame ``j``'s at time ``(j - start) / n`` (STG
  ``thirdparty/gaussian_splatting/scene/dataset_readers.py:913-932``).

A named source that is missing or holds no point is an error naming the file or folder expected."""


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Unit quaternion ``(w, x, y, z)`` -> rotation ``[3, 3]`` (COLMAP/Hamilton convention)."""
    w, x, y, z = (q.to(torch.float64) / q.to(torch.float64).norm()).tolist()
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ],
        dtype=torch.float64,
    )


def camera_number(name: str) -> int:
    """Camera id from an image name ending in digits (``cam10.png`` and ``X_undist_00151_10.png`` -> 10)."""
    m = _TRAILING_INT.search(Path(name).stem)
    if m is None:
        raise ValueError(f"Technicolor: cannot read a camera number from image name {name!r}")
    return int(m.group(1))


# -- calibration ---------------------------------------------------------------------------------------
def _colmap_cameras(model_dir: Path) -> dict[int, Camera]:
    rec = read_colmap(model_dir)
    cams = {}
    for image in rec.images.values():
        c = rec.cameras[image.camera_id]
        K = torch.tensor(np.asarray(c.calibration_matrix()), dtype=torch.float32)
        cid = camera_number(image.name)
        cams[cid] = Camera(
            K=K,
            world_to_camera=colmap_w2c(image),
            width=int(c.width),
            height=int(c.height),
            camera_id=cid,
            name=f"cam{cid:02d}",
        )
    return cams


def _raw_cameras(path: Path, size: tuple[int, int]) -> dict[int, Camera]:
    require_file(path, "Technicolor calibration")
    rows = [line.split() for line in path.read_text().splitlines()[1:] if line.strip()]
    cams = {}
    for i, row in enumerate(rows):
        if len(row) != 12:
            distorted = " (14: the distorted set's calibration, with d1 d2; use the undistorted set)"
            raise ValueError(
                f"{path}: row {i + 2} has {len(row)} columns, expected 12 "
                f"(f cu cv ar sk qw qx qy qz tx ty tz){distorted if len(row) == 14 else ''}"
            )
        v = [float(x) for x in row]
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = quat_to_rotmat(torch.tensor(v[5:9]))
        w2c[:3, 3] = torch.tensor(v[9:12], dtype=torch.float64)
        cams[i] = Camera(
            K=intrinsics(v[0], v[0], v[1], v[2]),
            world_to_camera=w2c.float(),
            width=size[0],
            height=size[1],
            camera_id=i,
            name=f"cam{i:02d}",
        )
    return cams


# -- layout discovery ----------------------------------------------------------------------------------
def _colmap_folders(root: Path) -> dict[int, Path]:
    out = {}
    for p in root.glob("colmap_*"):
        tail = p.name[len("colmap_") :]
        if p.is_dir() and tail.isdigit():
            out[int(tail)] = p
    return out


def _image_dir(folder: Path) -> Path:
    for sub in ("images", "input"):
        if (folder / sub).is_dir():
            return folder / sub
    raise FileNotFoundError(f"Technicolor: expected {folder / 'images'} (or input/) with one PNG per camera")


def _colmap_layout(root: Path, window: tuple[int, int]) -> tuple[list[Path], str]:
    """Per-frame folders for the window and the naming found (``absolute`` or ``local``)."""
    found = _colmap_folders(root)
    n = window[1] - window[0]
    if all(f in found for f in range(*window)):
        return [found[f] for f in range(*window)], "absolute"
    if all(k in found for k in range(n)):
        return [found[k] for k in range(n)], "local"
    have = f"{min(found)}..{max(found)}" if found else "none"
    raise FileNotFoundError(
        f"Technicolor: frames {window} need {root}/colmap_<frame> for frames {window[0]}.."
        f"{window[1] - 1} (Ex4DGS) or colmap_0..colmap_{n - 1} (STG); found colmap_ {have}"
    )


def _raw_frames(root: Path) -> dict[tuple[int, int], Path]:
    out = {}
    for p in root.glob("*_undist_*_*.png"):
        m = _RAW.match(p.stem)
        if m:
            out[(int(m["frame"]), int(m["cam"]))] = p
    return out


def detect_layout(root: Path) -> str:
    if _colmap_folders(root):
        return "colmap"
    if (root / "cameras_parameters.txt").is_file() and _raw_frames(root):
        return "raw"
    raise FileNotFoundError(
        f"Technicolor scene: expected {root}/colmap_<frame>/images + sparse/0 (STG/Ex4DGS "
        f"preprocessing) or {root}/<Scene>_undist_<frame>_<cam>.png + cameras_parameters.txt"
    )


def _default_window(root: Path, layout: str, frames: tuple[int, int] | None) -> tuple[int, int]:
    if frames is not None:
        start, stop = int(frames[0]), int(frames[1])
        if not 0 <= start < stop:
            raise ValueError(f"Technicolor: invalid frame window {frames} (half-open start, stop)")
        return start, stop
    if root.name.lower() in WINDOWS:
        return WINDOWS[root.name.lower()]
    nums = sorted(_colmap_folders(root)) if layout == "colmap" else sorted({f for f, _ in _raw_frames(root)})
    return nums[0], nums[-1] + 1


# -- loader --------------------------------------------------------------------------------------------
def load_technicolor(
    root: str | Path,
    resolution_scale: float = 1.0,
    frames: tuple[int, int] | None = None,
    test_cameras: tuple[int, ...] = (TEST_CAMERA,),
    points_frames: str | None = None,
    num_points: int = 100_000,
    seed: int = 0,
    resample: str = "bicubic",
    name: str | None = None,
    points: str = "auto",
) -> Scene:
    """Load a Technicolor scene (``colmap`` or ``raw`` layout, see the module docstring).

    Args:
        frames: half-open window in the dataset's frame numbering; default the protocol's window
            for the five benchmark scenes, else every frame found.
        test_cameras: held-out camera numbers (10).
        points_frames: with ``points="auto"``, which frames' COLMAP points: ``"first"`` (None, the
            default: the window's first frame) or ``"all"`` (every frame, each point tagged with its
            time); the clouds ``points="sparse"`` and ``points="frames"`` name.
        num_points: random points when ``points="auto"`` finds no cloud (0: none).
        points: which initial cloud (``POINT_SOURCES``; each expert's original takes its own).
    """
    root = Path(root)
    if points not in POINT_SOURCES:
        raise ValueError(f"Technicolor points: expected one of {', '.join(POINT_SOURCES)}, got {points!r}")
    if points_frames not in (None, "first", "all"):
        raise ValueError(f"points_frames must be 'first' or 'all', got {points_frames!r}")
    if points_frames is not None and points != "auto":
        raise ValueError(
            f"Technicolor: points_frames={points_frames!r} chooses the COLMAP points of points='auto' "
            f"only; points={points!r} names its cloud itself"
        )
    if not root.is_dir():
        raise FileNotFoundError(f"Technicolor scene: expected folder {root}")
    layout = detect_layout(root)
    window = _default_window(root, layout, frames)
    n = window[1] - window[0]
    bg = torch.zeros(3)
    folders: list[Path] | None = None
    meta: dict = {
        "layout": layout,
        "frames": list(window),
        "time": "(frame - start) / (stop - start)",
        "test_cameras": list(test_cameras),
        "points": points,
    }

    if layout == "colmap":
        folders, naming = _colmap_layout(root, window)
        meta["folder_naming"] = naming
        base = _colmap_cameras(folders[0] / "sparse" / "0")
        images = []
        for folder in folders:
            img_dir = _image_dir(folder)
            images.append({camera_number(p.name): p for p in img_dir.glob("*.png")})
    else:
        raw = _raw_frames(root)
        probe = next(iter(raw.values()))
        base = _raw_cameras(root / "cameras_parameters.txt", image_size(probe))
        images = [{c: p for (f, c), p in raw.items() if f == frame} for frame in range(*window)]

    train, test = [], []
    for k, frame in enumerate(range(*window)):
        time = normalised_time(frame, window[0], window[1], window[1], "local")
        for cid in sorted(base):
            if cid not in images[k]:
                where = folders[k] if folders is not None else root
                raise FileNotFoundError(
                    f"Technicolor: expected an image of camera {cid} for frame {frame} in {where}"
                )
            cam = replace(base[cid], time=time, frame=frame, name=f"cam{cid:02d}/{frame:05d}")
            native = (cam.width, cam.height)
            if resolution_scale != 1.0:
                cam = cam.scaled(resolution_scale)
            size = (cam.width, cam.height)
            view = View(
                camera=cam,
                key=f"technicolor:{root.name}/{frame}/{cid}@{size[0]}x{size[1]}",
                load_image=partial(load_rgb, images[k][cid], native, size, bg, resample),
            )
            (test if cid in test_cameras else train).append(view)
    if not test:
        raise ValueError(f"Technicolor: test cameras {test_cameras} not among cameras {sorted(base)}")
    train_cams = [base[c] for c in sorted(base) if c not in test_cameras]
    if points == "auto":
        cloud = _auto_points(root, folders, window, points_frames or "first")
        if cloud is None and num_points > 0:
            why = f"no COLMAP points or {MVS100K} in the scene folder"
            cloud = shared_volume_points(train_cams, num_points, 0.5, 10.0, seed, why)
    else:
        cloud = _named_points(root, points, folders, window)
    return loaded_scene(
        "technicolor",
        root.name.lower(),
        name,
        train,
        test,
        cameras=train_cams,
        points=cloud,
        num_frames=n,
        background=bg,
        multiview=True,
        meta=meta,
    )


def _auto_points(
    root: Path, folders: list[Path] | None, window: tuple[int, int], points_frames: str
) -> PointCloud | None:
    """``points="auto"``: the COLMAP points ``points_frames`` chooses, else E-D3DGS's cloud, else None."""
    cloud = _colmap_window_points(folders, window, points_frames) if folders is not None else None
    if cloud is None and (root / MVS100K).is_file():
        cloud = ply_points(root / MVS100K)
    return cloud


def _named_points(
    root: Path, points: str, folders: list[Path] | None, window: tuple[int, int]
) -> PointCloud:
    """The cloud ``points`` names (``POINT_SOURCES`` but ``auto``), or an error naming what is missing."""
    what = f"Technicolor points={points!r}"
    if points == "mvs100k":
        return ply_points(require_file(root / MVS100K, what))
    if folders is None:
        raise FileNotFoundError(
            f"{what}: expected COLMAP points in {root}/colmap_<frame>/sparse/0 (STG/Ex4DGS preprocessing); "
            "the raw layout has none"
        )
    chosen = folders[:1] if points == "sparse" else folders
    cloud = _colmap_window_points(folders, window, "first" if points == "sparse" else "all")
    if cloud is None:
        where = ", ".join(str(f / "sparse" / "0") for f in chosen[:2]) + (", ..." if len(chosen) > 2 else "")
        raise ValueError(f"{what}: expected 3D points in the COLMAP model of {where}; found none")
    return cloud


def _colmap_window_points(
    folders: list[Path], window: tuple[int, int], points_frames: str
) -> PointCloud | None:
    if points_frames not in ("first", "all"):
        raise ValueError(f"points_frames must be 'first' or 'all', got {points_frames!r}")
    chosen = folders[:1] if points_frames == "first" else folders
    clouds, times = [], []
    for k, folder in enumerate(chosen):
        rec = read_colmap(folder / "sparse" / "0")
        if not rec.points3D:
            continue
        cloud = colmap_points(rec, folder / "sparse" / "0")
        clouds.append(cloud)
        t = normalised_time(window[0] + k, window[0], window[1], window[1], "local")
        times.append(torch.full((len(cloud),), t))
    if not clouds:
        return None
    if len(clouds) == 1 and points_frames == "first":
        return clouds[0]
    return PointCloud(
        xyz=torch.cat([c.xyz for c in clouds]),
        rgb=torch.cat([c.rgb for c in clouds]),
        times=torch.cat(times),
        source=f"COLMAP points of {len(clouds)} frames (STG style)",
    )
