"""Synthetic benchmark scenes: ray caster, scene content, determinism, layouts, loaders, ground truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from moegs.camera import Camera, intrinsics, look_at
from moegs.data.synthetic import (
    CATEGORIES,
    build_scene,
    generate,
    get_spec,
    ground_truth,
    load_ground_truth,
    load_synthetic,
    render_ground_truth,
)
from moegs.data.synthetic.generate import _held_out_times, frame_time, torch_threads
from moegs.data.synthetic.raycast import Primitive, camera_rays, cast, render
from moegs.data.synthetic.rigs import forward_facing_rig, orbit_cameras
from moegs.data.synthetic.textures import Texture
from moegs.data.synthetic.writers import psnr_uint8
from moegs.io.video import VideoWriter, decode_video

N3V_SMALL = {"width": 64, "height": 48, "num_frames": 6, "num_cameras": 4, "triangulate": False}
DNERF_SMALL = {"width": 48, "height": 48, "num_frames": 6, "num_val": 2, "num_test": 2}
FLAT = Texture("checker", ((0.2, 0.2, 0.2), (0.8, 0.8, 0.8)), noise_amp=0.0)


@pytest.fixture(autouse=True)
def _one_thread():
    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def n3v_dir(tmp_path_factory):
    return generate("n3v_like", tmp_path_factory.mktemp("syn") / "n3v", progress=False, **N3V_SMALL)


@pytest.fixture(scope="module")
def dnerf_dir(tmp_path_factory):
    return generate("dnerf_like", tmp_path_factory.mktemp("syn") / "dnerf", progress=False, **DNERF_SMALL)


def _axis_camera(w=64, h=64, f=100.0) -> Camera:
    """Camera at the origin looking along +z (OpenCV), principal point at the centre."""
    return Camera(K=intrinsics(f, f, w / 2, h / 2), world_to_camera=torch.eye(4), width=w, height=h)


# -- ray caster: hand-checked cases --------------------------------------------------------------------
def test_sphere_depth_and_footprint():
    cam = _axis_camera()
    c, r = torch.tensor([0.0, 0.0, 5.0]), 1.0
    out = render([Primitive("ellipsoid", c, torch.eye(3), torch.full((3,), r), FLAT, 1)], cam, 0.0)
    # analytic: ray d = (x, y, 1) through pixel centres, |t d - c|^2 = r^2, t is the z-depth
    _, d = camera_rays(cam)
    d = d[0].to(torch.float64)
    dc = d @ c.double()
    dd = (d * d).sum(-1)
    disc = dc**2 - dd * (c.double() @ c.double() - r * r)
    hit = disc >= 0
    t = (dc - disc.clamp(min=0).sqrt()) / dd
    assert torch.equal(out.ids > 0, hit)
    assert torch.allclose(out.depth[hit].double(), t[hit], atol=1e-5)
    assert (out.depth[~hit] == 0).all() and (out.alpha[~hit] == 0).all()
    # the centre-most pixels see the sphere's front at depth ~ 4
    assert abs(float(out.depth[32, 32]) - 4.0) < 1e-3
    # footprint: silhouette radius f r / sqrt(z^2 - r^2) = 20.41 px -> area ~ 1309 px
    area = math.pi * (100.0 * r / math.sqrt(25.0 - r * r)) ** 2
    assert abs(int(hit.sum()) - area) / area < 0.02


def test_box_head_on_and_room_from_inside():
    cam = _axis_camera()
    box = Primitive("box", torch.tensor([0.0, 0.0, 5.0]), torch.eye(3), torch.ones(3), FLAT, 2)
    out = render([box], cam, 0.0)
    # front face z = 4 spans |x| <= 1 -> pixels 32 +- 25: exactly a 50 x 50 square at depth 4
    assert int((out.ids == 2).sum()) == 50 * 50
    assert torch.allclose(out.depth[out.ids == 2], torch.tensor(4.0))
    assert torch.allclose(out.normal[out.ids == 2], torch.tensor([0.0, 0.0, -1.0]), atol=1e-6)
    room = Primitive("room", torch.zeros(3), torch.eye(3), torch.full((3,), 3.0), FLAT, 1)
    out = render([room, box], cam, 0.0)
    assert (out.ids > 0).all()  # a closed room: every ray hits
    assert torch.allclose(
        out.depth[out.ids == 1].min(), torch.tensor(3.0)
    )  # back wall z = 3 (in front of box)
    assert (out.ids == 2).sum() == 0  # the box at z = 4..6 lies behind the wall at z = 3


def test_rotated_box_and_ellipsoid_normals_point_to_camera():
    cam = Camera(
        K=intrinsics(60.0, 60.0, 32, 24),
        world_to_camera=look_at(torch.tensor([3.0, -4.0, 2.0]), torch.zeros(3)),
        width=64,
        height=48,
    )
    from moegs.data.synthetic.scenes import rot_x, rot_z

    prims = [
        Primitive(
            "box",
            torch.tensor([0.5, 0.0, 0.0]),
            rot_z(0.7) @ rot_x(0.3),
            torch.tensor([0.4, 0.3, 0.2]),
            FLAT,
            1,
        ),
        Primitive(
            "ellipsoid", torch.tensor([-0.6, 0.3, 0.1]), rot_z(-0.4), torch.tensor([0.5, 0.2, 0.3]), FLAT, 2
        ),
    ]
    out = render(prims, cam, 0.0)
    o, d = camera_rays(cam)
    hit = out.ids > 0
    assert (out.ids == 1).sum() > 20 and (out.ids == 2).sum() > 20
    # shading normals face the camera (front faces only)
    assert ((out.normal[hit] * d[0][hit]).sum(-1) < 0).all()
    # hit points lie on the surfaces (z-depth times the z=1 ray direction)
    X = o[0] + out.depth[..., None] * d[0]
    for k, p in enumerate(prims, start=1):
        local = (X[out.ids == k] - p.center) @ p.rotation
        if p.kind == "box":
            on = (local.abs() / p.size).max(-1).values
        else:
            on = ((local / p.size) ** 2).sum(-1)
        assert torch.allclose(on, torch.ones_like(on), atol=1e-4)


# -- scene content -------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["n3v_like", "dnerf_like"])
def test_scene_has_every_motion_regime(name):
    desc = build_scene(name, seed=0)
    cats = {o.category for o in desc.objects}
    assert cats == set(CATEGORIES)
    assert desc.object("room" if name == "n3v_like" else "pedestal").category == "static"
    # abrupt: the velocity direction turns by more than 60 degrees at every interior knot, on a path
    # without a jump (a teleport is not a motion any deformation model can follow)
    hopper = desc.object("hopper")
    path = hopper.position
    for k in path.knots[1:-1]:
        v0, v1 = hopper.velocity(k - 1e-3), hopper.velocity(k + 1e-3)
        cos = float(v0 @ v1 / (v0.norm() * v1.norm()))
        assert cos < 0.5, f"no sharp turn at t={k}"
        assert float((path(k + 1e-6) - path(k - 1e-6)).norm()) < 1e-4, f"jump at t={k}"
    # smooth rigid: velocity changes little over any small step (no discontinuity)
    cube = desc.object("cube")
    ts = torch.linspace(0.01, 0.98, 60).tolist()
    dv = max(float((cube.velocity(t + 0.01) - cube.velocity(t)).norm()) for t in ts)
    assert dv < 0.05
    # articulated: the hand moves faster than the sliding cube
    speed = lambda o: np.mean([float(o.velocity(t).norm()) for t in ts])  # noqa: E731
    assert speed(desc.object("arm")) > 1.5 * speed(cube)
    # non-rigid: the blob changes shape
    axes = [desc.object("blob").parts(t)[0].size for t in (0.0, 1 / 16, 3 / 16)]
    assert not torch.allclose(axes[0], axes[1]) and not torch.allclose(axes[1], axes[2])
    # transient: present in a window only
    ghost = desc.object("ghost")
    assert not ghost.visible(0.1) and ghost.visible(0.5) and not ghost.visible(0.9)
    # appearance: the lamp's palette turns while its geometry stays put
    lamp = desc.object("lamp")
    p0, p1 = lamp.parts(0.0)[0], lamp.parts(0.3)[0]
    assert torch.equal(p0.center, p1.center)
    assert not torch.allclose(p0.texture.palette(0.0), p1.texture.palette(0.3), atol=0.05)


def test_gt_shows_dynamic_transient_and_appearance(n3v_dir):
    meta = json.loads((n3v_dir / "scene_meta.json").read_text())
    ids = {o["name"]: o["id"] for o in meta["objects"]}
    stack = np.load(n3v_dir / "gt" / "cam00" / "ids.npy")  # [T, H, W]
    T = stack.shape[0]
    present = [(stack[i] == ids["ghost"]).any() for i in range(T)]
    times = [frame_time(i, get_spec("n3v_like", **N3V_SMALL)) for i in range(T)]
    assert present == [0.3 <= t < 0.7 for t in times] and any(present) and not all(present)
    masks = [np.asarray(Image.open(n3v_dir / "gt" / "cam00" / "mask" / f"{i:04d}.png")) for i in range(T)]
    for i in range(T):
        dyn = np.isin(stack[i], meta["dynamic_ids"])
        assert np.array_equal(masks[i] > 0, dyn)
        assert 0.01 < dyn.mean() < 0.6  # moving pixels exist, background dominates
    # the dynamic mask moves over time
    assert not np.array_equal(masks[0], masks[2])
    # appearance change: lamp pixels change colour although the lamp does not move
    frames = decode_video(n3v_dir / "cam00.mp4")
    lamp = (stack[0] == ids["lamp"]) & (stack[3] == ids["lamp"])
    assert lamp.sum() > 5
    assert np.abs(frames[0][lamp].astype(float).mean(0) - frames[3][lamp].astype(float).mean(0)).max() > 20


def test_depth_consistency_between_cameras(n3v_dir):
    """Back-project cam A's GT depth; the ray from cam B towards each point first hits it (or an occluder)."""
    desc = build_scene("n3v_like", 0)
    spec = get_spec("n3v_like", **N3V_SMALL)
    cams = forward_facing_rig(spec.num_cameras, desc.target, spec.width, spec.height, spec.hfov_deg, seed=0)
    a, b = cams[1], cams[2]
    frame = 2
    t = frame_time(frame, spec)
    gt_a = load_ground_truth(n3v_dir, f"{a.name}/{frame:04d}")
    _, d = camera_rays(a)
    X = a.center + gt_a.depth[..., None] * d[0]  # [H, W, 3] world points
    X = X[gt_a.ids > 0].reshape(-1, 3)
    ids_a = gt_a.ids[gt_a.ids > 0].reshape(-1)
    pb = X @ b.world_to_camera[:3, :3].T + b.world_to_camera[:3, 3]
    z_b = pb[:, 2]
    uv = pb @ b.K.T
    u, v = uv[:, 0] / z_b, uv[:, 1] / z_b
    inside = (z_b > 0) & (u >= 0) & (u < b.width) & (v >= 0) & (v < b.height)
    hits = cast(
        desc.primitives(t), b.center.expand(int(inside.sum()), 3), (X[inside] - b.center) / z_b[inside, None]
    )
    assert (hits.t <= z_b[inside] * (1 + 1e-4) + 1e-4).all()  # nothing lies behind a surface point
    same = (hits.t - z_b[inside]).abs() < 1e-3 * z_b[inside]
    assert same.float().mean() > 0.8  # most points are visible from B: the same 3D point
    assert torch.equal(hits.ids[same], ids_a[inside][same])
    # the GT files of B agree with the analytic caster at B's pixel centres
    gt_b = load_ground_truth(n3v_dir, f"{b.name}/{frame:04d}")
    r = render(desc.primitives(t), b, t)
    assert torch.allclose(gt_b.depth, r.depth) and torch.equal(gt_b.ids, r.ids)


