"""Initial point clouds: COLMAP triangulation with known poses, random fallbacks, kNN scales.

- ``triangulate``: SIFT + exhaustive matching + triangulation with the *known* cameras (pycolmap 4.x),
  for one static snapshot or for every time step merged (STG-style, per-point ``times``).
- ``random_in_box`` / ``random_in_frusta``: the random initialisations used when a dataset has no
  points (D-NeRF, HyperNeRF without COLMAP, ...). ``point_colors``: colours for them.
- ``knn_mean_distance`` / ``initial_scales``: the CPU replacement of the CUDA ``distCUDA2`` that 3DGS
  uses for initial scales.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.scene import PointCloud, View

__all__ = [
    "TriangulationError",
    "backproject",
    "voxel_downsample",
    "initial_scales",
    "knn_mean_distance",
    "point_colors",
    "random_colors",
    "random_in_box",
    "random_in_frusta",
    "triangulate",
]


class TriangulationError(RuntimeError):
    """Raised when COLMAP finds too few matches / points to build a cloud."""


# -- triangulation with known poses ------------------------------------------------------------------
@contextlib.contextmanager
def _quiet_colmap() -> Iterator[None]:
    """Silence COLMAP's glog INFO/WARNING output for the duration of the block."""
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2  # ERROR and above
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _to_uint8(image: Tensor) -> np.ndarray:
    img = image.detach().cpu().to(torch.float32)
    if img.ndim != 3 or img.shape[-1] not in (1, 3, 4):
        raise ValueError(f"triangulate: images must be [H, W, 3] float in [0, 1], got {list(img.shape)}")
    img = img[..., :3] if img.shape[-1] >= 3 else img.expand(*img.shape[:2], 3)
    return (img.clamp(0, 1) * 255.0).round().to(torch.uint8).numpy()


def _pinhole_params(cam: Camera) -> list[float]:
    if abs(float(cam.K[0, 1])) > 1e-9 * max(1.0, abs(cam.fx)):
        raise ValueError(
            f"triangulate: camera {cam.name!r} has a skewed K; COLMAP's PINHOLE model has no skew"
        )
    return [cam.fx, cam.fy, cam.cx, cam.cy]


