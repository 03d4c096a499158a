"""DeformableGS: network layout, warm-up, activated-space deltas, AST, learning rates, presets."""

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.experts.deformable import DeformableConfig, DeformableExpert, DeformableField, ast_scale
from moegs.experts.gaussian_params import activate
from moegs.io import from_dict, to_dict
from moegs.train.schedules import group_lr


def _small_config(**kw) -> DeformableConfig:
    cfg = DeformableConfig.from_preset("quick")
    for k, v in kw.items():
        setattr(cfg, k, v)
    return cfg


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=2, size=16)


def test_network_layout_matches_the_original():
    blender = DeformableField()  # PE(x) 63 + timenet 30 = 93 inputs
    widths = [layer.in_features for layer in blender.trunk.layers]
    assert widths == [93, 256, 256, 256, 256, 256 + 93, 256, 256]
    assert sum(p.numel() for p in blender.parameters()) == 522_280  # spec: ~0.52M (blender)
    real = DeformableField(time_freqs=10, timenet_out=None)  # PE(x) 63 + PE(t) 21 = 84 inputs
    assert real.trunk.layers[0].in_features == 84 and real.timenet is None
    assert sum(p.numel() for p in real.parameters()) == 506_378  # spec: ~0.51M (real)
    out = blender(torch.rand(5, 3), torch.rand(5, 1))
    assert {k: tuple(v.shape) for k, v in out.items()} == {"dx": (5, 3), "drot": (5, 4), "dscale": (5, 3)}


def test_field_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"t \[N, 1\]"):
        DeformableField()(torch.rand(5, 3), torch.rand(5))


def test_warm_up_renders_the_canonical_gaussians(scene):
    expert = DeformableExpert.from_scene(scene, _small_config(warm_up=10))
    expert.on_step(9)
    assert not expert.deforming
    got, want = expert.frame(0.5), activate(expert.splats, 0)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        assert torch.equal(getattr(got, name), getattr(want, name))


def test_deltas_are_added_in_activated_space(scene):
    expert = DeformableExpert.from_scene(scene, _small_config(warm_up=10))
    expert.on_step(10)
    assert expert.deforming
    frame = expert.frame(0.25)
    s = expert.splats
    d = expert.fields(s["means"].detach(), torch.full((len(s["means"]), 1), 0.25))
    assert torch.allclose(frame.means, s["means"] + d["dx"])
    assert torch.allclose(frame.scales, torch.exp(s["scales"]) + d["dscale"])
    assert torch.allclose(frame.quats, torch.nn.functional.normalize(s["quats"], dim=-1) + d["drot"])
    assert not torch.allclose(frame.quats.norm(dim=-1), torch.ones(len(s["means"])))  # not renormalised


def test_small_deltas_at_the_start_of_training(scene):
    torch.manual_seed(0)
    expert = DeformableExpert.from_scene(scene, DeformableConfig())  # paper network, default init
    expert.on_step(expert.config.warm_up)
    canonical, frame = activate(expert.splats, 0), expert.frame(0.5)
    assert (frame.means - canonical.means).abs().max() < 0.2
    assert (frame.means - canonical.means).abs().mean() < 0.06


def test_canonical_xyz_is_detached_from_the_network(scene):
    expert = DeformableExpert.from_scene(scene, _small_config(warm_up=0))
    expert.on_step(1)
    expert.frame(0.5).means.sum().backward()
    assert torch.equal(expert.splats["means"].grad, torch.ones_like(expert.splats["means"]))


def test_ast_noise_schedule_and_gating(scene):
    assert [ast_scale(s) for s in (0, 10_000, 20_000, 30_000)] == pytest.approx([0.1, 0.05, 0.0, 0.0])
    expert = DeformableExpert.from_scene(scene, _small_config(warm_up=0, time_noise=True))
    expert.on_step(1)
    assert expert.time_interval == pytest.approx(1 / len(scene.train))
    expert.train()
    noisy = [expert.deltas(0.5)["dx"] for _ in range(2)]
    assert not torch.allclose(noisy[0], noisy[1])  # a new draw per call while training
    times = []
    hook = expert.fields.register_forward_pre_hook(lambda module, args: times.append(args[1]))
    expert.deltas(0.5)
    hook.remove()
    (time,) = times
    assert time.shape == (expert.num_gaussians, 1) and not torch.allclose(time, torch.full_like(time, 0.5))
    assert torch.equal(time, torch.full_like(time, float(time[0])))  # one draw shared by every Gaussian
    expert.eval()
    assert torch.equal(expert.deltas(0.5)["dx"], expert.deltas(0.5)["dx"])  # no noise at evaluation
    # the noise anneals to zero over the config's time_noise_steps
    short = DeformableExpert.from_scene(scene, _small_config(warm_up=0, time_noise=True, time_noise_steps=10))
    short.train()
    short.on_step(10)
    assert torch.equal(short.deltas(0.5)["dx"], short.deltas(0.5)["dx"])


def test_learning_rates_follow_the_original(scene):
    expert = DeformableExpert.from_scene(scene, DeformableConfig())
    groups = {g.name: g for g in expert.param_groups()}
    assert group_lr(groups["deform"], 0) == pytest.approx(8e-4)  # 1.6e-4 x spatial_lr_scale 5
    assert group_lr(groups["deform"], 40_000) == pytest.approx(1.6e-6)  # final rate is not scaled
    assert group_lr(groups["means"], 0) == pytest.approx(8e-4)
    assert group_lr(groups["means"], 30_000) == pytest.approx(8e-6)
    assert groups["scales"].lr == pytest.approx(5e-3)  # scaling_lr 0.001 x 5 (scene/gaussian_model.py:124)
    assert {p for p in groups["deform"].params} == set(expert.fields.parameters())


def test_presets_and_config_round_trip():
    presets = DeformableConfig.presets()
    assert {"quick", "paper", "paper-dnerf", "paper-n3v", "paper-hypernerf"} <= set(presets)
    paper, real = DeformableConfig.from_preset("paper"), DeformableConfig.from_preset("paper-hypernerf")

    def key(c):
        return c.time_freqs, c.timenet_out, c.time_noise, c.train.iterations

    assert key(paper) == (6, 30, False, 40_000)
    assert key(real) == (10, None, True, 20_000)
    quick = DeformableConfig.from_preset("quick")
    assert from_dict(DeformableConfig, to_dict(quick)) == quick


def test_ast_divides_by_the_views_left_in_the_epochs_stack(scene):
    """``train.py:79-85`` takes ``1 / len(viewpoint_stack)`` before each pop: 1/n, 1/(n-1), ..., 1/1, then
    1/n again after the refill; the loop passes the sampler's stack to the expert every step."""
    from dataclasses import replace

    from moegs.train.config import TrainConfig
    from moegs.train.loop import TrainingRun

    n = len(scene.train)
    config = DeformableConfig(time_noise=True, warm_up=0, train=TrainConfig(iterations=n + 2))
    expert = DeformableExpert.from_scene(scene, config)
    assert expert.time_interval == 1 / n  # before any step: the whole stack
    run = TrainingRun(expert, scene, config.train, None)
    seen = []
    expert.train()
    for step in range(1, n + 3):
        run.iteration(step)
        seen.append(expert.time_interval)
    assert seen == [1 / k for k in range(n, 0, -1)] + [1 / n, 1 / (n - 1)]
    whole = DeformableExpert.from_scene(scene, replace(config, time_noise_over_left=False))
    whole.on_views(3)
    assert whole.time_interval == 1 / n  # the option keeps the whole stack