# -- determinism -------------------------------------------------------------------------------------
def test_generation_is_deterministic(tmp_path):
    small = {"width": 32, "height": 24, "num_frames": 3, "num_cameras": 3, "triangulate": False}
    p1 = generate("n3v_like", tmp_path / "a", progress=False, **small)
    p2 = generate("n3v_like", tmp_path / "b", progress=False, **small)
    for rel in ["poses_bounds.npy", "gt/cam01/depth.npy", "gt/cam01/ids.npy", "gt/cam02/mask/0002.png"]:
        assert (p1 / rel).read_bytes() == (p2 / rel).read_bytes(), rel
    assert np.array_equal(decode_video(p1 / "cam01.mp4"), decode_video(p2 / "cam01.mp4"))
    m1, m2 = (json.loads((p / "scene_meta.json").read_text()) for p in (p1, p2))
    assert m1["spec_hash"] == m2["spec_hash"] and m1["objects"] == m2["objects"]
    # another seed changes textures and the abrupt path
    p3 = generate("n3v_like", tmp_path / "c", seed=1, progress=False, **small)
    m3 = json.loads((p3 / "scene_meta.json").read_text())
    assert m3["abrupt"]["knots"] != m1["abrupt"]["knots"]
    assert not np.array_equal(decode_video(p1 / "cam01.mp4"), decode_video(p3 / "cam01.mp4"))