def _triangulate_once(
    images: Sequence[Tensor],
    cameras: Sequence[Camera],
    workdir: Path,
    max_num_features: int,
    max_reproj_error: float,
    min_points: int,
    num_threads: int,
) -> tuple[Tensor, Tensor, dict]:
    """One static snapshot. Returns ``xyz [P, 3]``, ``rgb [P, 3]`` in [0, 1] and statistics."""
    import pycolmap
    from PIL import Image

    if len(images) != len(cameras):
        raise ValueError(f"triangulate: {len(images)} images but {len(cameras)} cameras")
    if len(images) < 2:
        raise ValueError(f"triangulate: need at least 2 views of the same instant, got {len(images)}")
    img_dir = workdir / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for i, (img, cam) in enumerate(zip(images, cameras, strict=True)):
        arr = _to_uint8(img)
        if arr.shape[:2] != (cam.height, cam.width):
            raise ValueError(
                f"triangulate: image {i} is {arr.shape[1]}x{arr.shape[0]} but camera "
                f"{cam.name!r} is {cam.width}x{cam.height}"
            )
        names.append(f"{i:05d}.png")
        Image.fromarray(arr).save(img_dir / names[-1])

    db_path = workdir / "database.db"
    pycolmap.Database.open(str(db_path)).close()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    pycolmap.import_images(
        db_path, img_dir, camera_mode=pycolmap.CameraMode.PER_IMAGE, image_names=names, options=reader
    )
    db = pycolmap.Database.open(str(db_path))
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        for name, cam in zip(names, cameras, strict=True):
            ccam = db.read_camera(by_name[name].camera_id)
            ccam.params = _pinhole_params(cam)
            ccam.has_prior_focal_length = True
            db.update_camera(ccam)
    finally:
        db.close()

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.sift.max_num_features = max_num_features
    pycolmap.extract_features(
        db_path,
        img_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.PER_IMAGE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    pycolmap.match_exhaustive(db_path, matching_options=matching, device=pycolmap.Device.cpu)

    db = pycolmap.Database.open(str(db_path))
    try:
        images_db = {im.image_id: im for im in db.read_all_images()}
        stats = {
            "views": len(names),
            "keypoints": [int(db.num_keypoints_for_image(i)) for i in images_db],
            "verified_pairs": int(db.num_verified_image_pairs()),
            "inlier_matches": int(db.num_inlier_matches()),
        }
        if stats["verified_pairs"] == 0:
            raise TriangulationError(
                f"triangulate: no geometrically verified image pairs among {len(names)} views "
                f"(keypoints per image: {stats['keypoints']}). The images are too small, textureless or "
                "do not overlap; use moegs.data.points.random_in_frusta / random_in_box instead."
            )
        rec = pycolmap.Reconstruction()
        for ccam in db.read_all_cameras():
            rec.add_camera(ccam)
        for rig in db.read_all_rigs():
            rec.add_rig(rig)
        frames = db.read_all_frames()
        for frame in frames:
            image_ids = [d.id for d in frame.data_ids]
            if len(image_ids) != 1:
                raise RuntimeError(f"triangulate: expected one image per COLMAP frame, got {len(image_ids)}")
            cam = cameras[names.index(images_db[image_ids[0]].name)]
            w2c = cam.world_to_camera.detach().cpu().to(torch.float64).numpy()
            frame.rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
            rec.add_frame(frame)
        for im in images_db.values():
            rec.add_image(im)
        for frame in frames:
            rec.register_frame(frame.frame_id)
    finally:
        db.close()

    out = workdir / "sparse"
    out.mkdir(exist_ok=True)
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    rec = pycolmap.triangulate_points(
        rec, db_path, img_dir, out, clear_points=True, options=options, refine_intrinsics=False
    )
    pts = [p for p in rec.points3D.values() if p.error <= max_reproj_error]
    stats["points_raw"] = int(rec.num_points3D())
    stats["points"] = len(pts)
    stats["mean_reprojection_error"] = float(np.mean([p.error for p in pts])) if pts else float("nan")
    if len(pts) < min_points:
        raise TriangulationError(
            f"triangulate: only {len(pts)} points (of {stats['points_raw']}) with reprojection error <= "
            f"{max_reproj_error} px from {len(names)} views ({stats['verified_pairs']} verified pairs, "
            f"{stats['inlier_matches']} inlier matches, keypoints per image {stats['keypoints']}); "
            f"need {min_points}. Use random_in_frusta / random_in_box instead."
        )
    xyz = torch.tensor(np.stack([p.xyz for p in pts]), dtype=torch.float32)
    rgb = torch.tensor(np.stack([p.color for p in pts]), dtype=torch.float32) / 255.0
    return xyz, rgb, stats


def triangulate(
    views: Sequence[View] | Sequence[Tensor],
    cameras: Sequence[Camera] | None = None,
    *,
    frames: str | int = "one",
    max_num_features: int = 8192,
    max_reproj_error: float = 2.0,
    min_points: int = 10,
    num_threads: int = 2,
    workdir: str | Path | None = None,
) -> PointCloud:
    """Triangulate SIFT matches with KNOWN poses (pycolmap), like the COLMAP step of the N3V pipelines.

    Args:
        views: ``View`` objects (images and cameras read from them), or images ``[H, W, 3]`` float in
            [0, 1] together with ``cameras``.
        cameras: one ``Camera`` per image when ``views`` are images.
        frames: ``"one"``: every given view is one static snapshot (pass the views of a single time,
            e.g. ``[v for v in scene.train if v.camera.frame == 0]``); ``"all"``: the views are grouped
            by ``camera.time``, each group (>= 2 views) is triangulated on its own and the clouds are
            merged with per-point ``times`` (STG-style); groups that fail are skipped; an ``int``:
            only the views whose ``camera.frame`` equals it (images of other frames are never loaded).
        max_num_features: SIFT features per image.
        max_reproj_error: points with a larger mean reprojection error (pixels) are dropped.
        min_points: fewer points raise ``TriangulationError`` (per group for ``frames="one"``; overall
            for ``"all"``).
        workdir: keep the COLMAP database/images/model there (default: a temporary folder, deleted).
    Returns:
        ``PointCloud`` with ``xyz [P, 3]``, ``rgb [P, 3]`` (COLMAP's colours) and ``times [P]`` for ``"all"``.
    """
    if isinstance(frames, bool) or not (isinstance(frames, int) or frames in ("one", "all")):
        raise ValueError(f"triangulate: frames must be 'one', 'all' or a frame index, got {frames!r}")
    is_views = bool(views) and isinstance(views[0], View)
    if is_views and cameras is not None:
        raise ValueError("triangulate: pass either views, or images together with cameras, not both")
    if not is_views and cameras is None:
        raise ValueError("triangulate: images need their cameras (cameras=[...])")
    items = list(views)
    cams = [v.camera for v in items] if is_views else list(cameras)  # type: ignore[union-attr,arg-type]
    if len(items) != len(cams):
        raise ValueError(f"triangulate: {len(items)} images but {len(cams)} cameras")
    if isinstance(frames, int):  # select one frame index before decoding any image
        keep = [i for i, c in enumerate(cams) if c.frame == frames]
        if not keep:
            raise ValueError(
                f"triangulate: no view has frame {frames}; frames present: "
                f"{sorted({c.frame for c in cams})[:20]}"
            )
        items, cams, frames = [items[i] for i in keep], [cams[i] for i in keep], "one"
    if frames == "one" and len({c.time for c in cams}) > 1:
        raise ValueError(
            f"triangulate(frames='one'): the views span {len({c.time for c in cams})} different "
            "times; pass the views of one instant, a frame index (frames=0) or frames='all'"
        )
    images = [v.image() for v in items] if is_views else items  # type: ignore[union-attr]

    if frames == "one":
        groups = {cams[0].time: list(range(len(cams)))} if cams else {}
    else:
        groups = {}
        for i, c in enumerate(cams):
            groups.setdefault(c.time, []).append(i)
        groups = {t: idx for t, idx in sorted(groups.items()) if len(idx) >= 2}
        if not groups:
            raise ValueError(
                "triangulate(frames='all'): no time step is seen by 2 or more views "
                "(monocular data cannot be triangulated per frame)"
            )

    base = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="moegs-colmap-"))
    xyz_all, rgb_all, t_all, errors, used = [], [], [], [], 0
    try:
        with _quiet_colmap():
            for gi, (t, idx) in enumerate(groups.items()):
                wd = base / f"group_{gi:04d}"
                if wd.exists():
                    shutil.rmtree(wd)
                wd.mkdir(parents=True)
                try:
                    xyz, rgb, stats = _triangulate_once(
                        [images[i] for i in idx],
                        [cams[i] for i in idx],
                        wd,
                        max_num_features,
                        max_reproj_error,
                        min_points if frames == "one" else 1,
                        num_threads,
                    )
                except TriangulationError as err:
                    if frames == "one":
                        raise
                    errors.append(f"t={t:g}: {err}")
                    continue
                used += 1
                xyz_all.append(xyz)
                rgb_all.append(rgb)
                t_all.append(torch.full((xyz.shape[0],), float(t)))
    finally:
        if workdir is None:
            shutil.rmtree(base, ignore_errors=True)
    if not xyz_all or sum(x.shape[0] for x in xyz_all) < min_points:
        n = sum(x.shape[0] for x in xyz_all)
        raise TriangulationError(
            f"triangulate(frames='all'): {n} points from {used}/{len(groups)} time steps "
            f"(need {min_points}); failures: {errors[:3]}"
        )
    xyz, rgb = torch.cat(xyz_all), torch.cat(rgb_all)
    if frames == "one":
        return PointCloud(
            xyz=xyz,
            rgb=rgb,
            source=f"pycolmap triangulation, {len(cams)} known views, "
            f"{xyz.shape[0]} points ({stats['mean_reprojection_error']:.2f} px)",
        )
    return PointCloud(
        xyz=xyz,
        rgb=rgb,
        times=torch.cat(t_all),
        source=f"pycolmap triangulation per time step, {used}/{len(groups)} steps merged, "
        f"{xyz.shape[0]} points",
    )


