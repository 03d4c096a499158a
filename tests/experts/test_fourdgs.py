"""4DGaussians: field sizes, coarse/fine stages, raw-space deltas, plane regularisers, schedules, strategy."""

import math

import pytest
import torch
from helpers.scenes import tiny_scene
from torch import nn

from moegs.experts.fourdgs import FourDGSConfig, FourDGSExpert, FourDGSField, FourDGSStrategy
from moegs.experts.gaussian_params import activate, init_splats
from moegs.fields import HexPlane
from moegs.io import from_dict, to_dict
from moegs.train.optim import Optimizers
from moegs.train.schedules import group_lr


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=2, size=16)


def _expert(scene, coarse=3, **kw) -> FourDGSExpert:
    cfg = FourDGSConfig.from_preset("quick")
    cfg.coarse_iterations = cfg.strategy.coarse_iterations = coarse
    for k, v in kw.items():
        setattr(cfg, k, v)
    return FourDGSExpert.from_scene(scene, cfg)


def test_mlp_sizes_match_the_spec():
    def mlp_size(width, t, c, **kw):
        field = FourDGSField(HexPlane((8, 8, 8, t), c, (1, 2)), width, **kw)
        return sum(p.numel() for p in field.mlp_parameters())

    assert mlp_size(64, 75, 32, deform_opacity=True, deform_sh=True) == 28_795  # spec ~29k (W 64, 5 heads)
    assert mlp_size(128, 150, 16, deform_opacity=True, deform_sh=True) == 94_395  # spec ~94k (W = 128)
    assert mlp_size(64, 75, 32, depth=1) == mlp_size(64, 75, 32, depth=0)  # defor_depth 0 and 1 coincide
    field = FourDGSField(HexPlane((8, 8, 8, 5), 4, (1, 2)), 16)
    assert list(field.heads.heads) == ["dx", "ds", "dr"]
    first = field.heads.heads["dx"]
    assert [type(m).__name__ for m in first] == ["ReLU", "Linear", "ReLU", "Linear"]


def test_hexplane_uses_the_point_cloud_box_and_scene_time_resolution(scene):
    expert = _expert(scene)
    means = expert.splats["means"].detach()
    assert torch.equal(expert.fields.grid.aabb, torch.stack([means.max(0).values, means.min(0).values]))
    assert expert.fields.grid.resolution == (32, 32, 32, 25)  # quick planes; D-NeRF default T 25
    from moegs.recipes import config_for

    assert config_for("fourdgs", "dnerf:mutant").config.time_resolution == 75  # arguments/dnerf/mutant.py:8


def test_coarse_stage_is_static_then_fine_deforms_in_raw_space(scene):
    expert = _expert(scene, coarse=3, deform_opacity=True, deform_sh=True)
    assert expert.on_step(3) is False and not expert.deforming
    got, want = expert.frame(0.4), activate(expert.splats, 0)
    for k in ("means", "quats", "scales", "opacities", "sh"):
        assert torch.equal(getattr(got, k), getattr(want, k))
    assert expert.on_step(4) is True and expert.deforming  # new stage: the loop builds fresh optimisers
    s = expert.splats
    d = expert.fields(s["means"], torch.full((len(s["means"]), 1), 0.4))
    frame = expert.frame(0.4)
    assert torch.allclose(frame.means, s["means"] + d["dx"])
    assert torch.allclose(frame.scales, torch.exp(s["scales"] + d["ds"]))
    assert torch.allclose(frame.quats, torch.nn.functional.normalize(s["quats"] + d["dr"], dim=-1))
    assert torch.allclose(frame.opacities, torch.sigmoid(s["opacities"] + d["do"][:, 0]))
    assert torch.allclose(frame.sh, want.sh + d["dsh"].view(-1, 16, 3)[:, :1])
    assert expert.on_step(5) is False


def test_xyz_gradient_reaches_the_hexplane_input(scene):
    expert = _expert(scene, coarse=0)
    expert.on_step(1)
    expert.frame(0.5).means.sum().backward()
    grad = expert.splats["means"].grad  # ones from the identity path, plus the deformation's own part
    assert torch.isfinite(grad).all() and not torch.allclose(grad, torch.ones_like(grad))


def test_regulariser_is_the_weighted_sum_in_the_fine_stage(scene):
    expert = _expert(scene, coarse=2)
    expert.on_step(2)
    assert float(expert.regularization(2)) == 0.0
    expert.on_step(3)
    grid, c = expert.fields.grid, expert.config
    with torch.no_grad():
        want = (
            c.plane_tv_weight * grid.space_smoothness()
            + c.time_smoothness_weight * grid.time_smoothness()
            + c.l1_time_planes * grid.time_l1()
        )
        assert float(expert.regularization(3)) == pytest.approx(float(want))
    off = _expert(scene, coarse=0, time_smoothness_weight=0.0)
    off.on_step(1)
    assert float(off.regularization(1)) == 0.0  # the original skips all three when this weight is 0


def test_the_deformation_mlp_starts_xavier_uniform(scene):
    """``initialize_weights``: Xavier-uniform on every Linear of the feature MLP and the heads (PyTorch's
    default would be bounded by ``1 / sqrt(fan_in)``, well inside Xavier's bound for these sizes)."""
    field = _expert(scene).fields
    linears = [
        m for part in (field.feature_out, field.heads) for m in part.modules() if isinstance(m, nn.Linear)
    ]
    assert len(linears) >= 4
    for m in linears:
        bound = math.sqrt(6.0 / (m.in_features + m.out_features))
        assert 1.0 / math.sqrt(m.in_features) < 0.9 * bound  # the two inits are told apart
        assert 0.9 * bound < float(m.weight.detach().abs().max()) <= bound


