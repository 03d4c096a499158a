"""STG: polynomial motion, rotation, temporal opacity, decoder, segments, sampling, densification."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.data.scene import PointCloud
from moegs.experts.stg import (
    STGConfig,
    STGExpert,
    STGSegments,
    STGStrategy,
    keep_isolated_later_points,
    linear_rotation,
    polynomial_motion,
    segment_bounds,
    segment_index,
    segment_scene,
    temporal_opacity,
)
from moegs.experts.stg_decoder import FeatureDecoder
from moegs.recipes import config_for
from moegs.train.config import TrainConfig
from moegs.train.entry import finished_run, load_trained, train_recipe
from moegs.train.loop import TrainingRun
from moegs.train.optim import Optimizers
from moegs.train.segments import SEGMENTS_NAME, train_segments


def monocular(scene):
    """One camera per frame (cycling), as D-NeRF."""
    cams = len({v.camera.camera_id for v in scene.train})
    return replace(
        scene, train=[v for v in scene.train if v.camera.camera_id == v.camera.frame % cams], multiview=False
    )


def with_times(scene):
    """Points tagged with the normalised time of a random frame (an STG-style merged per-frame cloud)."""
    g = torch.Generator().manual_seed(3)
    frames = torch.randint(scene.num_frames, (len(scene.points),), generator=g).float()
    times = frames / max(scene.num_frames - 1, 1)
    return replace(scene, points=PointCloud(scene.points.xyz, scene.points.rgb, "tiny per-frame", times))


def test_cubic_polynomial_motion_by_hand():
    means = torch.tensor([[1.0, 2.0, 3.0]])
    motion = torch.tensor([[1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 3.0]])  # b1 x, b2 y, b3 z
    out = polynomial_motion(means, motion, torch.tensor([[0.5]]))
    assert out.tolist() == [[1.5, 2.0 + 2.0 * 0.25, 3.0 + 3.0 * 0.125]]


def test_linear_rotation_velocity():
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    omega = torch.tensor([[0.0, 0.0, 0.0, 2.0]])
    out = linear_rotation(q, omega, torch.tensor([[0.5]]))
    assert torch.allclose(out, torch.tensor([[1.0, 0.0, 0.0, 1.0]]) / math.sqrt(2))


def test_temporal_rbf_opacity_divides_by_the_scale():
    logits = torch.zeros(3)  # sigmoid = 0.5
    dt = torch.tensor([0.0, 0.5, 1.0])
    log_scale = torch.log(torch.tensor([1.0, 0.5, 2.0]))
    expected = 0.5 * torch.exp(-torch.tensor([0.0, 1.0, 0.25]))
    assert torch.allclose(temporal_opacity(logits, dt, log_scale), expected)


def test_segment_lookup_and_bounds():
    times = [j / 300 for j in range(300)]
    bounds = segment_bounds(times, 150)
    assert bounds == [(0.0, 0.5), (0.5, 1.0)]  # MoE-GS N3V: local t/150 and (t-150)/150
    starts = [b[0] for b in bounds]
    assert [segment_index(t, starts) for t in (0.0, 0.4967, 0.5, 0.99, 1.2, -0.1)] == [0, 0, 1, 1, 1, 0]
    assert segment_bounds([0.0, 0.25, 0.5, 0.75], None) == [(0.0, 1.0)]
    assert segment_bounds([0.0, 0.25, 0.5, 0.75], 3) == [(0.0, 0.75), (0.75, 1.0)]


def test_decoder_is_bias_free_12_6_3_and_uses_rays():
    dec = FeatureDecoder("sigmoid")
    assert [tuple(p.shape) for p in dec.parameters()] == [(6, 12), (3, 6)]
    cam = tiny_scene(num_frames=1, cameras=2).train[0].camera
    feats = torch.zeros(cam.height, cam.width, 9)
    feats[..., :3] = 0.3
    with torch.no_grad():
        dec.mlp2.weight.zero_()
        assert torch.allclose(
            dec(feats, cam), torch.sigmoid(torch.tensor(0.3)).expand(cam.height, cam.width, 3)
        )
        dec.mlp2.weight.fill_(0.1)
        dec.mlp1.weight.fill_(0.0)
        dec.mlp1.weight[0, 6:9] = 1.0  # hidden unit 0 = ReLU(camera centre x + y + z)
        origins, _ = cam.rays()
        h = torch.relu(origins.sum(-1, keepdim=True))
        assert torch.allclose(dec(feats, cam), torch.sigmoid(0.3 + 0.1 * h).expand(-1, -1, 3), atol=1e-6)
    clamp = FeatureDecoder("clamp")
    with torch.no_grad():
        clamp.mlp2.weight.zero_()
    feats[..., :3] = 1.7
    assert torch.all(clamp(feats, cam) == 1.0)


@pytest.mark.parametrize("color", ["full", "sh", "lite"])
def test_colour_models_frame_channels_and_groups(color):
    scene = tiny_scene(num_frames=2)
    expert = STGExpert.from_scene(scene, STGConfig(color=color, max_init_points=50))
    cam = scene.train[0].camera
    frame = expert.frame(cam.time, cam)
    assert frame.num_channels == {"full": 9, "sh": 3, "lite": 3}[color]
    rgb, out, _ = expert.render(cam, scene.background)
    assert rgb.shape == (cam.height, cam.width, 3) and torch.isfinite(rgb).all()
    opts = Optimizers(expert.param_groups())
    assert set(opts.for_splats(expert.splats)) == set(expert.splats.keys())
    assert len({id(p) for g in expert.param_groups() for p in g.params}) == len(list(expert.parameters()))


def test_time_centre_learns_only_through_opacity():
    scene = tiny_scene(num_frames=2)
    expert = STGExpert.from_scene(scene, STGConfig(max_init_points=50))
    with torch.no_grad():
        expert.splats["motion"].normal_()
        expert.splats["omega"].normal_()
    frame = expert.frame(0.7)
    (frame.means.sum() + frame.quats.sum() + frame.colors.sum()).backward()
    assert expert.splats["trbf_center"].grad is None or expert.splats["trbf_center"].grad.abs().sum() == 0
    frame = expert.frame(0.7)
    frame.opacities.sum().backward()
    assert expert.splats["trbf_center"].grad.abs().sum() > 0


def test_birth_times_come_from_the_point_cloud_in_local_time():
    scene = with_times(tiny_scene(num_frames=3))  # scene times 0, 0.5, 1 -> STG's j / D = 0, 1/3, 2/3
    expert = STGExpert.from_scene(scene, STGConfig())
    assert expert.window == (0.0, 1.5)
    assert torch.allclose(expert.splats["trbf_center"].detach(), scene.points.times / 1.5)
    with torch.no_grad():
        expert.splats["trbf_center"].fill_(2 / 3)
    assert torch.allclose(expert.frame(1.0).opacities, torch.sigmoid(expert.splats["opacities"]))  # Δt = 0


def test_preprocesspoints_3_keeps_the_first_time_and_the_most_isolated_of_later_times():
    """``interpolate_point`` (STG ``helper_model.py:126-178``): the earliest time whole; in a later time of
    n points those whose nearest-neighbour distance exceeds the floor(n / 4)-th largest (strictly: k - 1
    points), the smallest distance when floor(n / 4) = 0 (index -0), a lone point dropped; the groups
    earliest first, each in input order."""

    def on_x(xs, t):
        return [[float(x), 0.0, 0.0] for x in xs], [t] * len(xs)

    groups = [
        on_x([0, 1, 5], 1.0),  # 3 points, k = 0: the threshold is the smallest distance (1) -> x = 5 only
        on_x([0, 0.1, 0.2], 0.0),  # the earliest time: kept whole however close
        on_x([10, 0, 21, 1, 6, 28, 3, 15], 0.5),  # 8 points, nn 4 1 6 1 3 7 2 5: k = 2, > 6 -> x = 28 only
        on_x([7], 0.75),  # a lone point has no neighbour: dropped
    ]
    xyz = torch.tensor([p for g in groups for p in g[0]])
    times = torch.tensor([t for g in groups for t in g[1]])
    rgb = torch.arange(len(xyz), dtype=torch.float32)[:, None].expand(-1, 3) / 100  # follows each point
    cloud = PointCloud(xyz, rgb, "per-frame", times)
    thinned = keep_isolated_later_points(cloud)
    torch.testing.assert_close(thinned.xyz[:, 0], torch.tensor([0.0, 0.1, 0.2, 28.0, 5.0]))
    torch.testing.assert_close(thinned.times, torch.tensor([0.0, 0.0, 0.0, 0.5, 1.0]))
    torch.testing.assert_close(thinned.rgb[:, 0], torch.tensor([3.0, 4, 5, 11, 2]) / 100)
    untimed = PointCloud(xyz, rgb, "one frame")
    assert keep_isolated_later_points(untimed) is untimed


def test_the_technicolor_recipes_thin_later_frames_before_the_expert_starts():
    """``"preprocesspoints": 3`` on Birthday, Theater and Train (configs/techni_full/<Scene>.json:6), applied
    in ``create_from_pcd`` (scene/oursfull.py:155-156) to the cloud of the model's window."""
    assert config_for("stg", "technicolor:train", "paper").config.thin_later_frames
    assert not config_for("stg", "technicolor:painter", "paper").config.thin_later_frames
    scene = with_times(tiny_scene(num_frames=3))
    expected = keep_isolated_later_points(scene.points)
    assert len(expected) < len(scene.points)
    expert = STGExpert.from_scene(scene, STGConfig(thin_later_frames=True))
    assert expert.num_gaussians == len(expected)
    torch.testing.assert_close(expert.splats["means"].detach(), expected.xyz)
    torch.testing.assert_close(expert.splats["trbf_center"].detach(), expected.times / 1.5)
    assert STGExpert.from_scene(scene, STGConfig()).num_gaussians == len(scene.points)


