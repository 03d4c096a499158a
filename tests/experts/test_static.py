"""Static 3DGS baseline: construction, learning rates, and a quick run on real D-NeRF mutant."""

import pytest
import torch
from helpers.scenes import tiny_scene
from helpers.training import trained_expert

from moegs.experts import get_expert_class
from moegs.experts.static import StaticConfig, StaticExpert, thin_points
from moegs.metrics import psnr
from moegs.train.strategy import ADCStrategy

STATIC_PSNR_FLOOR = 22.0  # bench.floors: 22.56-22.65 dB over 3 seeds x {1, 2} threads (quick, mutant)


@pytest.fixture(scope="module")
def scene():
    return tiny_scene()


def test_registry_and_presets():
    assert get_expert_class("static") is StaticExpert
    quick, paper = StaticConfig.from_preset("quick"), StaticConfig.from_preset("paper")
    assert paper.train.iterations == 30_000 and paper.train.resolution_scale is None
    assert isinstance(paper.strategy, ADCStrategy) and paper.strategy.densify_until == 15_000
    assert quick.train.iterations < 2000 and quick.train.resolution_scale == 0.125


def test_from_scene_and_thinning(scene):
    expert = StaticExpert.from_scene(scene, StaticConfig(max_init_points=80))
    assert expert.num_gaussians == 80
    again = StaticExpert.from_scene(scene, StaticConfig(max_init_points=80))
    assert torch.equal(expert.splats["means"], again.splats["means"])  # seeded by train.seed
    assert len(thin_points(scene.points, None, 0)) == len(scene.points)
    empty = tiny_scene()
    empty.points = None
    with pytest.raises(ValueError, match="has no initial points"):
        StaticExpert.from_scene(empty, StaticConfig())


def test_thinning_keeps_each_points_colour_and_time():
    """STG's per-frame clouds carry a time per point: a thinned cloud keeps the same rows of all three."""
    from moegs.data.scene import PointCloud

    index = torch.arange(20, dtype=torch.float32)
    cloud = PointCloud(index[:, None].repeat(1, 3), (index / 20)[:, None].repeat(1, 3), "test", index / 40)
    thin = thin_points(cloud, 7, seed=3)
    assert len(thin) == 7 and thin.xyz[:, 0].diff().gt(0).all()  # a subset, in the original order
    torch.testing.assert_close(thin.rgb[:, 0], thin.xyz[:, 0] / 20)
    torch.testing.assert_close(thin.times, thin.xyz[:, 0] / 40)


def test_param_groups_follow_3dgs(scene):
    expert = StaticExpert.from_scene(scene, StaticConfig())
    groups = {g.name: g for g in expert.param_groups()}
    assert set(groups) == {"means", "sh0", "shN", "opacities", "scales", "quats"}
    assert groups["means"].lr == pytest.approx(1.6e-4 * scene.extent)  # spatial_lr_scale = extent
    assert groups["means"].lr_final == pytest.approx(1.6e-6 * scene.extent)
    assert groups["shN"].lr == pytest.approx(groups["sh0"].lr / 20)
    assert (groups["opacities"].lr, groups["scales"].lr, groups["quats"].lr) == (0.05, 5e-3, 1e-3)
    assert all(g.eps == 1e-15 and g.optimizer == "adam" for g in groups.values())
    fixed = StaticExpert.from_scene(scene, StaticConfig(spatial_lr_scale=5.0))
    assert fixed.param_groups()[0].lr == pytest.approx(8e-4)


def test_frame_is_time_independent_with_scheduled_sh(scene):
    expert = StaticExpert.from_scene(scene, StaticConfig())
    expert.on_step(2000)
    f0, f1 = expert.frame(0.0), expert.frame(1.0)
    assert len(f0) == expert.num_gaussians and f0.sh.shape[1] == 9
    assert torch.equal(f0.means, f1.means)


@pytest.mark.realdata
@pytest.mark.slow
def test_quick_run_on_mutant():
    run = trained_expert("static", "dnerf:mutant", "quick")
    test = run.metrics["test"]
    assert test["num_views"] == 20 and run.metrics["completed"]
    assert test["psnr"] >= STATIC_PSNR_FLOOR, test["psnr"]
    assert test["ssim"] >= 0.9
    # a reasonable baseline: far better than the empty scene (the background colour everywhere)
    empty = torch.stack([psnr(run.scene.background.expand_as(v.image()), v.image()) for v in run.scene.test])
    assert test["psnr"] >= float(empty.mean()) + 8.0
