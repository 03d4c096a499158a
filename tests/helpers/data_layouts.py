"""Tiny scenes written in each dataset's native layout, from known OpenCV cameras.

Every writer takes the folder to fill and returns the ground truth it wrote (OpenCV world-to-camera
matrices, intrinsics, sizes, times), so a test can read the folder back through the loader and
compare. Pixel values encode ``(camera, frame)``: red = 10 * frame + 20, green = 30 * camera + 10,
blue = 128 (uniform per image, so lossy video codecs still decode them to within a few levels).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import av
import numpy as np
import torch
from PIL import Image

from moegs.camera import look_at


def colour(camera: int, frame: int) -> tuple[int, int, int]:
    return (10 * frame + 20) % 256, (30 * camera + 10) % 256, 128


def pattern(camera: int, frame: int, size: tuple[int, int]) -> np.ndarray:
    """uint8 ``[H, W, 3]`` filled with :func:`colour`."""
    return np.broadcast_to(np.array(colour(camera, frame), np.uint8), (size[1], size[0], 3)).copy()


def ring_w2c(n: int, radius: float = 4.0, height: float = 1.0, up: str = "z") -> list[torch.Tensor]:
    """``n`` OpenCV world-to-camera matrices on a ring, all looking at the origin."""
    out = []
    for i in range(n):
        a = 2 * math.pi * i / n + 0.3
        if up == "z":
            eye, upv = (
                torch.tensor([radius * math.cos(a), radius * math.sin(a), height]),
                torch.tensor([0.0, 0, 1]),
            )
        else:  # -y up (Panoptic)
            eye, upv = (
                torch.tensor([radius * math.cos(a), -height, radius * math.sin(a)]),
                torch.tensor([0.0, -1, 0]),
            )
        out.append(look_at(eye, torch.zeros(3), upv))
    return out


def _save(arr: np.ndarray, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path)


# -- D-NeRF ------------------------------------------------------------------------------------------------
def write_dnerf(
    root: Path,
    counts: dict[str, int] | None = None,
    size: int = 16,
    angle: float = 0.69,
    height: int | None = None,
) -> dict:
    """``transforms_{split}.json`` + RGBA PNGs ``size`` wide, ``height`` (default ``size``) high; the left
    half of every image has alpha 0."""
    from moegs.data.dnerf import w2c_to_blender

    counts = counts or {"train": 6, "val": 2, "test": 3}
    height = size if height is None else height
    truth: dict = {"angle": angle, "size": size}
    for split, n in counts.items():
        frames, w2cs = [], ring_w2c(n, radius=4.0)
        times = [i / max(n - 1, 1) for i in range(n)]
        for i, (w2c, t) in enumerate(zip(w2cs, times, strict=True)):
            rgba = np.concatenate(
                [pattern(i, i, (size, height)), np.full((height, size, 1), 255, np.uint8)], -1
            )
            rgba[:, : size // 2, 3] = 0
            rgba[:, : size // 2, :3] = 77  # hidden colour, must not leak through
            _save(rgba, root / split / f"r_{i:03d}.png")
            frames.append(
                {
                    "file_path": f"./{split}/r_{i:03d}",
                    "rotation": 0.1,
                    "time": t,
                    "transform_matrix": w2c_to_blender(w2c).tolist(),
                }
            )
        (root / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames})
        )
        truth[split] = {"w2c": w2cs, "times": times}
    return truth


# -- Panoptic ----------------------------------------------------------------------------------------------
def write_panoptic(
    root: Path,
    train_ids=(1, 2, 3, 4),
    test_ids=(0, 5),
    frames: int = 3,
    size=(32, 18),
    with_seg: bool = True,
    with_npz: bool = False,
) -> dict:
    """Dynamic3DGaussians metas, JPEG images, optional seg PNGs and init_pt_cld.npz."""
    ids = sorted([*train_ids, *test_ids])
    w2cs = dict(zip(ids, ring_w2c(len(ids), radius=3.0, height=1.5, up="-y"), strict=True))
    K = [[20.0, 0.0, size[0] / 2 + 0.5], [0.0, 21.0, size[1] / 2 - 0.5], [0.0, 0.0, 1.0]]
    for split, cams in (("train", train_ids), ("test", test_ids)):
        meta = {"w": size[0], "h": size[1], "k": [], "w2c": [], "fn": [], "cam_id": []}
        for t in range(frames):
            meta["k"].append([K for _ in cams])
            meta["w2c"].append([w2cs[c].tolist() for c in cams])
            meta["fn"].append([f"{c}/{t:06d}.jpg" for c in cams])
            meta["cam_id"].append(list(cams))
            for c in cams:
                _save(pattern(c, t, size), root / "ims" / str(c) / f"{t:06d}.jpg")
                if with_seg and split == "train":
                    seg = np.zeros((size[1], size[0]), np.uint8)
                    seg[:, size[0] // 2 :] = 255
                    Image.fromarray(seg).convert("1").save(_mk(root / "seg" / str(c) / f"{t:06d}.png"))
        (root / f"{split}_meta.json").write_text(json.dumps(meta))
    if with_npz:
        data = np.concatenate(
            [np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3)), np.full((50, 3), 0.25), np.ones((50, 1))],
            axis=1,
        )
        np.savez(root / "init_pt_cld.npz", data=data)
    return {"w2c": w2cs, "K": torch.tensor(K), "size": size, "frames": frames}


def _mk(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


# -- N3V ---------------------------------------------------------------------------------------------------
def write_video(
    path: Path, camera: int, frames: int, size: tuple[int, int], gop: int = 4, faststart: bool = False
) -> None:
    """H.264 mp4 (PyAV) whose frame ``j`` is filled with ``colour(camera, j)``; key frame every ``gop``.
    ``faststart`` puts the index (moov) first, so a truncated file still opens but lacks frames."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w", options={"movflags": "faststart"} if faststart else {}) as container:
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        stream.options = {"g": str(gop), "keyint_min": str(gop), "crf": "8", "bf": "2"}
        for j in range(frames):
            frame = av.VideoFrame.from_ndarray(pattern(camera, j, size), format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def write_n3v(
    root: Path,
    cams: int = 4,
    frames: int = 12,
    size=(32, 24),
    hwf_scale: float = 2.0,
    extracted: str | None = None,
) -> dict:
    """``poses_bounds.npy`` + ``camXX.mp4``. The hwf row says ``hwf_scale`` x the video size (as the
    released N3V files do for the full 2704x2028 capture) so the loader must rescale the focal.
    ``extracted`` = ``"4dgs"``, ``"stg"`` (numbered from 0) or ``"ffmpeg"`` (``%04d``, numbered from 1) writes
    PNG frames instead of videos."""
    from moegs.data.n3v import w2c_to_llff

    w2cs = ring_w2c(cams, radius=5.0)
    focal_video = 30.0
    rows = []
    for c, w2c in enumerate(w2cs):
        hwf = (size[1] * hwf_scale, size[0] * hwf_scale, focal_video * hwf_scale)
        rows.append(np.concatenate([w2c_to_llff(w2c, hwf).numpy().reshape(-1), [2.0 + c, 50.0 + c]]))
        if extracted is None:
            write_video(root / f"cam{c:02d}.mp4", c, frames, size)
        else:
            for j in range(frames):
                sub = {
                    "4dgs": f"cam{c:02d}/images/{j:04d}.png",
                    "ffmpeg": f"cam{c:02d}/images/{j + 1:04d}.png",
                    "stg": f"cam{c:02d}/{j}.png",
                }[extracted]
                _save(pattern(c, j, size), root / sub)
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return {"w2c": w2cs, "focal": focal_video, "size": size, "frames": frames}


# -- Technicolor -------------------------------------------------------------------------------------------
def _rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation ``[3, 3]`` -> unit quaternion (w, x, y, z)."""
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def technicolor_cameras(cams: int = 12, size=(40, 24)) -> tuple[list[torch.Tensor], list[list[float]]]:
    """A 4x3 planar rig facing +z (as the Technicolor rig), with off-centre principal points."""
    w2cs, intr = [], []
    for c in range(cams):
        w2c = torch.eye(4)
        w2c[:3, 3] = torch.tensor([-(c % 4) * 0.1, -(c // 4) * 0.1, 0.0])
        w2cs.append(w2c)
        intr.append([30.0 + c, size[0] / 2 + 1.5, size[1] / 2 - 0.75])
    return w2cs, intr


def write_technicolor_colmap(
    root: Path,
    frames=(5, 8),
    cams: int = 12,
    size=(40, 24),
    naming: str = "local",
    names: str = "stg",
    binary: bool = False,
) -> dict:
    """STG/Ex4DGS per-frame layout: ``colmap_<k>/images/*.png`` + ``colmap_<k>/sparse/0`` (text or binary)."""
    import pycolmap

    w2cs, intr = technicolor_cameras(cams, size)
    for k, frame in enumerate(range(*frames)):
        folder = root / f"colmap_{k if naming == 'local' else frame}"
        sparse = folder / "sparse" / "0"
        sparse.mkdir(parents=True, exist_ok=True)
        cam_lines, img_lines = [], []
        for c in range(cams):
            name = f"cam{c:02d}.png" if names == "stg" else f"Scene_undist_{frame:05d}_{c:02d}.png"
            _save(pattern(c, frame, size), folder / "images" / name)
            f, cx, cy = intr[c]
            cam_lines.append(f"{c + 1} PINHOLE {size[0]} {size[1]} {f} {f} {cx} {cy}")
            q = _rotmat_to_quat(w2cs[c][:3, :3].numpy().astype(np.float64))
            t = w2cs[c][:3, 3].tolist()
            img_lines += [f"{c + 1} {' '.join(map(str, q))} {' '.join(map(str, t))} {c + 1} {name}", ""]
        (sparse / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
        (sparse / "images.txt").write_text("\n".join(img_lines) + "\n")
        (sparse / "points3D.txt").write_text(
            f"1 0.1 0.2 {3 + k} 255 0 0 0.5\n2 -0.1 0.0 {4 + k} 0 255 0 0.5\n"
        )
        if binary:
            rec = pycolmap.Reconstruction(str(sparse))
            for p in sparse.glob("*.txt"):
                p.unlink()
            rec.write_binary(str(sparse))
    return {"w2c": w2cs, "intr": intr, "size": size, "frames": frames}


def write_technicolor_raw(
    root: Path, scene: str = "Birthday", frames=(151, 153), cams: int = 12, size=(40, 24)
) -> dict:
    """The distributed layout: ``<Scene>_undist_<frame>_<cam>.png`` + ``cameras_parameters.txt``."""
    w2cs, intr = technicolor_cameras(cams, size)
    lines = ["f cu cv ar sk qw qx qy qz tx ty tz"]  # the undistorted set's header
    for c in range(cams):
        q = _rotmat_to_quat(w2cs[c][:3, :3].numpy().astype(np.float64))
        lines.append(" ".join(map(str, [*intr[c], 1.0, 0.0, *q, *w2cs[c][:3, 3].tolist()])))
        for frame in range(*frames):
            _save(pattern(c, frame, size), root / f"{scene}_undist_{frame:05d}_{c:02d}.png")
    (root / "cameras_parameters.txt").write_text("\n".join(lines) + "\n")
    return {"w2c": w2cs, "intr": intr, "size": size, "frames": frames}


# -- HyperNeRF ---------------------------------------------------------------------------------------------
def write_hypernerf(
    root: Path,
    steps: int = 5,
    full=(64, 40),
    factor: int = 2,
    center=(0.5, -0.2, 1.0),
    scale: float = 0.25,
    val: bool = True,
) -> dict:
    """A two-camera rig over ``steps`` time steps: left camera trains, right camera is ``val_ids``.

    Cameras are defined in the normalised frame (OpenCV); the files hold the un-normalised Nerfies
    values ``position = pos / scale + center``."""
    left, right = ring_w2c(2 * steps, radius=1.0)[::2], ring_w2c(2 * steps, radius=1.0)[1::2]
    ids, train_ids, val_ids, metadata, truth = [], [], [], {}, {}
    (root / "camera").mkdir(parents=True, exist_ok=True)
    for t in range(steps):
        for cam_id, w2c in ((0, left[t]), (1, right[t])):
            item = f"{cam_id}_{t:05d}"
            ids.append(item)
            (train_ids if cam_id == 0 else val_ids).append(item)
            metadata[item] = {"warp_id": t * 2, "appearance_id": t, "camera_id": cam_id, "time_id": t}
            R = w2c[:3, :3].double()
            pos = -R.T @ w2c[:3, 3].double()
            cj = {
                "orientation": R.tolist(),
                "position": (pos / scale + torch.tensor(center)).tolist(),
                "focal_length": 50.0,
                "principal_point": [full[0] / 2 + 3.0, full[1] / 2 - 2.0],
                "skew": 0.0,
                "pixel_aspect_ratio": 1.0,
                "radial_distortion": [0.01, -0.002, 0.0],
                "tangential_distortion": [0.0, 0.0],
                "image_size": list(full),
            }
            (root / "camera" / f"{item}.json").write_text(json.dumps(cj))
            small = (full[0] // factor, full[1] // factor)
            _save(pattern(cam_id, t, small), root / "rgb" / f"{factor}x" / f"{item}.png")
            truth[item] = w2c
    if not val:
        train_ids, val_ids = ids, []
    (root / "dataset.json").write_text(
        json.dumps(
            {
                "count": len(ids),
                "num_exemplars": len(train_ids),
                "ids": ids,
                "train_ids": train_ids,
                "val_ids": val_ids,
            }
        )
    )
    (root / "metadata.json").write_text(json.dumps(metadata))
    (root / "scene.json").write_text(
        json.dumps({"scale": scale, "center": list(center), "near": 0.1, "far": 3.0})
    )
    np.save(root / "points.npy", np.array([[0.5, -0.2, 1.0], [0.5 + 1 / scale, -0.2, 1.0]]))
    return {"w2c": truth, "full": full, "factor": factor, "steps": steps, "center": center, "scale": scale}