def test_two_views_of_one_timestamp_per_step():
    scene = tiny_scene(num_frames=3, cameras=4)
    expert = STGExpert.from_scene(scene, STGConfig(max_init_points=50))
    g = torch.Generator().manual_seed(0)
    for step in range(1, 20):
        picks = expert.select_views(step, scene.train, 1, g)
        cams = [scene.train[i].camera for i in picks]
        assert len(picks) == 2 and cams[0].time == cams[1].time and cams[0].camera_id != cams[1].camera_id
    mono = monocular(tiny_scene(num_frames=3))
    assert len(expert.select_views(1, mono.train, 1, g)) == 1


def test_densification_randomises_new_time_centres_and_caps_events():
    scene = tiny_scene(num_frames=2)
    expert = STGExpert.from_scene(scene, STGConfig(max_init_points=40))
    strategy = STGStrategy(densify_from=0, densify_every=1, max_densify_events=2, prune_until=100)
    params = expert.splats
    with torch.no_grad():
        params["trbf_center"].fill_(0.5)
    state = strategy.initialize_state(1.0)
    n = params["means"].shape[0]
    state.update(grad2d=torch.ones(n), count=torch.ones(n), max_radii=torch.zeros(n))
    strategy._clone_and_split(params, {}, state)
    centres = params["trbf_center"].detach()
    assert centres.shape[0] > n and torch.all(centres[: n - state["last_refine"]["split"]] == 0.5)
    assert not torch.all(centres == 0.5)
    assert state["last_refine"]["clone"] + state["last_refine"]["split"] == n