def test_render_is_deterministic():
    desc = build_scene("dnerf_like", 3)
    cam = Camera(
        K=intrinsics(50.0, 50.0, 20, 20),
        world_to_camera=look_at(torch.tensor([3.0, 2.0, 2.0]), desc.target),
        width=40,
        height=40,
    )
    r1 = render(build_scene("dnerf_like", 3).primitives(0.4), cam, 0.4, supersample=2)
    r2 = render(desc.primitives(0.4), cam, 0.4, supersample=2)
    assert torch.equal(r1.rgb, r2.rgb) and torch.equal(r1.depth, r2.depth) and torch.equal(r1.ids, r2.ids)


def test_generate_skips_and_replaces_atomically(tmp_path):
    small = {"width": 24, "height": 24, "num_frames": 2, "num_val": 1, "num_test": 1}
    out = tmp_path / "scene"
    generate("dnerf_like", out, progress=False, **small)
    stamp = (out / "scene_meta.json").stat().st_mtime_ns
    generate("dnerf_like", out, progress=False, **small)  # identical spec: skipped
    assert (out / "scene_meta.json").stat().st_mtime_ns == stamp
    generate("dnerf_like", out, progress=False, **{**small, "num_frames": 3})  # new spec: replaced
    meta = json.loads((out / "scene_meta.json").read_text())
    assert meta["spec"]["num_frames"] == 3 and len(list((out / "train").iterdir())) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]  # no temporary folders left
    other = tmp_path / "user_data"
    other.mkdir()
    (other / "keep.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not a generated synthetic scene"):
        generate("dnerf_like", other, progress=False, **small)