# -- random fallbacks --------------------------------------------------------------------------------
def backproject(depth: Tensor, camera: Camera, image: Tensor) -> tuple[Tensor, Tensor]:
    """World points and colours of the pixels of ``depth [H, W]`` (camera z, 0 = no surface) seen by
    ``camera`` with colours ``image [H, W, 3]``: ``([P, 3], [P, 3])``, pixel centres."""
    h, w = depth.shape
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    hit = depth > 0
    z = depth[hit].to(torch.float64)
    k = camera.K.to(torch.float64)
    x = (cols[hit] + 0.5 - k[0, 2]) / k[0, 0] * z
    y = (rows[hit] + 0.5 - k[1, 2]) / k[1, 1] * z
    c2w = torch.linalg.inv(camera.world_to_camera.to(torch.float64))
    xyz = torch.stack([x, y, z], -1) @ c2w[:3, :3].T + c2w[:3, 3]
    return xyz.to(torch.float32), image[hit].to(torch.float32)


def voxel_downsample(xyz: Tensor, rgb: Tensor, voxel: float) -> tuple[Tensor, Tensor]:
    """One point per occupied ``voxel``-sized cell: the mean position and colour of its points
    (Open3D ``voxel_down_sample``, which 4DGaussians' ``scripts/downsample_point.py`` uses)."""
    cells = torch.floor(xyz.to(torch.float64) / voxel).to(torch.int64)
    _, inverse, counts = torch.unique(cells, dim=0, return_inverse=True, return_counts=True)
    sums = torch.zeros(len(counts), 6, dtype=torch.float64).index_add_(
        0, inverse, torch.cat([xyz, rgb], 1).double()
    )
    means = (sums / counts[:, None]).to(torch.float32)
    return means[:, :3], means[:, 3:]