def _late_strategy(**kw) -> STGStrategy:
    """An STG strategy past densification, with only the late events ``kw`` switches on."""
    off = {"densify_until": 0, "prune_z_below": None, "z_prune_every": None, "omega_mask_from": None,
           "bbox_prune_at": None, "reset_at": (), "guided_from": None}  # fmt: skip
    return STGStrategy(**{**off, **kw})


def test_the_omega_mask_keeps_rotation_velocity_for_moving_gaussians_only():
    """``helper_train.py:196-199``: at ``omega_mask_from``, Gaussians moving faster than 0.3 (the velocity
    ``b1``), of size in (0.2, 0.6) and opacity > 0.7 keep omega; then omega learns only for them and the
    static rotation only for the others."""
    params = STGExpert.from_scene(tiny_scene(num_frames=2), STGConfig(max_init_points=40)).splats
    with torch.no_grad():
        params["motion"].zero_()
        params["motion"][0, 0:3] = torch.tensor([0.2, 0.2, 0.0])  # velocity 0.4: moving
        params["motion"][1, 3:6] = 1.0  # accelerating from rest: not moving
        params["scales"].fill_(math.log(0.4))
        params["opacities"].fill_(math.log(0.9 / 0.1))
        params["omega"].fill_(1.0)
    strategy = _late_strategy(omega_mask_from=10)
    state = strategy.initialize_state(1.0)
    strategy.step_post_backward(params, {}, state, 10, {})
    assert params["omega"][0].tolist() == [1.0] * 4 and params["omega"][1].tolist() == [0.0] * 4
    params["omega"].grad, params["quats"].grad = (
        torch.ones_like(params["omega"]),
        torch.ones_like(params["quats"]),
    )
    strategy.step_post_backward(params, {}, state, 11, {})
    assert params["omega"].grad[0].tolist() == [1.0] * 4 and params["omega"].grad[1].tolist() == [0.0] * 4
    assert params["quats"].grad[0].tolist() == [0.0] * 4 and params["quats"].grad[1].tolist() == [1.0] * 4