def test_clear_errors():
    with pytest.raises(KeyError, match="valid: \\['dnerf_like', 'n3v_like'\\]"):
        get_spec("nope")
    with pytest.raises(KeyError, match="valid: \\['paper', 'quick'\\]"):
        get_spec("n3v_like", "huge")
    with pytest.raises(TypeError, match="unknown SyntheticSpec field"):
        get_spec("n3v_like", frames=3)
    with pytest.raises(KeyError, match="valid"):
        build_scene("n3v")
    with pytest.raises(ValueError, match="even image sizes"):
        get_spec("n3v_like", width=65, codec="yuv420")


# -- layouts and the real loaders --------------------------------------------------------------------
def test_n3v_layout(n3v_dir):
    spec = get_spec("n3v_like", **N3V_SMALL)
    pb = np.load(n3v_dir / "poses_bounds.npy")
    assert pb.shape == (spec.num_cameras, 17) and pb.dtype == np.float64
    desc = build_scene("n3v_like", 0)
    cams = forward_facing_rig(spec.num_cameras, desc.target, spec.width, spec.height, spec.hfov_deg, seed=0)
    for row, cam in zip(pb, cams, strict=True):
        pose = row[:15].reshape(3, 5)
        R = cam.world_to_camera[:3, :3].double().numpy()  # rows: camera x, y, z axes in world
        # LLFF columns: down (= OpenCV +y), right (= +x), backwards (= -z), then the centre and hwf
        np.testing.assert_allclose(pose[:, 0], R[1], atol=1e-6)
        np.testing.assert_allclose(pose[:, 1], R[0], atol=1e-6)
        np.testing.assert_allclose(pose[:, 2], -R[2], atol=1e-6)
        np.testing.assert_allclose(pose[:, 3], cam.center.double().numpy(), atol=1e-5)
        np.testing.assert_allclose(pose[:, 4], [spec.height, spec.width, cam.fx], rtol=1e-6)
        assert 0 < row[15] < row[16]
    frames = decode_video(n3v_dir / "cam02.mp4")
    assert frames.shape == (spec.num_frames, spec.height, spec.width, 3)
    r = render(desc.primitives(frame_time(4, spec)), cams[2], frame_time(4, spec), spec.supersample)
    assert psnr_uint8((r.rgb * 255).round().byte().numpy(), frames[4]) == float("inf")  # lossless
    meta = json.loads((n3v_dir / "scene_meta.json").read_text())
    assert meta["stand_in_for"] == "N3V" and meta["video"]["roundtrip_exact"] is True
    assert meta["test_cameras"] == ["cam00"] and meta["seed"] == 0