def test_param_groups_per_stage(scene):
    expert = _expert(scene, coarse=3)
    expert.on_step(1)
    assert {g.name for g in expert.param_groups()} == {"means", "sh0", "shN", "opacities", "scales", "quats"}
    expert.on_step(4)
    groups = {g.name: g for g in expert.param_groups()}
    extent = scene.extent
    assert {"deformation", "grid"} <= set(groups)
    assert all(g.start_step == 3 for g in groups.values())  # every schedule restarts with the fine stage
    assert group_lr(groups["grid"], 4) == pytest.approx(1.6e-3 * extent, rel=1e-2)
    assert group_lr(groups["deformation"], 3 + 600) == pytest.approx(1.6e-6 * extent)
    assert group_lr(groups["grid"], 3 + 600) == pytest.approx(1.6e-5 * extent)  # both ends scaled
    assert group_lr(groups["means"], 3 + 600) == pytest.approx(1.6e-6 * extent)


def test_paper_presets():
    dnerf, n3v = FourDGSConfig.from_preset("paper"), FourDGSConfig.from_preset("paper-n3v")
    assert (dnerf.max_init_points, dnerf.width, dnerf.train.iterations) == (2000, 64, 23_000)
    assert dnerf.train.lambda_dssim == 0
    assert dnerf.strategy.prune_every == 8000 and dnerf.strategy.reset_every == 3000
    assert (n3v.deform_opacity, n3v.deform_sh, n3v.time_resolution) == (True, True, 150)
    assert n3v.train.batch_size == 2
    for name in FourDGSConfig.presets():
        cfg = FourDGSConfig.from_preset(name)
        assert from_dict(FourDGSConfig, to_dict(cfg)) == cfg
    with pytest.raises(ValueError, match="coarse_iterations"):
        FourDGSConfig(coarse_iterations=10)


# -- strategy ----------------------------------------------------------------------------------
def _strategy_setup(scene, n_points=40, **kw):
    from moegs.data.scene import PointCloud

    g = torch.Generator().manual_seed(0)
    points = PointCloud(torch.rand(n_points, 3, generator=g), torch.rand(n_points, 3, generator=g))
    splats = init_splats(points)
    optimizers = Optimizers([_group(k, v) for k, v in splats.items()]).for_splats(splats)
    strategy = FourDGSStrategy(
        coarse_iterations=10,
        densify_from=1,
        densify_every=2,
        prune_from=1,
        prune_every=2,
        reset_every=1000,
        **kw,
    )
    return strategy, splats, optimizers, strategy.initialize_state(scene_scale=100.0)


def _group(name, param):
    from moegs.train.params import ParamGroup

    return ParamGroup(name, [param], 1e-3)


def _render(n, grad):
    means2d = torch.zeros(n, 2, requires_grad=True)
    means2d.grad = torch.full((n, 2), grad)
    return {
        "means2d": means2d,
        "visible": torch.ones(n, dtype=torch.bool),
        "radii": torch.ones(n, dtype=torch.int32),
        "width": 2,
        "height": 2,
    }


def test_strategy_densifies_below_the_cap_and_sums_batch_gradients(scene):
    strategy, splats, opts, state = _strategy_setup(scene)
    strategy.step_post_backward(splats, opts, state, 2, {"renders": [_render(40, 1.0)]})
    assert len(splats["means"]) == 80  # every Gaussian is large-gradient and small: cloned
    capped, splats, opts, state = _strategy_setup(scene, densify_below=40)
    capped.step_post_backward(splats, opts, state, 2, {"renders": [_render(40, 1.0)]})
    assert len(splats["means"]) == 40
    # two views of a batch with opposite gradients: 4DGaussians sums before the norm -> no densification
    strategy, splats, opts, state = _strategy_setup(scene)
    strategy.step_post_backward(splats, opts, state, 2, {"renders": [_render(40, 1.0), _render(40, -1.0)]})
    assert len(splats["means"]) == 40


def test_strategy_prunes_only_above_the_floor(scene):
    strategy, splats, opts, state = _strategy_setup(scene, densify_below=0)
    with torch.no_grad():
        splats["opacities"][:10] = -10.0
    strategy.step_post_backward(splats, opts, state, 2, {"renders": [_render(40, 0.0)]})
    assert len(splats["means"]) == 40  # N <= 200k: never pruned (small scenes)
    strategy, splats, opts, state = _strategy_setup(scene, densify_below=0, prune_above=0)
    with torch.no_grad():
        splats["opacities"][:10] = -10.0
    strategy.step_post_backward(splats, opts, state, 2, {"renders": [_render(40, 0.0)]})
    assert len(splats["means"]) == 30 and len(state["grad2d"]) == 30


def test_strategy_counter_restarts_with_the_fine_stage(scene):
    strategy, splats, opts, state = _strategy_setup(scene)
    assert [strategy.stage_step(s) for s in (1, 10, 11, 15)] == [1, 10, 1, 5]
    strategy.step_post_backward(splats, opts, state, 9, {"renders": [_render(40, 0.0)]})
    assert float(state["count"].sum()) == 40
    strategy.step_post_backward(splats, opts, state, 11, {"renders": [_render(40, 0.0)]})
    assert float(state["count"].sum()) == 40  # statistics restarted at the first fine step
