"""Gate-aware pruning and lifting on a tiny scene: importance is a per-Gaussian gate sensitivity, pruning
removes exactly the least important rows from experts and router alike, responsibilities are convex
shares that reproduce by hand, and the fused frame scales opacity by them."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene, untrained_experts

from moegs.experts import get_expert_class
from moegs.moe import MoEGS, RouterConfig, compute_responsibilities, gate_importance, lift, prune
from moegs.render import rasterize
from moegs.render.projection import rgb_to_sh0


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=3, size=24, num_points=100)


def model(scene, variant="vapr", names=("static", "mcmc")) -> MoEGS:
    m = MoEGS(untrained_experts(scene, names), replace(RouterConfig.from_preset("quick"), variant=variant))
    torch.manual_seed(3)
    with torch.no_grad():
        for p in m.router.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return m


@pytest.mark.parametrize("variant", ["vapr", "volume"])
def test_importance_is_zero_for_gaussians_no_view_sees(scene, variant):
    m = model(scene, variant)
    with torch.no_grad():  # push one static Gaussian far behind every camera ring: never splatted
        m.experts[0].splats["means"][0] = torch.tensor([0.0, 0.0, 50.0])
    scores = gate_importance(m, scene.train[:3], scene.background)
    assert [s.shape[0] for s in scores] == [e.num_gaussians for e in m.experts]
    assert scores[0][0] == 0 and (scores[0] > 0).sum() > 10
    # mcmc: rows of the model of t=0 only are seen by views at t=0
    assert (scores[1] > 0).any()


def test_importance_is_the_mean_over_views(scene):
    """``E_i = 1/|D| sum_v ...``: a threshold means the same whatever the number of views scored."""
    m = model(scene)
    one, two = (gate_importance(m, [v], scene.background) for v in scene.train[:2])
    both = gate_importance(m, scene.train[:2], scene.background)
    for k in range(len(both)):
        torch.testing.assert_close(both[k], (one[k] + two[k]) / 2)
        assert (both[k] > 0).any()


@pytest.mark.parametrize("k", [0, 1, 2])
def test_importance_is_the_norm_of_the_own_gate_gradient(scene, k):
    """``E_i`` of expert ``k`` by hand: the L2 norm of the gradient of expert ``k``'s own gate map (summed
    over pixels) with respect to row ``i`` of both routing parameters, ``w`` and ``w_time``. Three experts:
    with two, the gates sum to one and the other expert's gate has the same gradient norm."""
    m = model(scene, names=("static", "mcmc", "static"))
    view = next(v for v in scene.train if v.camera.time == 1.0)  # w_time enters as t * w_time
    scores = gate_importance(m, [view], scene.background)
    w = m.router.weights
    gates = m.render(view.camera, scene.background).gates
    d_mix, d_time = torch.autograd.grad(gates[k].sum(), [w.mix[k], w.time[k]])
    expected = torch.sqrt((d_mix**2).sum(1) + (d_time**2).sum(1))
    assert (expected > 0).sum() > 10 and (d_time != 0).any()
    torch.testing.assert_close(scores[k], expected)


def test_pruning_keeps_the_responsibilities_of_the_rows_it_keeps(scene):
    """Responsibilities computed before pruning follow the kept rows, so a pruned model still lifts."""
    m = model(scene)
    views = scene.train[:3]
    resp = [r.clone() for r in compute_responsibilities(m, views, scene.background)]
    scores = gate_importance(m, views, scene.background)
    prune(m, replace(scene, train=views), ratio=0.5)
    for k, (score, before) in enumerate(zip(scores, resp, strict=True)):
        kept = torch.sort(torch.argsort(score, stable=True)[int(0.5 * len(score)) :]).values
        torch.testing.assert_close(m.responsibilities[k], before[kept])
    assert len(lift(m, 0.0)) == sum(len(e.frame(0.0)) for e in m.experts)


def test_ratio_pruning_drops_the_least_important_rows_everywhere(scene):
    m = model(scene)
    views = scene.train[:3]
    scores = gate_importance(m, views, scene.background)
    before = [e.num_gaussians for e in m.experts]
    kept_means = (
        m.experts[0].splats["means"][torch.argsort(scores[0], stable=True)[int(0.55 * before[0]) :]].clone()
    )
    report = prune(m, replace(scene, train=views), ratio=0.55)
    assert report["before"] == before
    assert report["after"] == [n - int(0.55 * n) for n in before]
    assert [p.shape[0] for p in m.router.weights.mix] == report["after"]
    assert [p.shape[0] for p in m.router.weights.time] == report["after"]
    assert set(map(tuple, m.experts[0].splats["means"].tolist())) == set(map(tuple, kept_means.tolist()))
    out = m.render(scene.test[0].camera, scene.background)  # still renders
    assert torch.isfinite(out.image).all()