def test_dnerf_layout(dnerf_dir):
    spec = get_spec("dnerf_like", **DNERF_SMALL)
    for split, n in (("train", spec.num_frames), ("val", spec.num_val), ("test", spec.num_test)):
        tf = json.loads((dnerf_dir / f"transforms_{split}.json").read_text())
        assert math.isclose(tf["camera_angle_x"], math.radians(spec.hfov_deg))
        assert len(tf["frames"]) == n
        for fr in tf["frames"]:
            assert fr["file_path"].startswith(f"./{split}/r_") and not fr["file_path"].endswith(".png")
            assert 0.0 <= fr["time"] <= 1.0
            rgba = np.asarray(Image.open(dnerf_dir / (fr["file_path"][2:] + ".png")))
            assert rgba.shape == (spec.height, spec.width, 4)
            c2w = np.asarray(fr["transform_matrix"])
            # OpenGL: the camera looks along -z; the target is in front of it
            target = build_scene("dnerf_like", 0).target.numpy()
            to_target = target - c2w[:3, 3]
            assert (-c2w[:3, 2]) @ to_target / np.linalg.norm(to_target) > 0.999
    train_t = [f["time"] for f in json.loads((dnerf_dir / "transforms_train.json").read_text())["frames"]]
    test_t = [f["time"] for f in json.loads((dnerf_dir / "transforms_test.json").read_text())["frames"]]
    assert train_t[0] == 0.0 and train_t[-1] == 1.0 and not set(test_t) & set(train_t)
    alpha = np.asarray(Image.open(dnerf_dir / "train" / "r_000.png"))[..., 3]
    assert (alpha == 0).any() and (alpha == 255).any()  # transparent background around the content


def test_mp4_roundtrip_psnr(tmp_path):
    g = np.random.default_rng(0)
    base = g.integers(0, 256, (6, 8, 3)).repeat(8, 0).repeat(8, 1)
    frames = [np.clip(base + g.integers(-20, 20, base.shape), 0, 255).astype(np.uint8) for _ in range(5)]
    results = {}
    for codec in ("lossless", "yuv444", "yuv420"):
        path = tmp_path / f"{codec}.mp4"
        with VideoWriter(path, 64, 48, 30, codec) as vw:
            for f in frames:
                vw.write(f)
        back = decode_video(path)
        assert back.shape == (5, 48, 64, 3)
        results[codec] = psnr_uint8(np.stack(frames), back)
    assert results["lossless"] == float("inf")
    assert results["yuv444"] > 45.0
    assert results["yuv420"] > 20.0  # chroma subsampling of per-pixel noise: lossy by design


def test_yuv420_is_encoded_at_the_quality_of_real_n3v_videos(tmp_path):
    """crf 18 (as real N3V videos): 43.4 dB on this grey texture, where crf 23 gives 37.8 and crf 30 32.3."""
    y, x = np.mgrid[0:64, 0:96]
    frames = [
        np.repeat(((x * 3 + y * 2 + 9 * t) % 200 + 20)[..., None], 3, -1).astype(np.uint8) for t in range(5)
    ]
    with VideoWriter(tmp_path / "grey.mp4", 96, 64, 30, "yuv420") as vw:
        for f in frames:
            vw.write(f)
    assert psnr_uint8(np.stack(frames), decode_video(tmp_path / "grey.mp4")) > 40.0
    with pytest.raises(ValueError, match="unknown codec 'h265'; valid: lossless, yuv444, yuv420"):
        VideoWriter(tmp_path / "x.mp4", 96, 64, 30, "h265")


