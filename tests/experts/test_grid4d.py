"""Grid4D: network, rigid warp, activated-space deltas, perturbation regularisers, learning rates."""

import math

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.experts.gaussian_params import activate
from moegs.experts.grid4d import Grid4DConfig, Grid4DExpert, Grid4DNetwork, perturbation_loss, rigid_warp
from moegs.io import from_dict, to_dict
from moegs.train.schedules import group_lr


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=2, size=16)


def _expert(scene, **kw) -> Grid4DExpert:
    cfg = Grid4DConfig.from_preset("quick")
    for k, v in kw.items():
        setattr(cfg, k, v)
    return Grid4DExpert.from_scene(scene, cfg)


def test_network_sizes_match_the_spec():
    assert sum(p.numel() for p in Grid4DNetwork(32, 192, depth=0).parameters()) == 61_454  # spec ~61k
    assert sum(p.numel() for p in Grid4DNetwork(32, 192, depth=1).parameters()) == 127_246  # spec ~127k


def test_attention_range_and_identity_offset():
    net = Grid4DNetwork(4, 6, width=8)
    with torch.no_grad():
        a = net.attention(torch.randn(100, 4))
        plain = Grid4DNetwork(4, 6, width=8, directional=False).attention(torch.randn(50, 4))
    assert -1 < float(a.min()) < 0 < float(a.max()) < 1  # directional: 2 sigmoid - 1
    assert 0 < float(plain.min()) and float(plain.max()) < 1
    with torch.no_grad():  # ReLU(Linear(h_t)) * a: the temporal features are non-negative
        h = net.temporal_mlp(torch.randn(100, 6))
    assert float(h.min()) == 0.0 and float(h.max()) > 0
    with torch.no_grad():
        for p in net.heads.parameters():
            p.zero_()
    out = net(torch.randn(3, 4), torch.randn(3, 6))
    assert out["warp"].tolist() == [[1.0, 0, 0, 0, 0, 0, 0]] * 3
    assert out["drot"].abs().sum() == 0 and out["dscale"].abs().sum() == 0


def test_attention_multiplies_the_temporal_features():
    torch.manual_seed(0)
    net = Grid4DNetwork(4, 6, width=8)
    h_xyz, h_t = torch.randn(2, 4), torch.randn(2, 6)
    hidden = net.temporal_mlp(h_t) * (2 * torch.sigmoid(net.spatial_mlp(h_xyz)) - 1)
    assert torch.allclose(net(h_xyz, h_t)["dscale"], net.heads.heads["dscale"](hidden))


def test_rigid_warp_hand_checked():
    half = math.sqrt(0.5)
    warp = torch.tensor([[2 * half, 0.0, 0.0, 2 * half, 1.0, 0.0, -1.0]])  # 90 deg about z (unnormalised q)
    # R (1, 2, 3) = (-2, 1, 3), plus t = (1, 0, -1)
    assert rigid_warp(torch.tensor([[1.0, 2.0, 3.0]]), warp)[0].tolist() == pytest.approx([-1.0, 1.0, 2.0])


def test_perturbation_loss_subsample_and_value():
    sizes = []

    def encode(p):
        sizes.append(p.shape[0])
        return 2.0 * p

    points = torch.zeros(50, 2)
    value = perturbation_loss(encode, points, torch.tensor([0.1, 0.0]), ratio=0.1)
    assert sizes == [5, 5]  # one moved and one original batch of int(0.1 * 50) rows
    assert 0 < float(value) <= 4 * 0.1**2  # ||2 d||^2 with |d_x| <= 0.1, d_y = 0
    sizes.clear()
    perturbation_loss(encode, points, torch.tensor([0.1, 0.1]), ratio=1.0)
    assert sizes == [50, 50]
    inputs = []

    def record(p):
        inputs.append(p)
        return 2.0 * p

    value = perturbation_loss(record, torch.rand(40, 3), torch.tensor([0.1, 0.2, 0.3]), ratio=1.0)
    moved, original = inputs
    offsets = moved - original
    assert (offsets.abs() <= torch.tensor([0.1, 0.2, 0.3])).all()
    assert (offsets < 0).any() and (offsets > 0).any()  # U(-p, p), both ways
    # the squared norm of each row's change (summed over channels), averaged over rows
    assert float(value) == pytest.approx(float((2.0 * offsets).square().sum(-1).mean()))


def test_warm_up_then_deltas_in_activated_space(scene):
    expert = _expert(scene, warm_up=5)
    expert.on_step(4)
    assert torch.equal(expert.frame(0.3).means, activate(expert.splats, 0).means)
    expert.on_step(5)
    s = expert.splats
    frame = expert.frame(0.3)
    d = expert.fields(s["means"].detach(), torch.full((len(s["means"]), 1), 0.3))
    assert torch.allclose(frame.means, rigid_warp(s["means"], d["warp"]))
    assert torch.allclose(frame.scales, torch.exp(s["scales"]) + d["dscale"])
    assert torch.allclose(frame.quats, torch.nn.functional.normalize(s["quats"], dim=-1) + d["drot"])
    # MoDE's Grid4D member adds dr to the raw canonical quaternion (r_can + d_rotation)
    raw = expert.deform({**s, "quats": 2 * s["quats"]}, 0.3, raw_quats=True)
    assert torch.allclose(raw.quats, 2 * s["quats"] + d["drot"])