def random_in_box(bbox: Tensor, n: int, seed: int = 0) -> Tensor:
    """``n`` points uniform in the axis-aligned box ``bbox [2, 3]`` (min, max) -> ``[n, 3]`` float32."""
    bbox = torch.as_tensor(bbox, dtype=torch.float32)
    if tuple(bbox.shape) != (2, 3):
        raise ValueError(f"random_in_box: bbox must have shape [2, 3] (min, max), got {list(bbox.shape)}")
    if (bbox[1] < bbox[0]).any():
        raise ValueError(f"random_in_box: bbox max {bbox[1].tolist()} < min {bbox[0].tolist()}")
    if n < 0:
        raise ValueError(f"random_in_box: n must be >= 0, got {n}")
    g = torch.Generator().manual_seed(int(seed))
    return bbox[0] + torch.rand(n, 3, generator=g) * (bbox[1] - bbox[0])


def _frustum_sample(cam: Camera, n: int, near: float, far: float, g: torch.Generator) -> Tensor:
    """``n`` points uniform in volume in one camera's frustum between z = near and z = far, ``[n, 3]``."""
    u = torch.rand(n, 3, generator=g, dtype=torch.float64)
    # uniform in volume: p(z) ~ z^2 -> inverse CDF of z^3
    z = (near**3 + u[:, 2] * (far**3 - near**3)) ** (1.0 / 3.0)
    px = u[:, 0] * cam.width
    py = u[:, 1] * cam.height
    K = cam.K.to(torch.float64)
    y = (py - K[1, 2]) / K[1, 1]
    x = (px - K[0, 2] - K[0, 1] * y) / K[0, 0]
    pc = torch.stack([x * z, y * z, z], dim=-1)
    w2c = cam.world_to_camera.to(torch.float64)
    R, t = w2c[:3, :3], w2c[:3, 3]
    return (pc - t) @ R  # R^T (p - t)


def _in_frustum(xyz: Tensor, cam: Camera, near: float, far: float) -> Tensor:
    w2c = cam.world_to_camera.to(xyz.dtype)
    pc = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    uv = pc @ cam.K.to(xyz.dtype).T
    zs = z.clamp_min(1e-12)
    u, v = uv[:, 0] / zs, uv[:, 1] / zs
    return (z >= near) & (z <= far) & (u >= 0) & (u <= cam.width) & (v >= 0) & (v <= cam.height)


