"""Generate a synthetic scene folder in a native dataset layout (atomic, skipped when already there)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import time
import uuid
from collections.abc import Iterator
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from moegs.camera import Camera
from moegs.data.synthetic import writers as W
from moegs.data.synthetic.raycast import render
from moegs.data.synthetic.rigs import forward_facing_rig, orbit_cameras
from moegs.data.synthetic.scenes import SceneDescription, build_scene
from moegs.data.synthetic.spec import GENERATOR_VERSION, SyntheticSpec, get_spec, spec_hash
from moegs.io.video import VideoWriter, codec_settings, decode_video

META_FILE = "scene_meta.json"
GENERATOR = "moegs.data.synthetic"
DEPTH_CONVENTION = "z-depth along the camera's optical axis (OpenCV z), metres; 0 where no surface"


def frame_time(index: int, spec: SyntheticSpec) -> float:
    """Time of training frame ``index``.

    n3v: ``index / num_frames`` (the N3V ``frame/300`` convention); dnerf: ``linspace(0, 1)``.
    """
    if spec.layout == "n3v":
        return index / spec.num_frames
    return index / (spec.num_frames - 1)


def read_meta(folder: Path) -> dict | None:
    """``scene_meta.json`` of a generated folder, or None."""
    path = Path(folder) / META_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        return None


def is_generated(folder: Path, digest: str) -> bool:
    meta = read_meta(folder)
    return meta is not None and meta.get("spec_hash") == digest


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Temporarily set torch's intra-op threads (``None``: leave them)."""
    if n is None:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def generate(
    name: str,
    out_dir: str | Path,
    preset: str = "quick",
    seed: int = 0,
    *,
    progress: bool = True,
    num_threads: int | None = 1,
    device: str = "cpu",
    **overrides,
) -> Path:
    """Render the named synthetic scene and write it in its dataset layout into ``out_dir``.

    Skips the work when ``out_dir/scene_meta.json`` records the same spec hash (spec, seed and
    ``GENERATOR_VERSION``). Writes into a temporary sibling folder and renames it into place, so a
    reader never sees a half-written scene. ``overrides`` replace ``SyntheticSpec`` fields.
    ``num_threads``: torch threads while rendering; the ray caster issues many small vectorised ops for
    which one thread is faster than two (and far faster on a loaded machine, where OpenMP threads spin).
    ``device``: where rays are cast (e.g. ``"cuda"`` for the ``paper`` presets); outputs are identical
    up to float rounding, so the spec hash does not include it.

    Returns:
        ``out_dir``.
    """
    spec = get_spec(name, preset, **overrides)
    digest = spec_hash(spec, seed)
    out_dir = Path(out_dir)
    if is_generated(out_dir, digest):
        return out_dir
    if (
        out_dir.exists()
        and any(out_dir.iterdir())
        and (read_meta(out_dir) or {}).get("generator") != GENERATOR
    ):
        raise FileExistsError(
            f"generate: {out_dir} exists, is not empty and is not a generated synthetic scene; "
            "refusing to overwrite it"
        )
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.parent / f".{out_dir.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        t0 = time.perf_counter()
        desc = build_scene(spec.scene, seed)
        writer = _write_n3v if spec.layout == "n3v" else _write_dnerf
        with torch_threads(num_threads):
            info = writer(desc, spec, tmp, progress, device)
        meta = {
            "generator": GENERATOR,
            "version": GENERATOR_VERSION,
            "name": name,
            "preset": preset,
            "seed": int(seed),
            "spec": asdict(spec),
            "overrides": {k: v for k, v in overrides.items()},
            "spec_hash": digest,
            "stand_in_for": spec.stand_in_for,
            "layout": spec.layout,
            "objects": desc.table(),
            "dynamic_ids": desc.dynamic_ids(),
            "closed": desc.closed,
            "bbox": desc.bbox.tolist(),
            "abrupt": _abrupt_info(desc),
            "depth": DEPTH_CONVENTION,
            **info,
        }
        meta["timings"]["total_s"] = round(time.perf_counter() - t0, 3)
        (tmp / META_FILE).write_text(json.dumps(meta, indent=2, allow_nan=False))
        _install(tmp, out_dir, digest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out_dir


def _install(tmp: Path, out_dir: Path, digest: str) -> None:
    """Atomically move ``tmp`` to ``out_dir``, replacing an outdated generation."""
    old = None
    if out_dir.exists():
        if is_generated(out_dir, digest):  # a concurrent run finished first
            return
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        os.rename(out_dir, old)
    try:
        os.rename(tmp, out_dir)
    except OSError:
        if not is_generated(out_dir, digest):
            raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _abrupt_info(desc: SceneDescription) -> dict | None:
    for o in desc.objects:
        if o.category == "abrupt":
            path = o.position
            knots = getattr(path, "knots", None)
            if knots is not None:
                return {"object": o.name, "knots": list(knots[1:-1])}
    return None


def _gt_arrays(r, lut: torch.Tensor) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
    ids = r.ids.clamp(0, 255).cpu()
    return r.depth.to(torch.float32).cpu().numpy(), ids.to(torch.uint8).numpy(), lut[ids]


def _write_n3v(desc: SceneDescription, spec: SyntheticSpec, out: Path, progress: bool, device: str) -> dict:
    cams = forward_facing_rig(
        spec.num_cameras,
        desc.target,
        spec.width,
        spec.height,
        spec.hfov_deg,
        span=spec.rig_span,
        seed=desc.seed,
    )
    T = spec.num_frames
    lut = desc.id_to_dynamic()
    gt = out / "gt"
    bounds, roundtrip = [], []
    t_render = t_encode = 0.0
    frame0: list[np.ndarray] = []
    depth0: list[np.ndarray] = []
    bar = tqdm(
        total=len(cams) * T,
        desc=f"synthetic {spec.scene} ({spec.width}x{spec.height})",
        disable=not progress,
        unit="img",
    )
    for cam in cams:
        folder = gt / cam.name
        (folder / "mask").mkdir(parents=True)
        depth = np.zeros((T, spec.height, spec.width), np.float32)
        ids = np.zeros((T, spec.height, spec.width), np.uint8)
        frames = []
        with VideoWriter(out / f"{cam.name}.mp4", spec.width, spec.height, spec.fps, spec.codec) as vw:
            for i in range(T):
                t = frame_time(i, spec)
                s = time.perf_counter()
                r = render(desc.primitives(t), replace(cam, time=t, frame=i).to(device), t, spec.supersample)
                t_render += time.perf_counter() - s
                rgb = W.to_uint8(r.rgb)
                depth[i], ids[i], dyn = _gt_arrays(r, lut)
                W.save_mask(folder / "mask" / f"{i:04d}.png", dyn)
                s = time.perf_counter()
                vw.write(rgb)
                t_encode += time.perf_counter() - s
                frames.append(rgb)
                bar.update(1)
        np.save(folder / "depth.npy", depth)
        np.save(folder / "ids.npy", ids)
        hit = depth[depth > 0]
        bounds.append((float(hit.min()) * 0.9, float(hit.max()) * 1.1))
        decoded = decode_video(out / f"{cam.name}.mp4")
        if decoded.shape != (T, spec.height, spec.width, 3):
            raise RuntimeError(
                f"video round trip of {cam.name}: decoded {decoded.shape}, expected "
                f"{(T, spec.height, spec.width, 3)}"
            )
        roundtrip.append(W.psnr_uint8(np.stack(frames), decoded))
        frame0.append(frames[0])
        depth0.append(depth[0])
    bar.close()
    W.write_poses_bounds(out / "poses_bounds.npy", cams, bounds)

    points_info: dict = {"written": False}
    t_tri = 0.0
    if spec.triangulate:
        from moegs.data.points import TriangulationError, triangulate

        s = time.perf_counter()
        train = [i for i, c in enumerate(cams) if c.name != "cam00"]
        try:
            cloud = triangulate(
                [torch.from_numpy(frame0[i]).float() / 255.0 for i in train],
                [replace(cams[i], time=0.0, frame=0) for i in train],
            )
            W.write_ply(out / "points3D.ply", cloud.xyz, cloud.rgb)
            points_info = {
                "written": True,
                "file": "points3D.ply",
                "count": len(cloud),
                "source": cloud.source,
            }
        except TriangulationError as err:
            points_info = {"written": False, "error": str(err)}
        t_tri = time.perf_counter() - s

    dense_info: dict = {"written": False}
    if spec.dense_points:
        train = [i for i, c in enumerate(cams) if c.name != "cam00"]
        xyz, rgb, voxel = _dense_cloud(
            [cams[i] for i in train],
            [depth0[i] for i in train],
            [frame0[i] for i in train],
            spec.dense_points,
        )
        W.write_ply(out / DENSE_POINTS, xyz, rgb)
        dense_info = {"written": True, "file": DENSE_POINTS, "count": len(xyz), "voxel": voxel}

    finite = [p for p in roundtrip if math.isfinite(p)]
    codec_name, pix_fmt, _ = codec_settings(spec.codec)
    return {
        "cameras": [c.name for c in cams],
        "test_cameras": ["cam00"],
        "num_frames": T,
        "time_of_frame": "frame / num_frames",
        "frame_times": [frame_time(i, spec) for i in range(T)],
        "bounds": {c.name: list(b) for c, b in zip(cams, bounds, strict=True)},
        "video": {
            "codec": codec_name,
            "pix_fmt": pix_fmt,
            "fps": spec.fps,
            "roundtrip_exact": len(finite) == 0,
            "roundtrip_psnr_db_min": min(finite) if finite else None,
        },
        "points": points_info,
        "dense_points": dense_info,
        "gt_layout": {
            "depth": "gt/<cam>/depth.npy [T, H, W] float32",
            "ids": "gt/<cam>/ids.npy [T, H, W] uint8",
            "mask": "gt/<cam>/mask/<frame:04d>.png (255 = dynamic object)",
        },
        "timings": {
            "render_s": round(t_render, 3),
            "encode_s": round(t_encode, 3),
            "triangulate_s": round(t_tri, 3),
        },
    }


DENSE_POINTS = "points3D_downsample2.ply"
"""The name 4DGaussians gives its dense N3V cloud; the N3V loader prefers it to every other cloud."""


def _dense_cloud(
    cams: list[Camera], depths: list[np.ndarray], images: list[np.ndarray], max_points: int
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Frame 0 of ``cams`` back-projected with the ground-truth depth, voxel-downsampled with 2 cm cells
    growing by 1 cm until at most ``max_points`` remain (4DGaussians: COLMAP dense MVS of frame 0, then
    ``scripts/downsample_point.py``). Returns ``(xyz, rgb, voxel)``."""
    from moegs.data.points import backproject, voxel_downsample

    parts = [
        backproject(torch.from_numpy(d), c, torch.from_numpy(im).float() / 255.0)
        for c, d, im in zip(cams, depths, images, strict=True)
    ]
    xyz, rgb = torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
    voxel = 0.02
    down = voxel_downsample(xyz, rgb, voxel)
    while len(down[0]) > max_points:
        voxel += 0.01
        down = voxel_downsample(xyz, rgb, voxel)
    return down[0], down[1], round(voxel, 4)


def _held_out_times(n: int, seed: int) -> list[float]:
    """``n`` sorted times in (0, 1), one per stratum, jittered so they miss the training grid."""
    g = torch.Generator().manual_seed(seed)
    u = 0.2 + 0.6 * torch.rand(n, generator=g, dtype=torch.float64)
    return [float((j + u[j]) / n) for j in range(n)]


def _write_dnerf(desc: SceneDescription, spec: SyntheticSpec, out: Path, progress: bool, device: str) -> dict:
    hfov = math.radians(spec.hfov_deg)
    splits: dict[str, list[Camera]] = {
        "train": orbit_cameras(
            [frame_time(i, spec) for i in range(spec.num_frames)],
            desc.target,
            spec.orbit_radius,
            spec.width,
            spec.height,
            spec.hfov_deg,
            seed=desc.seed,
        ),
        "val": orbit_cameras(
            _held_out_times(spec.num_val, 31 + desc.seed),
            desc.target,
            spec.orbit_radius,
            spec.width,
            spec.height,
            spec.hfov_deg,
            seed=desc.seed + 1000,
        ),
        "test": orbit_cameras(
            _held_out_times(spec.num_test, 37 + desc.seed),
            desc.target,
            spec.orbit_radius,
            spec.width,
            spec.height,
            spec.hfov_deg,
            seed=desc.seed + 2000,
        ),
    }
    lut = desc.id_to_dynamic()
    t_render = 0.0
    total = sum(len(v) for v in splits.values())
    bar = tqdm(
        total=total,
        desc=f"synthetic {spec.scene} ({spec.width}x{spec.height})",
        disable=not progress,
        unit="img",
    )
    for split, cams in splits.items():
        (out / split).mkdir()
        (out / "gt" / split).mkdir(parents=True)
        for cam in cams:
            s = time.perf_counter()
            r = render(desc.primitives(cam.time), cam.to(device), cam.time, spec.supersample)
            t_render += time.perf_counter() - s
            rgba = np.concatenate([W.to_uint8(r.rgb), W.to_uint8(r.alpha)[..., None]], axis=-1)
            W.save_png(out / split / f"{cam.name}.png", rgba)
            depth, ids, dyn = _gt_arrays(r, lut)
            np.save(out / "gt" / split / f"{cam.name}_depth.npy", depth)
            W.save_png(out / "gt" / split / f"{cam.name}_ids.png", ids)
            W.save_mask(out / "gt" / split / f"{cam.name}_mask.png", dyn)
            bar.update(1)
        W.write_transforms(out / f"transforms_{split}.json", split, cams, hfov)
    bar.close()
    return {
        "splits": {k: len(v) for k, v in splits.items()},
        "test_split": "test",
        "num_frames": spec.num_frames,
        "time_of_frame": "train: linspace(0, 1, num_frames); val/test: held-out jittered times",
        "gt_layout": {
            "depth": "gt/<split>/r_XXX_depth.npy [H, W] float32",
            "ids": "gt/<split>/r_XXX_ids.png uint8",
            "mask": "gt/<split>/r_XXX_mask.png (255 = dynamic object)",
        },
        "background": "transparent (alpha 0); the loader composites on its background colour",
        "timings": {"render_s": round(t_render, 3)},
    }
