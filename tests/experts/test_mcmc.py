"""Per-frame 3DGS-MCMC: one model per time (or time bin), nearest-model frames, quick run on mutant."""

import pytest
import torch
from helpers.scenes import tiny_scene
from helpers.training import trained_expert

from moegs.data.scene import PointCloud
from moegs.experts import get_expert_class
from moegs.experts.mcmc import MCMCConfig, MCMCExpert, key_times
from moegs.train.strategy import ADCStrategy, MCMCStrategy


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=3)


def test_registry_and_presets():
    assert get_expert_class("mcmc") is MCMCExpert
    paper = MCMCConfig.from_preset("paper")
    assert paper.num_models is None and paper.init_opacity == 0.5 and paper.init_scale == 0.1
    assert paper.strategy.noise_lr == 5e5 and paper.strategy.opacity_reg == paper.strategy.scale_reg == 0.01
    assert MCMCConfig.from_preset("quick").num_models == 4


def test_key_times():
    times = torch.linspace(0, 1, 10)
    torch.testing.assert_close(key_times(times, None), times)
    torch.testing.assert_close(key_times(times, 2), torch.stack([times[:5].mean(), times[5:].mean()]))
    # 10 times in 4 bins: sizes 3, 3, 2, 2 (as even as possible), never fewer bins than asked
    expected = torch.stack([times[:3].mean(), times[3:6].mean(), times[6:8].mean(), times[8:].mean()])
    torch.testing.assert_close(key_times(times, 4), expected)
    assert len(key_times(times[:7], 6)) == 6


def test_one_model_per_time(scene):
    expert = MCMCExpert.from_scene(scene, MCMCConfig(max_init_points=30))
    assert expert.num_models == 3 and expert.splats["model"].tolist() == [0] * 30 + [1] * 30 + [2] * 30
    assert not expert.splats["model"].requires_grad


def test_frame_rows_are_found_again_when_the_model_index_changes(scene):
    """Kept per model between refinements (no read per step), found again for a new or rewritten index."""
    expert = MCMCExpert.from_scene(scene, MCMCConfig(max_init_points=30))
    rows = expert.frame_rows(0.0)
    assert rows.tolist() == list(range(30)) and expert.frame_rows(0.0) is rows
    with torch.no_grad():
        expert.splats["model"][:5] = 2
    assert expert.frame_rows(0.0).tolist() == list(range(5, 30))
    expert.splats["model"] = torch.nn.Parameter(expert.splats["model"][5:].clone(), requires_grad=False)
    assert expert.frame_rows(0.0).tolist() == list(range(25))
    assert "model" not in {g.name for g in expert.param_groups()}
    assert [expert.model_index(t) for t in (0.0, 0.2, 0.3, 0.5, 0.8, 1.0)] == [0, 0, 1, 1, 2, 2]
    assert expert.view_groups(scene.train) == [expert.model_index(v.camera.time) for v in scene.train]
    with torch.no_grad():
        expert.splats["means"][30:60] += 10.0  # move model 1 only
    f1 = expert.frame(0.5)
    assert len(f1) == 30 and (f1.means.mean(0) - expert.frame(0.0).means.mean(0)).norm() > 9
    torch.testing.assert_close(torch.sigmoid(expert.splats["opacities"]), torch.full((90,), 0.5))


def test_regularization_is_per_rendered_model(scene):
    expert = MCMCExpert.from_scene(scene, MCMCConfig(max_init_points=30))
    frame = expert.frame(1.0)
    expected = 0.01 * frame.opacities.mean() + 0.01 * frame.scales.mean()
    torch.testing.assert_close(expert.regularization(1, frame), expected)


def test_points_with_times_seed_their_own_model(scene):
    timed = tiny_scene(num_frames=3)
    n = len(timed.points)
    timed.points = PointCloud(timed.points.xyz, timed.points.rgb, "timed", torch.arange(n) % 3 / 2.0)
    expert = MCMCExpert.from_scene(timed, MCMCConfig())
    for m in range(3):
        members = expert.splats["model"] == m
        assert int(members.sum()) == len(range(m, n, 3))
        torch.testing.assert_close(expert.splats["means"][members], timed.points.xyz[m::3])


def test_strategy_must_be_grouped(scene):
    with pytest.raises(ValueError, match="group_key='model'"):
        MCMCExpert.from_scene(scene, MCMCConfig(strategy=MCMCStrategy()))
    with pytest.raises(ValueError, match="group_key='model'"):
        MCMCExpert.from_scene(scene, MCMCConfig(strategy=ADCStrategy()))


@pytest.mark.realdata
@pytest.mark.slow
def test_quick_run_on_mutant_grows_every_model():  # its PSNR floor: test_mutant_quick.py
    run = trained_expert("mcmc", "dnerf:mutant", "quick")
    counts = torch.bincount(run.expert.splats["model"], minlength=run.expert.num_models)
    cap = run.expert.config.strategy.cap_max
    assert (counts > run.expert.config.max_init_points).all() and (counts <= cap).all()  # every model grew
    assert len(run.expert.frame(0.5)) == int(counts[run.expert.model_index(0.5)])