def random_in_frusta(
    cameras: Sequence[Camera],
    n: int,
    near: float,
    far: float,
    seed: int = 0,
    mode: str = "any",
    max_rounds: int = 200,
) -> Tensor:
    """``n`` random points in the cameras' view frusta between depths ``near`` and ``far`` -> ``[n, 3]``.

    ``mode="any"`` (the union, every point is seen by at least one camera): a camera is drawn with
    probability proportional to its frustum volume and the point is uniform in that frustum's volume
    (so regions seen by several cameras are proportionally denser). ``mode="all"`` (the intersection,
    every point is seen by all cameras between near and far): rejection sampling from the union;
    raises ``ValueError`` when the intersection is empty or too small to fill in ``max_rounds``.
    """
    cams = list(cameras)
    if not cams:
        raise ValueError("random_in_frusta: no cameras")
    if not 0 < near < far:
        raise ValueError(f"random_in_frusta: need 0 < near < far, got near={near}, far={far}")
    if mode not in ("any", "all"):
        raise ValueError(f"random_in_frusta: mode must be 'any' or 'all', got {mode!r}")
    if n < 0:
        raise ValueError(f"random_in_frusta: n must be >= 0, got {n}")
    g = torch.Generator().manual_seed(int(seed))
    vol = torch.tensor([c.width * c.height / (c.fx * c.fy) for c in cams], dtype=torch.float64)

    def draw(m: int) -> Tensor:
        which = torch.multinomial(vol / vol.sum(), m, replacement=True, generator=g) if m else torch.zeros(0)
        out = torch.empty(m, 3, dtype=torch.float64)
        for k, cam in enumerate(cams):
            sel = (which == k).nonzero(as_tuple=True)[0]
            if sel.numel():
                out[sel] = _frustum_sample(cam, sel.numel(), near, far, g)
        return out

    if mode == "any":
        return draw(n).to(torch.float32)
    kept: list[Tensor] = []
    have = 0
    for _ in range(max_rounds):
        if have >= n:
            break
        cand = draw(max(4 * (n - have), 1024))
        ok = torch.ones(cand.shape[0], dtype=torch.bool)
        for cam in cams:
            ok &= _in_frustum(cand, cam, near, far)
        kept.append(cand[ok])
        have += int(ok.sum())
    if have < n:
        raise ValueError(
            f"random_in_frusta(mode='all'): the {len(cams)} frusta between {near} and {far} barely "
            f"intersect (found {have} of {n} points); use mode='any' or a wider depth range"
        )
    return torch.cat(kept)[:n].to(torch.float32)


def random_colors(n: int, seed: int = 0) -> Tensor:
    """``[n, 3]`` uniform random colours in [0, 1]."""
    g = torch.Generator().manual_seed(int(seed) + 1)
    return torch.rand(n, 3, generator=g)