def test_late_z_pruning_runs_halfway_through_each_period():
    """``helper_train.py:223-226`` (N3V): after densification, at ``k every + every / 2``."""

    def left_after(step):
        params = STGExpert.from_scene(tiny_scene(num_frames=2), STGConfig(max_init_points=40)).splats
        with torch.no_grad():
            params["means"][:, 2] = 10.0
            params["means"][0, 2] = 1.0  # in front of the z = 4.5 plane: pruned when the event runs
        strategy = _late_strategy(prune_z_below=4.5, z_prune_every=1000)
        strategy.step_post_backward(params, {}, strategy.initialize_state(1.0), step, {})
        return params["means"].shape[0]

    assert [left_after(s) for s in (1000, 1499, 1500, 2500)] == [40, 40, 39, 39]


def test_the_initial_z_prune_runs_before_the_first_render():
    """``train.py:149-152`` prunes the initial points below the plane before its loop; pruned after the first
    render (as before), the step's statistics no longer matched the cloud and densification raised."""
    scene = tiny_scene(num_frames=2)
    config = STGConfig(max_init_points=40)
    config = replace(
        config,
        strategy=replace(config.strategy, prune_z_below=0.0, densify_from=0, densify_every=1),
        train=replace(config.train, iterations=3),
    )
    expert = STGExpert.from_scene(scene, config)
    below = int((expert.splats["means"][:, 2] < 0.0).sum())
    assert 0 < below < expert.num_gaussians
    rendered = []
    render = expert.render

    def counting(camera, *args, **kwargs):
        rendered.append(expert.num_gaussians)
        return render(camera, *args, **kwargs)

    n = expert.num_gaussians
    run = TrainingRun(expert, scene, config.train, None)  # takes each camera's depths from every point
    expert.render = counting
    for step in (1, 2, 3):
        run.iteration(step)
    assert rendered[0] == n - below


def test_a_guided_event_waits_more_than_the_gap_after_the_last():
    scene = tiny_scene(num_frames=2)
    params = STGExpert.from_scene(scene, STGConfig(max_init_points=40)).splats
    strategy = _late_strategy(guided_from=100, guided_gap=100)
    view = scene.train[0]
    image = view.image()
    info = {"views": [{"camera": view.camera, "rgb": image, "target": image}]}  # SSIM 1: counted, no points

    def events_at(step):
        state = strategy.initialize_state(1.0)
        selected = [str(view.camera.camera_id), "other"]
        state["guided"].update(phase="selected", selected=selected, last=1000)
        strategy.step_post_backward(params, {}, state, step, info)
        return state["guided"]["events"]

    assert [events_at(s) for s in (1099, 1100, 1101)] == [0, 0, 1]