def test_positions_learn_through_the_warp_and_not_through_the_hash_grids(scene):
    """Grid4D's encoder reads ``xyz.detach()``: the canonical positions get gradients only through the
    rigid warp of themselves."""
    expert = _expert(scene, warm_up=0)
    expert.on_step(1)
    seen = []
    hook = expert.fields.register_forward_pre_hook(lambda module, args: seen.append(args[0].requires_grad))
    expert.frame(0.3).means.sum().backward()
    hook.remove()
    assert seen == [False]
    assert expert.splats["means"].grad is not None and expert.splats["means"].grad.abs().sum() > 0


def test_zero_heads_give_the_canonical_frame(scene):
    expert = _expert(scene, warm_up=0)
    with torch.no_grad():
        for p in expert.fields.network.heads.parameters():
            p.zero_()
    expert.on_step(1)
    frame, canonical = expert.frame(0.7), activate(expert.splats, 0)
    assert torch.allclose(frame.means, canonical.means, atol=1e-6)
    assert torch.equal(frame.scales, canonical.scales) and torch.equal(frame.quats, canonical.quats)


def test_encoder_inputs_time_mapping(scene):
    expert = _expert(scene)
    xyz, xyzt = expert.fields.coordinates(torch.zeros(2, 3), torch.tensor([[0.0], [1.0]]))
    assert xyzt[:, 3].tolist() == pytest.approx([-0.9 * 1.6, 0.9 * 1.6])


def test_regularization_gates(scene):
    expert = _expert(scene, warm_up=3)
    expert.train()
    expert.on_step(2)
    expert.frame(0.5)
    assert float(expert.regularization(2)) == 0.0  # warm-up
    expert.on_step(3)
    expert.frame(0.5)
    reg = expert.regularization(3)
    assert float(reg.detach()) > 0
    reg.backward()
    assert expert.fields.encoder.spatial.embeddings.grad.abs().sum() > 0
    gated = _expert(scene, warm_up=0, reg_after_densify=True)
    gated.train()
    gated.on_step(gated.config.strategy.densify_until)
    gated.frame(0.5)
    assert float(gated.regularization(gated.step)) == 0.0
    gated.on_step(gated.config.strategy.densify_until + 1)
    gated.frame(0.5)
    assert float(gated.regularization(gated.step).detach()) > 0


def test_learning_rates_follow_the_original(scene):
    expert = Grid4DExpert.from_scene(scene, Grid4DConfig(spatial_log2_size=12, temporal_log2_size=12))
    groups = {g.name: g for g in expert.param_groups()}
    assert group_lr(groups["means"], 0) == pytest.approx(8e-4)  # 1.6e-4 x 5
    assert group_lr(groups["means"], 35_000) == pytest.approx(8e-6)
    assert group_lr(groups["deform"], 0) == pytest.approx(8e-4)  # 1.6e-4 x network_lr_scale 5
    assert group_lr(groups["deform"], 45_000) == pytest.approx(1.6e-6)
    assert group_lr(groups["grid"], 0) == pytest.approx(8e-3)  # 1.6e-4 x grid_lr_scale 50
    assert group_lr(groups["grid"], 45_000) == pytest.approx(8e-5)
    assert set(groups["grid"].params) == set(expert.fields.encoder.parameters())


def test_presets_and_config_round_trip():
    assert {"quick", "paper", "paper-dnerf", "paper-n3v", "paper-hypernerf"} <= set(Grid4DConfig.presets())
    n3v = Grid4DConfig.from_preset("paper-n3v")
    assert (n3v.bound, n3v.temporal_desired, n3v.reg_after_densify) == (30.0, (512, 512, 128), True)
    quick = Grid4DConfig.from_preset("quick")
    assert from_dict(Grid4DConfig, to_dict(quick)) == quick
    assert from_dict(Grid4DConfig, to_dict(n3v)) == n3v


def test_the_bound_comes_from_the_scene_where_grid4d_has_no_configuration():
    """D-NeRF, N3V and HyperNeRF keep their configured bounds; Panoptic, Technicolor and the stand-ins
    derive it from the scene's bounds (the N3V bound of 30 left most of each grid axis empty there)."""
    from helpers.scenes import tiny_scene

    from moegs.experts.grid4d import BOUND_MARGIN, Grid4DExpert, scene_bound
    from moegs.recipes import config_for

    assert config_for("grid4d", "dnerf:mutant", "paper").config.bound == 1.6
    assert config_for("grid4d", "n3v:sear_steak", "paper").config.bound == 30.0
    for scene in ("synthetic:n3v_like", "panoptic:basketball", "technicolor:birthday"):
        assert config_for("grid4d", scene, "quick").config.bound is None, scene
    scene = tiny_scene()
    config = config_for("grid4d", "synthetic:n3v_like", "quick").config
    expert = Grid4DExpert.from_scene(scene, config)
    assert expert.config.bound == scene_bound(scene) == round(BOUND_MARGIN * float(scene.bbox.abs().max()), 3)
    assert expert.fields.encoder.bound == expert.config.bound