def point_colors(
    xyz: Tensor, views: Sequence[View] | None = None, seed: int = 0, default: Tensor | None = None
) -> Tensor:
    """Colours ``[P, 3]`` of points ``xyz [P, 3]``.

    Without ``views``: random colours (``random_colors``). With views: the mean of the nearest-pixel
    colours over every view in whose image the point projects (in front of the camera); occlusion is
    not tested. Points seen by no view get ``default`` (random colours if None).
    """
    xyz = torch.as_tensor(xyz, dtype=torch.float32)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"point_colors: xyz must be [P, 3], got {list(xyz.shape)}")
    fallback = (
        random_colors(xyz.shape[0], seed) if default is None else default.expand(xyz.shape[0], 3).clone()
    )
    if not views:
        return fallback
    acc = torch.zeros(xyz.shape[0], 3)
    cnt = torch.zeros(xyz.shape[0])
    for view in views:
        cam = view.camera
        img = view.image().to(torch.float32)
        pc = xyz @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        uv = pc @ cam.K.T
        z = pc[:, 2].clamp_min(1e-12)
        u, v = uv[:, 0] / z, uv[:, 1] / z
        ok = (pc[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        idx = ok.nonzero(as_tuple=True)[0]
        if idx.numel() == 0:
            continue
        ui = u[idx].floor().long().clamp(0, cam.width - 1)
        vi = v[idx].floor().long().clamp(0, cam.height - 1)
        acc[idx] += img[vi, ui, :3]
        cnt[idx] += 1
    seen = cnt > 0
    out = fallback
    out[seen] = acc[seen] / cnt[seen, None]
    return out


# -- nearest-neighbour scales ------------------------------------------------------------------------
def knn_torch(points: Tensor, k: int, first: int = 0, max_elements: int = 1 << 24) -> tuple[Tensor, Tensor]:
    """Squared distances (ascending) and indices ``[P - first, k]`` of the ``k`` nearest other points of
    the points ``first..P-1`` of ``points [P, D]``, by exact sums of squared differences over all the points
    (blocks of at most ``max_elements`` differences), on their device."""
    P, D = points.shape
    rows = max(1, max_elements // max(P * D, 1))
    dist = torch.empty(P - first, k, dtype=points.dtype, device=points.device)
    index = torch.empty(P - first, k, dtype=torch.long, device=points.device)
    for s in range(first, P, rows):
        e = min(P, s + rows)
        d2 = (points[s:e, None, :] - points[None, :, :]).square().sum(-1)  # exact squares: no sqrt
        d2[torch.arange(e - s, device=points.device), torch.arange(s, e, device=points.device)] = float("inf")
        dist[s - first : e - first], index[s - first : e - first] = d2.topk(k, dim=1, largest=False)
    return dist, index


def _knn_kdtree(points: Tensor, k: int, first: int = 0) -> Tensor:
    from scipy.spatial import cKDTree

    p = points.detach().cpu().to(torch.float64).numpy()
    d, _ = cKDTree(p).query(p[first:], k=k + 1)
    d = np.asarray(d).reshape(p.shape[0] - first, k + 1)[:, 1:]  # drop one zero (the point itself)
    return torch.from_numpy(d**2).to(points.dtype)


def knn_mean_distance(
    points: Tensor,
    k: int = 3,
    *,
    squared: bool = False,
    method: str = "auto",
    max_elements: int = 1 << 24,
    last: int | None = None,
) -> Tensor:
    """Mean distance of every point to its ``k`` nearest OTHER points.

    Args:
        points: ``[P, 3]`` (any dimension D works: ``[P, D]``).
        k: neighbours (the point itself is excluded by index; exact duplicates count as distance 0).
            With fewer than ``k + 1`` points, all other points are used.
        squared: False -> mean of the Euclidean distances; True -> mean of the SQUARED distances,
            which is exactly what the CUDA ``distCUDA2`` of 3DGS returns.
        method: ``"torch"`` (exact, chunked sums of squared differences, any device), ``"kdtree"``
            (exact, scipy ``cKDTree`` on CPU, much faster for large P) or ``"auto"`` (kdtree on CPU when
            scipy is importable and P > 4096, else torch).
        max_elements: size of one block of coordinate differences for the torch path (memory bound).
        last: only the last ``last`` points' distances (to all the points; the same values as the full
            answer's last rows); None: every point's.
    Returns:
        ``[P]`` (``[last]``) with the dtype and device of ``points``; zeros when ``P < 2``.
    """
    if points.ndim != 2:
        raise ValueError(f"knn_mean_distance: points must be [P, D], got {list(points.shape)}")
    if k < 1:
        raise ValueError(f"knn_mean_distance: k must be >= 1, got {k}")
    if method not in ("auto", "torch", "kdtree"):
        raise ValueError(f"knn_mean_distance: method must be 'auto', 'torch' or 'kdtree', got {method!r}")
    P = points.shape[0]
    first = P - min(P, last) if last is not None else 0
    if P < 2:
        return torch.zeros(P - first, dtype=points.dtype, device=points.device)
    k_eff = min(k, P - 1)
    if method == "auto":
        method = "torch"
        if points.device.type == "cpu" and P > 4096:
            try:
                import scipy.spatial  # noqa: F401

                method = "kdtree"
            except ImportError:
                pass
    if method == "kdtree":
        d2 = _knn_kdtree(points, k_eff, first).to(points.device)
    else:
        d2 = knn_torch(points, k_eff, first, max_elements)[0]
    return d2.mean(1) if squared else d2.sqrt().mean(1)


def initial_scales(points: Tensor, k: int = 3, min_sq_dist: float = 1e-7) -> Tensor:
    """3DGS initial log-scales ``[P, 3]``.

    ``scale = sqrt(clamp(mean squared distance to the 3 nearest neighbours, min=1e-7))`` (``distCUDA2``),
    ``log(scale)`` repeated on the three axes (3DGS ``create_from_pcd``). Computed in float64, the
    logarithm by numpy: every process gets the same bits (torch's first parallel ``sqrt`` or ``log`` in a
    fresh process can differ, see ``moegs.threads``).
    """
    d2 = knn_mean_distance(points.detach().to(torch.float64), k, squared=True).cpu().numpy()
    log_scale = 0.5 * np.log(np.maximum(d2, min_sq_dist))  # log(sqrt(d2))
    return torch.from_numpy(log_scale).to(points.dtype).to(points.device)[:, None].repeat(1, 3)
