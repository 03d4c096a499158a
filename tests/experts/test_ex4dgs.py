"""Ex4DGS: keyframe interpolation, temporal opacity, conversion, progressive schedule, back-tracking."""

from __future__ import annotations

import math

import pytest
import torch
from helpers.scenes import tiny_scene
from torch import Tensor

from moegs.experts.ex4dgs import (
    Ex4DGSConfig,
    Ex4DGSExpert,
    catmull_rom,
    extrapolate_keyframes,
    grown_keyframe_count,
    initial_keyframes,
    keyframe_count,
    keyframe_position,
    slerp,
    temporal_opacity,
)
from moegs.render import rasterize
from moegs.train.config import TrainConfig
from moegs.train.optim import Optimizers
from moegs.train.strategy import ADCStrategy


def test_keyframe_position_and_count():
    assert keyframe_position(3, 12, 10) == (1, 0.5)  # u = 15
    assert keyframe_position(0, 12, 10) == (1, 0.2)
    assert keyframe_count(300, 12, 10) == 36  # N3V: ceil(325 / 10) + 3


def test_catmull_rom_hermite_by_hand():
    xs = torch.tensor([0.0, 1.0, 4.0, 9.0, 16.0])
    points = torch.stack([xs, torch.zeros(5), -xs], dim=-1)[None]  # [1, 5, 3]
    # k = 1: tangents (4 - 0) / 2 = 2 and (9 - 1) / 2 = 4; h = (0.5, 0.125, 0.5, -0.125) at δ = 0.5
    assert catmull_rom(points, 1, 0.5)[0].tolist() == pytest.approx([2.25, 0.0, -2.25])
    assert catmull_rom(points, 1, 0.0)[0, 0].item() == pytest.approx(1.0)
    assert catmull_rom(points, 1, 1.0)[0, 0].item() == pytest.approx(4.0)
    with pytest.raises(ValueError, match="outside the keyframe range"):
        catmull_rom(points, 0, 0.5)


def test_slerp_halfway_and_no_shortest_arc_flip():
    q0 = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    q1 = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])  # 90 degrees about z
    half = slerp(q0, q1, 0.5)
    assert torch.allclose(
        half, torch.tensor([[math.cos(math.pi / 8), 0, 0, math.sin(math.pi / 8)]]), atol=1e-5
    )
    assert torch.allclose(slerp(q0, q1, 0.0), q0) and torch.allclose(slerp(q0, q1, 1.0), q1, atol=1e-6)
    long_way = slerp(q0, -q1, 0.5)  # the same rotation as q1, but no sign flip: the long arc
    assert not torch.allclose(long_way.abs(), half.abs(), atol=1e-3)
    assert torch.allclose(long_way.norm(dim=-1), torch.ones(1))


def test_two_sided_temporal_opacity_literal():
    centers = torch.tensor([[2.0, 4.0]]).repeat(3, 1)
    widths = torch.tensor([[0.0, math.log(2.0)]]).repeat(3, 1)
    var_min = 0.3
    out = temporal_opacity(
        centers, widths, torch.tensor([3.0, 5.0, 1.0])[:, None].squeeze(1)[0].item(), var_min
    )
    assert torch.all(out == 1.0)  # between the centres
    right = temporal_opacity(centers[:1], widths[:1], 5.0, var_min)
    assert right.item() == pytest.approx(
        math.exp(-1.0 / (2.0 + var_min / 2.36) ** 2)
    )  # m = 5 - 4, right width
    left = temporal_opacity(centers[:1], widths[:1], 1.0, var_min)
    assert left.item() == pytest.approx(math.exp(-9.0 / (1.0 + var_min / 2.36) ** 2))  # m = min(-1, -3) = -3


def test_initial_keyframes_resize_two_points_like_the_original():
    x, d = torch.zeros(1, 3), torch.ones(1, 3)
    keys = initial_keyframes(x, d, interval=10, duration=10, count=4)  # ends -1 and 2, align_corners=False
    assert keys[0, :, 0].tolist() == pytest.approx([-1.0, -0.25, 1.25, 2.0])


def test_extrapolate_keyframes_steps_like_lin_interp_last():
    """``c_gaussian_model.py:1265``: the step is the mean of ``P_{v-j} - P_{v-a-1}`` over ``j = 1..a``, so a
    straight line with unit steps goes on with steps of ``(a + 1) / 2``."""
    keys = torch.tensor([0.0, 1.0, 2.0, 3.0, 99.0, 99.0])[None, :, None]
    assert extrapolate_keyframes(keys, valid=4, average=2)[0, :, 0].tolist() == [0, 1, 2, 3, 4.5, 6]
    assert extrapolate_keyframes(keys, valid=4, average=1)[0, :, 0].tolist() == [0, 1, 2, 3, 4, 5]


