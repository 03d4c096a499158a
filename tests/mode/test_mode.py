"""MoDE: weight spline and top-k gating by hand, attribute mixing, gradient blocking of the canonical
set, random warm-up, training and reloading through the one loop."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.mode import MoDEConfig, MoDEExpert, top_k_gates, weight_spline
from moegs.mode.expert import GATE_KEY
from moegs.train.checkpoint import load_expert
from moegs.train.evaluate import evaluate
from moegs.train.loop import train


def test_spline_hits_the_control_points_and_reproduces_lines():
    control = torch.tensor([[[0.0], [2.0], [1.0], [5.0]]])  # N=1, N_w=4, G=1
    for k in range(4):
        assert float(weight_spline(control, k / 3)) == pytest.approx(float(control[0, k, 0]))
    line = torch.tensor([[[1.0], [3.0], [5.0]]])  # Catmull-Rom (and one-sided ends) keep straight lines
    for t in (0.1, 0.37, 0.5, 0.93):
        assert float(weight_spline(line, t)) == pytest.approx(1.0 + 4.0 * t)
    # middle of segment 1 of [0, 2, 1, 5]: h00 = h01 = 1/2, h10 = 1/8, h11 = -1/8, m1 = (1-0)/2, m2 = (5-2)/2
    assert float(weight_spline(control, 0.5)) == pytest.approx(0.5 * 2 + 0.125 * 0.5 + 0.5 * 1 - 0.125 * 1.5)
    with pytest.raises(ValueError, match="N_w >= 2"):
        weight_spline(torch.zeros(1, 1, 2), 0.5)


def test_top_k_gates():
    scores = torch.tensor([[1.0, 3.0, 2.0], [0.0, 0.0, 5.0]])
    g = top_k_gates(scores, 2)
    torch.testing.assert_close(g.sum(-1), torch.ones(2))
    assert (g > 0).sum(-1).tolist() == [2, 2] and g[0, 0] == 0
    torch.testing.assert_close(g[0, 1:], torch.softmax(torch.tensor([3.0, 2.0]), 0))
    torch.testing.assert_close(top_k_gates(scores, 3), torch.softmax(scores, -1))
    assert top_k_gates(scores, 1).tolist() == [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    two = top_k_gates(torch.tensor([[0.3, -7.0]]), 2, std_normalize=True)  # code: gap fixed at sqrt(2)
    assert float(two[0, 0]) == pytest.approx(1 / (1 + math.exp(-math.sqrt(2))))
    with pytest.raises(ValueError, match="top-k"):
        top_k_gates(scores, 4)


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=3, cameras=3, size=32, num_points=120)


def make(scene, **kw) -> MoDEExpert:
    cfg = MoDEConfig.from_preset("quick-paper")  # the paper's wording: one gate for every mixed attribute
    cfg = replace(cfg, experts=("ed3dgs", "fourdgs"), **kw)  # E-D3DGS base: deforms from step 1
    mode = MoDEExpert.from_scene(scene, cfg)
    mode.on_step(5_000)  # both members deforming, warm-up over
    return mode.eval()


def force(mode: MoDEExpert, expert: int) -> None:
    with torch.no_grad():
        control = mode.splats[GATE_KEY]
        control.zero_()
        control[:, :, expert] = 10.0


def test_one_hot_gates_give_each_experts_own_deformation(scene):
    mode = make(scene, top_k=1)
    assert mode.splats is mode.base.splats is mode.members[1].splats  # one shared canonical set
    for index, member in enumerate(mode.members):
        force(mode, index)
        with torch.no_grad():
            got = mode.frame(0.4)
            own = member.deform(mode.splats, 0.4)
        for attr in ("means", "quats", "scales"):
            torch.testing.assert_close(getattr(got, attr), getattr(own, attr))
        base = mode.base.deform(mode.splats, 0.4)
        torch.testing.assert_close(got.opacities, base.opacities.detach())  # opacity, SH: the base's


def test_only_the_base_updates_the_canonical_positions(scene):
    mode = make(scene, top_k=1)
    force(mode, 1)  # all weight on the non-base expert
    mode.frame(0.6).means.sum().backward()
    grad = mode.splats["means"].grad
    assert grad is None or grad.abs().sum() == 0
    mode.zero_grad()
    force(mode, 0)
    mode.frame(0.6).means.sum().backward()
    assert mode.splats["means"].grad.abs().sum() > 0


def test_random_warmup_while_training_then_spline(scene):
    mode = make(scene, warmup_iterations=10)
    mode.deform_from = 4_995
    mode.train()
    torch.manual_seed(0)
    a, b = mode.gates(0.5), mode.gates(0.5)
    assert not torch.equal(a, b)  # fresh random scores per call during the warm-up
    mode.on_step(5_010)
    torch.testing.assert_close(mode.gates(0.5), mode.gates(0.5))
    mode.eval()
    expected = top_k_gates(weight_spline(mode.splats[GATE_KEY], 0.5), 2)
    torch.testing.assert_close(mode.gates(0.5), expected)


def test_code_preset_gates_position_and_rotation_separately(scene):
    cfg = replace(MoDEConfig.from_preset("code"), experts=("ed3dgs", "fourdgs"))
    assert cfg.mixed == ("means", "quats") and cfg.num_gates == 4 and cfg.std_normalize
    assert MoDEConfig.from_preset("paper").mixed == ("means", "quats", "scales")
    with pytest.raises(ValueError, match=">= 2 of"):
        MoDEConfig(experts=("fourdgs",))
    with pytest.raises(ValueError, match=">= 2 of"):
        MoDEConfig(experts=("fourdgs", "stg"))


def test_code_preset_mixes_position_and_rotation_by_their_own_gates(scene):
    """Gate channels ``[0:E]`` choose the position, ``[E:2E]`` the rotation (the code's spline layout)."""
    mode = make(scene, top_k=1, mixed=("means", "quats"), gate_per_attribute=True)
    e = len(mode.members)
    with torch.no_grad():
        control = mode.splats[GATE_KEY]
        control.zero_()
        control[:, :, 0] = 10.0  # position: the base
        control[:, :, e + 1] = 10.0  # rotation: the second expert
        got = mode.frame(0.4)
        base, other = (m.deform(mode.splats, 0.4, raw_quats=True) for m in mode.members)
    assert not torch.allclose(base.means, other.means) and not torch.allclose(base.quats, other.quats)
    torch.testing.assert_close(got.means, base.means)
    torch.testing.assert_close(got.quats, torch.nn.functional.normalize(other.quats, dim=-1))


def test_schedules_restart_with_the_base_fine_stage(scene):
    """The code counts the fine stage's iterations from 1 again (``specs/official_moegs.md`` section 6):
    with a 4DGaussians base, every group's schedule (the members' and the gate control weights') starts
    where the base's fine stage does; an E-D3DGS base has no stage (a 4DGaussians member keeps its own)."""
    groups = {g.name: g.start_step for g in make(scene).param_groups()}
    assert groups["means"] == groups[GATE_KEY] == 0 and groups["fourdgs.deformation"] > 0
    cfg = replace(MoDEConfig.from_preset("quick"), experts=("fourdgs", "grid4d"))
    mode = MoDEExpert.from_scene(scene, cfg)
    coarse = mode.base.config.coarse_iterations
    assert mode.on_step(coarse + 1)  # fine stage: fresh optimisers
    groups = {g.name: g.start_step for g in mode.param_groups()}
    assert {"grid4d.deform", GATE_KEY} <= set(groups) and set(groups.values()) == {coarse}, groups


def test_trains_and_reloads(scene, tmp_path):
    cfg = MoDEConfig.from_preset("quick")
    cfg = replace(
        cfg, experts=("ed3dgs", "fourdgs"), warmup_iterations=5, train=replace(cfg.train, iterations=30)
    )
    mode = MoDEExpert.from_scene(scene, cfg)
    groups = [g.name for g in mode.param_groups()]
    assert groups.count(GATE_KEY) == 1 and groups[0] == "means"  # the base (E-D3DGS) groups first
    start = evaluate(mode.eval(), scene.test, scene.background)["psnr"]
    result = train(mode, scene, out_dir=tmp_path, progress=False)
    assert result["completed"] and result["test"]["psnr"] > start + 1.0, (start, result["test"]["psnr"])
    assert mode.deform_from == 1
    again, state = load_expert(tmp_path, scene)
    assert again.num_gaussians == mode.num_gaussians and state["step"] == 30
    assert again.deform_from == 1  # checkpointed: a resumed run keeps the warm-up where it was
    with torch.no_grad():
        torch.testing.assert_close(again.frame(0.5).means, mode.eval().frame(0.5).means)


def _scene_named(name: str, dataset: str):
    from types import SimpleNamespace

    return SimpleNamespace(name=name, dataset=dataset)


def test_members_take_the_code_settings_over_their_dataset_recipe():
    """The MoDE code gives its Grid4D member Grid4D's D-NeRF geometry with one hidden layer and its
    E-D3DGS member a 64-wide net without a warm-up, on every dataset (``arguments_MoDE/__init__.py``)."""
    from moegs.experts.base import quick_step
    from moegs.mode.expert import CODE_ITERATIONS, member_config
    from moegs.recipes import config_for

    n3v = _scene_named("n3v:cook_spinach", "n3v")
    grid = member_config("grid4d", n3v, MoDEConfig.from_preset("code"))
    own = config_for("grid4d", "n3v:cook_spinach", "paper").config
    assert (own.bound, own.depth, own.temporal_desired) == (30.0, 0, (512, 512, 128))  # Grid4D's N3V recipe
    assert (grid.bound, grid.depth, grid.temporal_base, grid.temporal_desired) == (
        1.6,
        1,
        (8, 8, 8),
        (32, 32, 16),
    )
    assert grid.network_lr_scale == 5.0 and grid.train == MoDEConfig.from_preset("code").train
    stand_in = member_config(
        "grid4d", _scene_named("synthetic:n3v_like", "n3v"), MoDEConfig.from_preset("code")
    )
    assert stand_in.bound is None and stand_in.depth == 1  # a stand-in's bound still comes from the scene

    quick = MoDEConfig.from_preset("quick")
    emb = member_config("ed3dgs", n3v, MoDEConfig.from_preset("code"))
    assert (emb.width, emb.deform_from, emb.coarse_to_fine_until, emb.coarse_min_embeddings) == (
        64,
        0,
        20_000,
        False,
    )
    assert "opacities" not in emb.deform
    emb_quick = member_config("ed3dgs", n3v, quick)
    assert emb_quick.coarse_to_fine_until == quick_step(20_000, CODE_ITERATIONS)  # the same share of the run
    base = member_config("fourdgs", n3v, quick)  # no member fields: the base's own quick recipe
    assert base == replace(config_for("fourdgs", "n3v:cook_spinach", "quick").config, train=quick.train)


def test_member_fields_survive_the_config_file(tmp_path):
    from moegs.io.config import from_dict, to_dict
    from moegs.mode.expert import member_config

    cfg = MoDEConfig.from_preset("quick")
    again = from_dict(MoDEConfig, to_dict(cfg))
    scene = _scene_named("n3v:cook_spinach", "n3v")
    assert member_config("grid4d", scene, again) == member_config("grid4d", scene, cfg)