def test_loads_through_real_n3v_loader(tmp_path):
    small = {"width": 48, "height": 36, "num_frames": 4, "num_cameras": 4, "triangulate": False}
    scene = load_synthetic("n3v_like", root=tmp_path, overrides=small, progress=False, num_points=500)
    assert scene.name == "synthetic:n3v_like" and scene.stand_in == "N3V (synthetic stand-in)"
    assert scene.multiview and scene.num_frames == 4
    assert {v.camera.name.split("/")[0] for v in scene.test} == {"cam00"}
    assert len(scene.train) == 3 * 4 and len(scene.test) == 4
    assert sorted({round(v.camera.time, 6) for v in scene.train}) == [0.0, 0.25, 0.5, 0.75]
    view = scene.test[2]
    folder = scene.meta["synthetic"]["dir"] if hasattr(scene, "meta") else None
    r = render_ground_truth("n3v_like", view.camera, supersample=2)  # the loaded camera and its time
    assert (r.rgb - view.image()).abs().max() < 1.5 / 255
    mask = view.mask()
    assert mask is not None and mask.shape == (36, 48)
    assert torch.equal(mask > 0, load_ground_truth(folder, view).dynamic)
    assert torch.allclose(load_ground_truth(folder, view).depth, r.depth, atol=1e-3)
    # one mask per motion regime of the scene, on every view (also where a regime is not in sight): disjoint,
    # and together exactly the dynamic mask
    dynamic_categories = set(CATEGORIES) - {"static"}
    for v in scene.test:
        regions = v.regions()
        assert set(regions) == dynamic_categories
        stack = torch.stack(list(regions.values()))
        assert stack.shape[1:] == (36, 48) and stack.sum(0).max() <= 1.0
        assert torch.equal(stack.sum(0) > 0, v.mask() > 0)
    ghost = [bool(v.regions()["transient"].any()) for v in scene.test]
    assert ghost == [0.3 <= v.camera.time < 0.7 for v in scene.test]


def test_loads_through_real_dnerf_loader(tmp_path):
    small = {"width": 32, "height": 32, "num_frames": 4, "num_val": 1, "num_test": 2}
    scene = load_synthetic("dnerf_like", root=tmp_path, overrides=small, progress=False, num_points=100)
    assert scene.stand_in == "D-NeRF (synthetic stand-in)" and not scene.multiview
    assert len(scene.train) == 4 and len(scene.test) == 2
    spec = get_spec("dnerf_like", "quick", **small)
    desc = build_scene(spec.scene, 0)
    times = _held_out_times(spec.num_test, 37 + desc.seed)
    written = orbit_cameras(
        times, desc.target, spec.orbit_radius, spec.width, spec.height, spec.hfov_deg, seed=desc.seed + 2000
    )
    for view, camera in zip(scene.test, written, strict=True):
        # The loaded camera is the written one up to float32 rounding of the JSON pose and its inverse ...
        torch.testing.assert_close(
            view.camera.world_to_camera, camera.world_to_camera.float(), atol=1e-6, rtol=0
        )
        torch.testing.assert_close(view.camera.K, camera.K.float(), atol=1e-5, rtol=0)
        assert view.camera.time == camera.time
        # ... and the loaded image is the render at the written camera. (Not at the loaded one: where the
        # written pose has an exact 0 that the float32 inverse turns into ~1e-17, the ray caster
        # flips whole silhouette pixels: measured 19 px by up to 0.09 on an AVX-512 CPU.)
        r = render_ground_truth("dnerf_like", camera, supersample=2)
        white = r.rgb * r.alpha[..., None] + (1 - r.alpha[..., None])
        assert (white - view.image()).abs().max() < 1.5 / 255
        gt = ground_truth(scene, view)
        assert torch.equal(gt.ids, r.ids)
        assert torch.equal(view.mask() > 0, gt.dynamic)
        assert gt.mask(categories=("static",)).any()


def test_the_abrupt_hopper_reverses_its_spin_at_every_knot():
    """Velocity and spin change at once at each knot: turning back by the angle it turned forward."""
    from moegs.data.synthetic.scenes import TurningPath, _hopper

    path = TurningPath(knots=(0.0, 0.5, 1.0), points=((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0)))
    hopper = _hopper(3, path, 0.1, Texture("checker", ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))), "test", spin=2.0)

    def rotation(t: float) -> torch.Tensor:
        (box,) = hopper.parts(t)
        return box.rotation

    assert not torch.allclose(rotation(0.25), rotation(0.0))
    torch.testing.assert_close(rotation(0.75), rotation(0.25))  # 2 x 0.5 - 2 x 0.25 = 2 x 0.25 rad
    torch.testing.assert_close(rotation(1.0), rotation(0.0))