def _expert(num_frames=3, **overrides) -> tuple[Ex4DGSExpert, object]:
    scene = tiny_scene(num_frames=num_frames)
    config = Ex4DGSConfig.quick()
    config.max_init_points = 80
    for k, v in overrides.items():
        setattr(config, k, v)
    return Ex4DGSExpert.from_scene(scene, config), scene


def test_static_drift_over_the_model_duration():
    """``get_static_xyz_at_t``: ``x + d t / D`` with the Gaussians' duration, which ``expand_duration``
    (called before training, ``train.py:75``) sets one past the sampling length: 3 for ``start_duration``
    2."""
    expert, scene = _expert(num_frames=5, start_duration=2)
    with torch.no_grad():
        expert.splats["drift"].fill_(1.0)
    frame_time = scene.train[-1].camera.time  # frame 4
    means = expert.frame(frame_time).means
    assert expert.model_duration() == 3
    assert torch.allclose(means, expert.splats["means"] + 4.0 / 3.0)


def test_dynamic_gaussians_follow_their_keyframes_between_k_and_k_plus_1():
    """Keyframe ``j`` at ``x = j`` rotated by ``0.2 j`` about z: Catmull-Rom reproduces the line and slerp
    the angle, so frame time ``k + δ`` (in keyframes) sits at ``x = k + δ``, angle ``0.2 (k + δ)``."""
    expert, scene = _expert(num_frames=5)
    c, s = expert.config, expert.splats
    keyframes = s["motion_means"].shape[1]
    angles = 0.2 * torch.arange(keyframes, dtype=torch.float32)
    with torch.no_grad():
        s["dynamic"][:2] = True
        s["drift"].zero_()
        s["motion_means"][:2] = 0.0
        s["motion_means"][:2, :, 0] = torch.arange(keyframes, dtype=torch.float32)
        s["motion_quats"][:2] = 0.0
        s["motion_quats"][:2, :, 0] = torch.cos(angles / 2)
        s["motion_quats"][:2, :, 3] = torch.sin(angles / 2)
    t = scene.train[len(scene.train) // 2].camera.time
    k, delta = keyframe_position(expert.frame_index(t), c.shift, c.interval)
    assert 1 <= k <= keyframes - 3
    position = k + delta
    frame = expert.frame(t)
    torch.testing.assert_close(frame.means[:2], torch.tensor([[position, 0.0, 0.0]] * 2))
    half = 0.2 * position / 2
    expected = torch.tensor([[math.cos(half), 0.0, 0.0, math.sin(half)]] * 2)
    torch.testing.assert_close(frame.quats[:2], expected)


def test_conversion_uses_drift_over_squared_distance_and_best_frame():
    expert, scene = _expert()
    s = expert.splats
    cam = scene.train[0].camera
    with torch.no_grad():
        s["drift"][:5] = 0.5
        s["err_min_time"][:5] = 1.0
    converted = expert.convert(cam)
    assert converted.numel() >= 1 and torch.equal(s["dynamic"].nonzero()[:, 0], converted)
    i = int(converted[0])
    c = expert.config
    duration = max(expert.duration, c.interval)  # the original's max(max_dur, interval)
    assert s["widths"][i].tolist() == pytest.approx([1.0 + c.time_pad, duration - 1.0 + c.time_pad])
    lo, hi = (c.shift + 1) / c.interval, (c.shift + duration - 1) / c.interval
    expected = [
        min(max((0.5 + c.shift) / c.interval, lo), hi),
        min(max(((duration + 1) / 2 + c.shift) / c.interval, lo), hi),
    ]
    assert s["centers"][i].tolist() == pytest.approx(expected)
    assert torch.allclose(s["motion_quats"][i], s["quats"][i].expand_as(s["motion_quats"][i]))
    frame = expert.frame(scene.train[-1].camera.time)
    assert torch.isfinite(frame.means).all() and not torch.allclose(frame.means[i], s["means"][i])


def _frame(expert, view) -> int:
    return round(expert.frame_index(view.camera.time))


def _recording_conversions(expert) -> list:
    """Replace ``expert.convert`` by a recorder of the cameras it is called with (converting nothing)."""
    cameras = []

    def record(camera):
        cameras.append(camera)
        return torch.zeros(0, dtype=torch.long)

    expert.convert = record
    return cameras


def test_views_are_popped_from_a_shuffled_stack_of_the_trained_frames():
    """``train.py:117-124``: an empty stack is refilled with the shuffled views of frames ``0..duration``
    (inclusive, ``scene/__init__.py:271``) and popped one view per step, so a pass sees each view once."""
    expert, scene = _expert(num_frames=30, start_duration=10, grow_from=0, grow_every=10**6, interval=10)
    g = torch.Generator().manual_seed(0)
    eligible = sorted(i for i, v in enumerate(scene.train) if _frame(expert, v) <= 10)
    assert len(eligible) == 11 * (len(scene.train) // 30)  # frame 10 is trained from the start
    passes = [[expert.select_views(step, scene.train, 1, g)[0] for step in range(k, k + len(eligible))]
              for k in (1, 1 + len(eligible))]  # fmt: skip
    assert sorted(passes[0]) == eligible and sorted(passes[1]) == eligible
    assert passes[0] != passes[1] and passes[0] != eligible  # shuffled anew each pass


def test_growth_arms_a_conversion_that_runs_after_the_step_of_the_first_view_of_the_newest_frames():
    """``train.py:126-129, 257-283``, after each step's update: a growth that adds keyframes, and the step
    ``make_dynamic_interval`` into a growth period while ``need_extract`` holds (it starts true), arm a
    conversion (``mark_last``); it is due at the first popped view whose frame is within ``interval`` of the
    sampling length, whatever the batch, and runs after that step's update (``after_update``).
    The first growth waits for ``iteration > progressive_growing_steps``; growths go on to ``τs`` frames
    past the last one."""
    expert, scene = _expert(num_frames=30, start_duration=10, grow_from=0, grow_every=5, interval=10)
    c = expert.config
    c.make_dynamic_interval, c.extract_every = 2, 0
    assert (c.time_pad, c.shift) == (2, 12)
    with torch.no_grad():  # some dynamic Gaussians with the first conversion's keyframes at length 10
        expert.splats["dynamic"][:4] = True
    expert.keyframes = keyframe_count(10, c.shift, c.interval)
    assert expert.keyframes == 7  # ⌈(10 + 24 + 1) / 10⌉ + 3
    cameras = _recording_conversions(expert)
    g = torch.Generator().manual_seed(0)
    lengths, keyframes, converted, expected, armed, need = {}, {}, [], [], False, {}
    for step in range(1, 41):
        picks = expert.select_views(step, scene.train, 2, g)
        lengths[step], keyframes[step] = expert.duration, expert.keyframes
        newest = [i for i in picks if _frame(expert, scene.train[i]) >= lengths[step] - 10]
        due = None
        if armed and newest:
            due, armed = newest[0], False
        expert.after_update(step, {})
        need[step] = expert.need_extract
        if due is not None:
            expected.append(step)
            assert cameras[-1] is scene.train[due].camera
        if len(cameras) > len(converted):
            converted.append(step)
        # by hand, at the end of step: 2 (2 % 5, need_extract starts true); the growths of 15 (model
        # duration 31: ⌈(31 + 12 + 4 + 1) / 10⌉ + 3 = 8 > 7 keyframes) and 20 (41: 9), not those of 10
        # (21: 7) and 25 (to 42 = 30 + τs; 43: 9); 17 and 22 (need_extract set again by those growths)
        armed = armed or step in (2, 15, 17, 20, 22)
    assert [lengths[s] for s in (10, 11, 16, 21, 26, 31, 40)] == [10, 20, 30, 40, 42, 42, 42]
    assert [keyframes[s] for s in (11, 16, 21, 26)] == [7, 8, 9, 9]
    assert converted == expected and converted[0] == 3  # armed after step 2, due with step 3's view
    # need_extract: spent at 2, set again by the growths of 15 and 20, spent at 17 and 22
    assert [need[s] for s in (1, 2, 15, 16, 17, 20, 22)] == [True, False, True, True, False, True, False]


def test_growth_extrapolates_keyframes_and_adjusts_the_temporal_opacity_like_expand_duration():
    """``expand_duration`` (``c_gaussian_model.py:1243-1297``): new keyframes continue the mean step of the
    last ``min(K - 2, 4)``; a right width whose centre plus ``τs / I`` is within half a keyframe of the
    new end becomes 1; centres are clamped to the old model duration's ``(τs + D - 1) / I``."""
    expert, scene = _expert(num_frames=30, start_duration=10, grow_from=0, grow_every=5, interval=10)
    s = expert.splats
    with torch.no_grad():
        s["dynamic"][:2] = True
        steps = torch.arange(s["motion_means"].shape[1], dtype=torch.float)
        s["motion_means"][:2] = steps[None, :, None] * torch.tensor([1.0, 2.0, 3.0])  # a straight line
        s["motion_means"][:2, 7:] = 99.0  # beyond the 7 keyframes: to be replaced
        s["centers"][:2] = torch.tensor([[1.5, 2.0], [1.5, 4.0]])
        s["widths"][:2] = torch.tensor([[5.0, 6.0], [5.0, 6.0]])
    expert.keyframes = 7
    expert.duration = 20.0  # model duration 21
    assert expert._grow({})  # length 30, model duration 31: 8 keyframes
    assert expert.duration == 30 and expert.keyframes == 8
    # the line goes on with lin_interp_last's step: mean of P_6 - P_2 .. P_3 - P_2 (a = min(7 - 2, 4)), 2.5
    tail = 6 + 2.5 * torch.arange(1, len(steps) - 6)
    assert s["motion_means"][0, :, 0].tolist() == steps[:7].tolist() + tail.tolist()
    # right widths: 2.0 + 1.2 = 3.2 is not > (31 + 12) / 10 - 0.5 = 3.8; 4.0 + 1.2 is
    assert s["widths"][:2].tolist() == [[5.0, 6.0], [5.0, 1.0]]
    # centres clamped to (12 + 21 - 1) / 10 = 3.2
    assert s["centers"][:2].flatten().tolist() == pytest.approx([1.5, 2.0, 1.5, 3.2])
    assert not bool(s["dynamic"][2:].any()) and s["widths"][2:].eq(0).all()  # static ones untouched


def test_a_growth_without_dynamic_gaussians_only_extends_the_duration():
    expert, scene = _expert(num_frames=30, start_duration=10, interval=10)
    assert not expert._grow({}) and expert.duration == 20 and expert.keyframes == 0


def test_the_first_conversion_sets_the_keyframe_count_even_when_it_converts_nothing():
    """``extract_dynamic_points_from_static`` sets ``keyframe_num`` before it knows what it converts, and
    restarts the dynamic set's interval statistics whatever it converts
    (``c_gaussian_model.py:1213-1220``)."""
    expert, scene = _expert(num_frames=30, start_duration=10, interval=10)
    s = expert.splats
    with torch.no_grad():
        s["dynamic"][:2] = True
        s["err_sum"].fill_(1.0)
    assert expert.convert(scene.train[0].camera).numel() == 0  # nothing drifts
    assert expert.keyframes == keyframe_count(10, expert.config.shift, 10)
    assert s["err_sum"][:2].eq(0).all() and s["err_sum"][2:].eq(1).all()


def test_grown_keyframe_count_is_expand_durations_require_dim():
    assert grown_keyframe_count(31, shift=12, time_pad=2, interval=10) == math.ceil(48 / 10) + 3
    assert grown_keyframe_count(313, shift=12, time_pad=2, interval=10) == 36  # N3V's last growth


def test_interval_extraction_converts_with_the_step_view_only_while_densifying_between_densifications():
    """``train.py:203, 217, 228-232``: every ``extracton_interval`` iterations, while densifying but not at a
    densification step (the ``elif``), a time bin with errors converts with the popped view after the
    backward pass and is dropped (``get_errorneous_timestamp``)."""
    expert, scene = _expert(num_frames=3, grow_from=0, grow_every=10**6, interval=1)  # a bin a frame
    expert.config.extract_every, expert.config.make_dynamic_interval = 4, 0  # no growth, nothing armed
    strategy = expert.config.strategy
    strategy.densify_from, strategy.densify_every, strategy.densify_until = 0, 8, 14
    expert.bin_errors[0] = torch.tensor([1.0, 1.0])
    expert.bin_errors[-1] = torch.tensor([2.0, 1.0])
    cameras = _recording_conversions(expert)
    g = torch.Generator().manual_seed(0)
    at = {}
    for step in range(1, 21):
        (i,) = expert.select_views(step, scene.train, 1, g)
        expert.after_backward(step, {})
        if len(cameras) > len(at):
            at[step] = cameras[-1]
            assert cameras[-1] is scene.train[i].camera
    assert list(at) == [4, 12]  # 8 densifies, 16 and 20 are past densify_until
    assert not expert.bin_errors[:, 1].any()  # the worst bin first, then the other


def _with_moments_and_grads(expert) -> dict:
    """One optimiser step on ``sum(p²)`` of every trainable tensor, then fresh gradients: every Gaussian
    has non-zero moments and gradients. Returns the per-key optimisers."""
    optimizers = Optimizers(expert.param_groups())
    for _ in range(2):
        optimizers.zero_grad()
        sum((p.float() ** 2).sum() for p in expert.splats.values() if p.requires_grad).backward()
        if _ == 0:
            optimizers.step()
    return optimizers.for_splats(expert.splats)


def test_the_dynamic_colour_learns_at_feature_motion_lr():
    """``c_gaussian_model.py:432-441``: static SH at ``feature_lr`` (/20 for the higher bands), dynamic SH
    at ``feature_motion_lr`` (2.5e-4 on Technicolor Birthday, Painter, Train); the other groups share one
    rate between the sets."""
    expert, _ = _expert(motion_sh0_lr=2.5e-4, motion_shN_lr=2.5e-4 / 20)
    groups = {g.name: g for g in expert.param_groups()}
    assert (groups["sh0"].lr, groups["sh0"].second_lr) == (2.5e-3, 2.5e-4)
    assert (groups["shN"].lr, groups["shN"].second_lr) == (2.5e-3 / 20, 2.5e-4 / 20)
    assert all(g.second_lr is None for name, g in groups.items() if name not in ("sh0", "shN"))
    sets = Optimizers(expert.param_groups()).optimizers
    assert sets["sh0"].param_groups[0]["second_lr"] == 2.5e-4


def _moment(optimizers, expert, key) -> Tensor:
    return optimizers[key].state[expert.splats[key]]["exp_avg"]


def test_the_interval_conversion_rewrites_every_tensor_like_the_originals_optimiser():
    """``cat_tensors_to_optimizer`` and ``prune_points`` after the backward pass (``train.py:228-232``):
    the converted Gaussians' moments restart at zero, the others' are kept, and no tensor keeps the
    gradient, so the step's update changes nothing."""
    expert, scene = _expert(num_frames=3, grow_from=0, grow_every=10**6, interval=1)
    expert.config.extract_every, expert.config.adjust_every = 4, 0
    strategy = expert.config.strategy
    strategy.densify_from, strategy.densify_every, strategy.densify_until = 0, 8, 14
    s = expert.splats
    with torch.no_grad():
        s["drift"][:5] = 0.5
        s["err_min_time"][:5] = 1.0
    expert.bin_errors[0] = torch.tensor([1.0, 1.0])
    optimizers = _with_moments_and_grads(expert)
    before = _moment(optimizers, expert, "scales").clone()
    expert.select_views(4, scene.train, 1, torch.Generator().manual_seed(0))
    expert.after_backward(4, optimizers)
    converted = s["dynamic"].nonzero()[:, 0]
    assert converted.numel() >= 1 and before[converted].abs().sum() > 0
    after = _moment(optimizers, expert, "scales")
    assert after[converted].eq(0).all()
    kept = ~s["dynamic"]
    assert torch.equal(after[kept], before[kept])
    assert all(p.grad is None for p in s.values())
    means = s["means"].detach().clone()
    for opt in set(optimizers.values()):
        opt.step()
    assert torch.equal(s["means"], means)


def test_temporal_opacity_adjustment_rewrites_centres_and_widths_after_the_backward_pass():
    """``adjust_temp_opa`` (``train.py:233-234``, ``replace_tensor_to_optimizer``): centres and widths restart
    their moments and miss the step's update; the other tensors keep theirs. ``on_step``, which a resumed
    run replays for its last step, no longer adjusts."""
    expert, scene = _expert(num_frames=30, start_duration=10, interval=10)
    expert.config.adjust_every, expert.config.adjust_until, expert.config.extract_every = 6, 100, 0
    s = expert.splats
    with torch.no_grad():
        s["dynamic"][:3] = True
        s["centers"][:3] = 0.0  # before the trained range: clamped in
    expert.on_step(6)
    assert s["centers"][:3].eq(0).all()
    optimizers = _with_moments_and_grads(expert)
    means_moment = _moment(optimizers, expert, "means").clone()
    expert.after_backward(6, optimizers)
    assert s["centers"][:3].gt(0).all()
    for key in ("centers", "widths"):
        assert _moment(optimizers, expert, key).eq(0).all() and s[key].grad is None
    assert s["means"].grad is not None and torch.equal(_moment(optimizers, expert, "means"), means_moment)


def test_a_growth_that_adds_keyframes_restarts_the_keyframe_moments():
    """``expand_duration`` replaces ``motion_xyz``, ``motion_rotation`` and the temporal opacity tensors in
    the optimiser (``c_gaussian_model.py:1286``); a growth that adds none leaves them alone."""
    expert, scene = _expert(num_frames=30, start_duration=10, interval=10)
    with torch.no_grad():
        expert.splats["dynamic"][:2] = True
    expert.keyframes = 7
    optimizers = _with_moments_and_grads(expert)
    quats = _moment(optimizers, expert, "motion_quats").clone()
    assert not expert._grow(optimizers)  # to 20 (model duration 21): still 7 keyframes
    assert torch.equal(_moment(optimizers, expert, "motion_quats"), quats)
    assert expert._grow(optimizers)  # to 30: 8
    for key in ("motion_means", "motion_quats", "centers", "widths"):
        assert _moment(optimizers, expert, key).eq(0).all(), key
    assert _moment(optimizers, expert, "means").abs().sum() > 0


def test_the_strategy_runs_the_schedule_events_of_the_expert_it_is_bound_to():
    """... and a conversion restarts the dynamic Gaussians' densification statistics
    (``c_gaussian_model.py:1213-1220``)."""
    expert, scene = _expert(num_frames=3)
    strategy = expert.strategy()
    assert strategy is expert.config.strategy
    strategy.densify_until = 0  # the statistics stay as set here
    calls = []

    def recorder(name, converts):
        return lambda step, optimizers: calls.append((name, step)) or converts

    expert.after_backward, expert.after_update = recorder("backward", False), recorder("update", True)
    n = expert.splats["means"].shape[0]
    with torch.no_grad():
        expert.splats["dynamic"][:3] = True
    state = strategy.initialize_state(scene.extent)
    state.update(grad2d=torch.ones(n), count=torch.ones(n), max_radii=torch.ones(n))
    info = {"renders": [], "views": []}
    strategy.step_post_backward(expert.splats, {}, state, 7, info)
    assert state["grad2d"].eq(1).all()  # no conversion
    strategy.step_post_optimizer(expert.splats, {}, state, 7, info)
    assert calls == [("backward", 7), ("update", 7)]
    for key in ("grad2d", "count", "max_radii"):
        assert state[key].tolist() == [0.0] * 3 + [1.0] * (n - 3)
    expert.config.strategy = ADCStrategy()
    with pytest.raises(ValueError, match="Ex4DGSStrategy.*config.strategy is a ADCStrategy"):
        expert.strategy()


def test_invisible_and_thin_pruning_runs_once_per_pass_over_the_trained_views():
    """``train.py:117-122, 237-241``: when the shuffled view stack of the frames trained so far is refilled
    after ``prune_invisible_interval``, that iteration prunes Gaussians never seen since creation and the
    thin ones. A pass is as many draws as the stack holds; growth lengthens the next pass."""
    expert, scene = _expert(num_frames=30, start_duration=10, grow_from=0, grow_every=50, interval=10)
    strategy = expert.config.strategy
    starts = []
    strategy.start_pass = starts.append
    g = torch.Generator().manual_seed(0)
    for step in range(1, 200):
        expert.select_views(step, scene.train, 1, g)
        expert.after_update(step, {})
    per_frame = len(scene.train) // 30  # 4 cameras
    # frames 0-10 (44 views) for three passes, the third grown at 100 mid-pass; then 0-20 (84)
    assert starts == [1, 1 + 11 * per_frame, 1 + 22 * per_frame, 1 + 33 * per_frame]
    assert expert.pass_left == starts[-1] + 21 * per_frame - 200


def test_select_views_refuses_another_view_list():
    expert, scene = _expert()
    with pytest.raises(ValueError, match="built for 12 training views, select_views got 11"):
        expert.select_views(1, scene.train[:-1], 1, torch.Generator())


def test_pruning_waits_for_a_pass_start_after_prune_from_and_outlasts_densification():
    """Pruning sits outside the original's densification block (``train.py:203`` vs ``237``) and masks the
    statistics of the survivors instead of restarting them (``prune_points``)."""
    expert, scene = _expert(num_frames=3)
    strategy = expert.config.strategy
    strategy.prune_from, strategy.densify_from, strategy.densify_until = 5, 10**9, 20  # no densification
    s = expert.splats
    with torch.no_grad():
        s["err_min_time"][:10] = -1.0  # never seen
        s["err_min_time"][10:] = 0.0
        s["radius_min"].fill_(100.0)
    optimizers = Optimizers(expert.param_groups()).for_splats(s)
    state = strategy.initialize_state(scene.extent)
    n = s["means"].shape[0]
    for step in (3, 7):
        strategy.start_pass(step - 1)  # the pass started earlier: no pruning at step
        strategy.step_post_backward(s, optimizers, state, step, {"renders": [], "views": []})
        assert s["means"].shape[0] == n
    strategy.start_pass(3)  # a pass starting before prune_from prunes nothing
    strategy.step_post_backward(s, optimizers, state, 3, {"renders": [], "views": []})
    assert s["means"].shape[0] == n
    accumulated = torch.arange(n, dtype=torch.float32)
    state.update(grad2d=accumulated.clone(), count=torch.ones(n), max_radii=accumulated.clone())
    strategy.start_pass(8)
    strategy.step_post_backward(s, optimizers, state, 8, {"renders": [], "views": []})
    assert s["means"].shape[0] == n - 10
    assert torch.equal(state["grad2d"], accumulated[10:])
    assert torch.equal(state["max_radii"], accumulated[10:])
    s["err_min_time"][:5] = -1.0
    strategy.start_pass(20)  # at densify_until: densification is over, pruning goes on
    strategy.step_post_backward(s, optimizers, state, 20, {"renders": [], "views": []})
    assert s["means"].shape[0] == n - 15


def test_the_last_step_starts_no_pruning_pass():
    """``train.py:237``: ``iteration < opt.iterations``; the expert reports no pass at the last step."""
    expert, scene = _expert(num_frames=3)
    expert.config.train = TrainConfig(iterations=13)
    starts = []
    expert.config.strategy.start_pass = starts.append
    g = torch.Generator().manual_seed(0)
    for step in range(1, 14):
        expert.select_views(step, scene.train, 1, g)
    assert starts == [1]  # 12 views a pass: the second pass starts at the last step, 13


def test_far_plane_culls_beyond_it_in_renders_and_shared_passes():
    """The rasterizer culls at view depth ``> far`` (``auxiliary.h:284``); a shared pass with another
    Ex4DGS expert gives the same image by zeroing those Gaussians' opacity."""
    from dataclasses import replace

    from moegs.moe.splat import expert_inputs, splat_experts
    from moegs.render.projection import camera_points

    expert, scene = _expert()
    other = Ex4DGSExpert.from_scene(scene, replace(expert.config, max_init_points=60))
    expert.eval(), other.eval()
    camera = scene.test[0].camera
    assert expert.config.far == 300.0 and camera.far > 300.0
    with torch.no_grad():
        depth = camera_points(expert.frame(camera.time).means, camera)[:, 2]
        cut = float(depth.median())
        expert.config = replace(expert.config, far=cut)  # drops the farther half
        image, out, _ = expert.render(camera, scene.background, return_stats=True)
        one = splat_experts(expert_inputs([expert, other], camera, scene.background), camera)
        full = rasterize(expert.frame(camera.time), camera, background=scene.background, antialiased=True)
    assert not out.info["visible"][depth >= cut].any() and out.info["visible"][depth < cut].any()
    assert one.passes == 1
    torch.testing.assert_close(one.images[0], image, atol=1e-5, rtol=0)
    torch.testing.assert_close(one.images[1], other.render(camera, scene.background)[0], atol=1e-5, rtol=0)
    assert (image - full.image).abs().max() > 0.05  # the far half was in view: culling it shows


def test_backtracking_of_one_gaussian_is_its_mean_pixel_error():
    expert, scene = _expert()
    s = expert.splats
    keep = torch.zeros(len(s["means"]), dtype=torch.bool)
    keep[0] = True
    with torch.no_grad():
        s["opacities"].data[~keep] = -30.0  # only Gaussian 0 is visible
        s["means"][0] = 0.0
        s["scales"][0] = math.log(0.3)
        s["opacities"][0] = 0.0
    view = scene.train[0]
    expert.train()
    rgb, out, _ = expert.render(view.camera, scene.background, return_stats=True)
    target = view.image()
    expert.observe(1, view, rgb, target, out)
    (rgb - target).abs().mean().backward()
    covered = out.alpha > 1e-6
    expected = (rgb - target).abs().mean(-1)[covered].mean()
    assert s["err_count"][0] == 1 and s["err_sum"][0].item() == pytest.approx(expected.item(), rel=1e-3)
    assert s["err_min_time"][0] == 0 and s["err_min"][0] < 1000  # seen with weight > 0.01: frame 0


def test_dynamic_split_moves_every_keyframe_and_resets_widths():
    expert, scene = _expert()
    s = expert.splats
    with torch.no_grad():
        s["dynamic"][0] = True
        s["widths"][0] = torch.tensor([5.0, 6.0])
        s["centers"][0] = torch.tensor([1.0, 3.0])
    strategy = expert.strategy()
    before = s["motion_means"][0].clone()
    mask = torch.zeros(len(s["means"]), dtype=torch.bool)
    mask[0] = True
    strategy._split(s, {}, mask)
    kids = slice(len(mask) - 1, None)
    assert s["means"].shape[0] == len(mask) + 1 and bool(s["dynamic"][kids].all())
    offsets = s["motion_means"][kids] - before  # identity keyframe rotations: one offset for all keyframes
    assert torch.allclose(offsets, offsets[:, :1].expand_as(offsets), atol=1e-6)
    assert torch.all(s["widths"][kids] == 2.0)
    lo, hi = expert.center_bounds()  # jittered centres clamped to the trained range (cgm:944)
    assert bool(s["centers"][kids].ge(lo).all() and s["centers"][kids].le(hi).all())


def test_groups_antialiased_render_and_radam():
    expert, scene = _expert()
    groups = expert.param_groups()
    assert {g.optimizer for g in groups} == {"adam"}  # quick: RAdam's warm-up outlasts 600 iterations
    paper = Ex4DGSExpert.from_scene(scene, Ex4DGSConfig(max_init_points=80)).param_groups()
    assert {(g.optimizer, g.eps) for g in paper} == {("radam", 1e-8)}  # torch.optim.RAdam(l, lr=0.001)
    trainable = {k for k, p in expert.splats.items() if p.requires_grad}
    assert set(Optimizers(groups).for_splats(expert.splats)) == trainable
    expert.eval()
    cam = scene.test[0].camera
    rgb, _, frame = expert.render(cam, scene.background)
    ref = rasterize(frame, cam, background=scene.background, antialiased=True).image
    assert torch.allclose(rgb, ref)


def test_trains_on_tiny_scene():
    from moegs.train.loop import train

    expert, scene = _expert(num_frames=3)
    expert.config.train = TrainConfig(iterations=30, lambda_dssim=0.2)
    result = train(expert, scene, progress=False)
    assert result["completed"] and math.isfinite(result["final_loss"]) and result["test"]["psnr"] > 14.0
    assert float(expert.splats["err_count"].max()) > 0


def test_an_interrupted_run_resumes_the_view_stack_and_schedule_exactly(tmp_path):
    """The stack, the pass counter and the armed conversion are checkpointed with the model, so a run
    stopped mid-pass (12 views a pass, stopped at 17) and resumed ends bit for bit as an uninterrupted one."""
    from moegs.train.loop import train

    def run(out, **kw):
        expert, scene = _expert(num_frames=3)
        expert.config.train = TrainConfig(iterations=30, lambda_dssim=0.2, checkpoint_every=10)
        return expert, train(expert, scene, out_dir=tmp_path / out, progress=False, **kw)

    full, _ = run("full")
    run("part", stop_after=17)
    resumed, result = run("part")
    assert result["resumed_from"] == 17 and result["completed"]
    a, b = full.state_dict(), resumed.state_dict()
    assert a.keys() == b.keys() and "view_stack" in a["_extra_state"]
    assert a.pop("_extra_state") == b.pop("_extra_state")
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_error_statistics_stop_with_the_densification_the_smallest_radius_goes_on():
    """``add_l1_ssim_stats`` sits inside ``iteration < densify_until_iter`` (``train.py:203, 215``),
    ``mark_prune_stats`` before it (``:200``): after the densification the best frames stay as they were,
    which ``prune_invisible`` then reads."""
    expert, scene = _expert(num_frames=3)
    expert.train()
    s, view = expert.splats, scene.train[0]
    for step, counted in ((expert.config.strategy.densify_until, False), (1, True)):
        rgb, out, _ = expert.render(view.camera, scene.background, return_stats=True)
        expert.observe(step, view, rgb, view.image(), out)
        rgb.sum().backward()
        assert bool(s["err_count"].gt(0).any()) == counted
        assert bool(s["radius_min"].lt(1000).any())


def test_the_motion_regulariser_reads_the_keyframes_in_use():
    """``train.py:159-161``: ``mean ||P_0 - P_k||`` over the ``keyframe_num`` columns the original allocates;
    ours allocates more, extrapolated past the last one in use."""
    expert, scene = _expert(num_frames=3)
    c, s = expert.config, expert.splats
    c.static_reg = 0.0
    with torch.no_grad():
        s["dynamic"][:2] = True
        s["motion_means"][:2] = 1.0
        s["motion_means"][:2, 5:] = 7.0  # past the 5 keyframes in use
    expert.keyframes = 5
    assert float(expert.regularization(c.reg_from + 1).detach()) == 0.0
    expert.keyframes = 6
    expected = c.motion_reg * 6.0 * math.sqrt(3) / 5  # one of the 5 differences is (6, 6, 6)
    assert float(expert.regularization(c.reg_from + 1).detach()) == pytest.approx(expected)


def test_the_dynamic_set_counts_its_own_optimiser_steps_from_the_first_conversion():
    """The dynamic tensors enter the original's optimiser at the first conversion
    (``c_gaussian_model.py:78-87, 439-449``): their step count, and so the bias corrections, start there."""
    expert, scene = _expert(num_frames=3)
    s = expert.splats
    optimizers = Optimizers(expert.param_groups())
    for step in range(3):
        if step == 2:
            with torch.no_grad():
                s["dynamic"][:2] = True
        optimizers.zero_grad()
        sum((p.float() ** 2).sum() for p in s.values() if p.requires_grad).backward()
        optimizers.step()
    state = optimizers.for_splats(s)["scales"].state[s["scales"]]
    assert (float(state["step"]), float(state["step_second"])) == (3, 1)