def test_threshold_pruning_and_bad_arguments(scene):
    m = model(scene)
    report = prune(m, scene, threshold=float("inf"), max_views=2)
    assert report["after"] == [0, 0] or sum(report["after"]) == 0
    with pytest.raises(ValueError, match="ratio must be in"):
        prune(model(scene), scene, ratio=1.5)
    with pytest.raises(ValueError, match="no per-Gaussian routing parameters|has none"):
        prune(model(scene, "pixel"), scene, ratio=0.5)


@pytest.mark.parametrize("k", [0, 1])
def test_responsibilities_match_a_brute_force_sum(scene, k):
    """R for one Gaussian of expert ``k``, summed by hand from its render and expert ``k``'s gate."""
    m = model(scene, names=("static", "static"))
    view = scene.train[1]
    resp = compute_responsibilities(m, [view], scene.background)
    assert all(((r >= 0) & (r <= 1)).all() for r in resp)
    with torch.no_grad():
        gates = m.render(view.camera, scene.background).gates
        frame = m.experts[k].frame(view.camera.time)
        j = int(torch.argmax(rasterize(frame, view.camera, return_stats=True).info["contrib"]))
        one_hot = torch.zeros(len(frame), 1)
        one_hot[j] = 1.0
        contrib = rasterize(frame.with_colors(one_hot), view.camera).image[..., 0]  # T_j alpha_j per pixel
        expected = (gates[k] * contrib).sum() / contrib.sum()
    assert resp[k][j] == pytest.approx(float(expected), abs=1e-4)


def test_responsibilities_land_on_the_rows_of_the_views_time(scene):
    """Per-frame 3DGS-MCMC: a view at t = 1 lifts onto the model of t = 1, not onto the model of t = 0."""
    m = model(scene)
    view = next(v for v in scene.train if v.camera.time == 1.0)
    resp = compute_responsibilities(m, [view], scene.background)[1]
    rows = m.experts[1].frame_rows(1.0)
    others = torch.ones(len(resp), dtype=torch.bool)
    others[rows] = False
    assert (resp[rows] > 0).any() and (resp[others] == 0).all() and others.any()


def test_responsibilities_are_saved_with_the_router(scene, tmp_path):
    from moegs.io import save_checkpoint
    from moegs.moe import load_moe
    from moegs.moe.model import ROUTER_CHECKPOINT

    m = model(scene)
    resp = compute_responsibilities(m, scene.train[:2], scene.background)
    save_checkpoint(tmp_path / ROUTER_CHECKPOINT, m.checkpoint_state())
    loaded = load_moe(tmp_path, m.experts).responsibilities
    assert loaded is not None and all(torch.equal(a, b) for a, b in zip(loaded, resp, strict=True))


def test_lift_scales_opacity_and_needs_responsibilities(scene):
    m = model(scene)
    with pytest.raises(ValueError, match="compute_responsibilities"):
        lift(m, 0.0)
    resp = compute_responsibilities(m, scene.train[:3], scene.background)
    fused = lift(m, 1.0)
    parts = [e.frame(1.0) for e in m.experts]
    assert len(fused) == sum(len(p) for p in parts)
    rows = m.experts[1].frame_rows(1.0)
    expected = torch.cat([parts[0].opacities * resp[0], parts[1].opacities * resp[1][rows]])
    torch.testing.assert_close(fused.opacities, expected)
    assert rasterize(fused, scene.test[0].camera).image.shape == (24, 24, 3)


def test_lift_gives_an_rgb_expert_the_dc_term_of_the_others_sh(scene):
    """STG ``color='lite'`` splats RGB; fused with an SH expert its colours become the DC coefficient (the
    same colour under the plain renderer) and its higher bands zero, while the SH expert keeps its bands."""
    stg = get_expert_class("stg")
    cfg = stg.config_class.from_preset("quick")
    lite = stg.from_scene(scene, replace(cfg, color="lite")).eval()
    static = untrained_experts(scene, ("static",))[0]
    static.active_sh_degree = 2  # as after training: 9 SH coefficients
    m = MoEGS([static, lite], RouterConfig.from_preset("quick"))
    compute_responsibilities(m, scene.train[:2], scene.background)
    fused = lift(m, 1.0)
    sh, rgb = m.experts[0].frame(1.0).sh, m.experts[1].frame(1.0).colors
    n = len(sh)
    assert sh.shape[1] == 9 and fused.sh.shape[1:] == sh.shape[1:]
    torch.testing.assert_close(fused.sh[:n], sh)
    torch.testing.assert_close(fused.sh[n:, 0], rgb_to_sh0(rgb))
    assert (fused.sh[n:, 1:] == 0).all()