def test_segments_answer_global_time_with_local_models():
    scene = with_times(tiny_scene(num_frames=4, cameras=2))
    part = segment_scene(scene, 0.5, 1.0 + 1 / 3)
    assert {round(v.camera.time, 6) for v in part.train} == {0.2, 0.6}
    config = STGConfig.quick()
    config.segment_frames = 2
    config.max_init_points = 60
    config.train = TrainConfig(iterations=3, lambda_dssim=0.2)
    segments, result = train_segments(scene, config)
    assert (
        isinstance(segments, STGSegments)
        and len(segments.models) == 2
        and result["completed"]
        and [r["completed"] for r in result["segments"]] == [True, True]
    )
    model, local = segments.locate(2 / 3)
    assert model is segments.models[1] and local == pytest.approx(0.0)
    cam = scene.train[-1].camera
    rgb, _, _ = segments.render(cam, scene.background)
    assert rgb.shape == (cam.height, cam.width, 3)
    assert segments.num_gaussians == sum(m.num_gaussians for m in segments.models)


def test_stg_recipes_train_fifty_frame_segments_as_the_original():
    """``duration`` 50 in every STG config (configs/n3d_full/*.json:7 or :8, techni_full/*.json:10); STG†
    150."""
    assert config_for("stg", "n3v:cook_spinach", "paper").config.segment_frames == 50
    assert config_for("stg", "technicolor:birthday", "paper").config.segment_frames == 50
    assert STGConfig.moe_sh().segment_frames == 150


def test_a_segmented_recipe_trains_resumes_and_loads_as_one_run(tmp_path):
    scene = with_times(tiny_scene(num_frames=4, cameras=2))
    overrides = {"segment_frames": 2, "max_init_points": 60, "train.iterations": 3, "train.eval_every": 0}
    recipe = config_for("stg", "synthetic:n3v_like", "quick", overrides=overrides)
    segments, result = train_recipe(recipe, scene, tmp_path, progress=False)
    assert isinstance(segments, STGSegments) and len(segments.models) == 2
    assert {p.name for p in tmp_path.iterdir()} >= {
        SEGMENTS_NAME,
        "config.json",
        "metrics.json",
        "segment_0",
        "segment_1",
    }
    assert (result["step"], result["iterations"], result["num_gaussians"]) == (6, 6, segments.num_gaussians)
    # the whole run is scored with the wrapper at global time, on every test view of the scene
    assert result["test"]["num_views"] == len(scene.test) and finished_run(tmp_path)["test"] == result["test"]
    loaded, state = load_trained(tmp_path, scene, expect="stg")
    assert (
        isinstance(loaded, STGSegments) and len(state["segments"]) == 2 and loaded.bounds == segments.bounds
    )
    cam = scene.test[-1].camera
    with torch.no_grad():
        assert torch.equal(loaded.render(cam, scene.background)[0], segments.render(cam, scene.background)[0])
    with pytest.raises(ValueError, match="segmented 'stg' run, but its run says 'grid4d'"):
        load_trained(tmp_path, scene, expect="grid4d")
    record = json.loads((tmp_path / SEGMENTS_NAME).read_text())
    (tmp_path / SEGMENTS_NAME).write_text(json.dumps({**record, "expert": "grid4d"}))
    with pytest.raises(ValueError, match=r"segments.json: expected 'expert': 'stg' .* got 'grid4d'"):
        load_trained(tmp_path, scene)
    (tmp_path / SEGMENTS_NAME).write_text(json.dumps(record))
    _, again = train_recipe(recipe, scene, tmp_path, progress=False)  # finished segments are not retrained
    assert again["resumed_from"] == [3, 3] and again["test"]["psnr"] == result["test"]["psnr"]


def test_a_segmented_run_stopped_early_is_not_finished(tmp_path):
    scene = with_times(tiny_scene(num_frames=4, cameras=2))
    recipe = config_for(
        "stg",
        "synthetic:n3v_like",
        "quick",
        overrides={"segment_frames": 2, "max_init_points": 60, "train.iterations": 3},
    )
    segments, result = train_recipe(recipe, scene, tmp_path, progress=False, stop_after=2)
    assert len(segments.models) == 1 and not result["completed"] and result["test"] is None
    assert finished_run(tmp_path) is None and not (tmp_path / "segment_1").exists()
