"""3DGS adaptive density control: gradient convention, clone / split / prune / reset schedule."""

import math

import pytest
import torch
from torch import nn

from moegs.experts.ed3dgs import ED3DGSStrategy
from moegs.experts.fourdgs import FourDGSStrategy
from moegs.experts.stg import STGStrategy
from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.strategy import ADCStrategy


def _params(scales, opacities):
    n = len(scales)
    params = nn.ParameterDict(
        {
            "means": nn.Parameter(torch.zeros(n, 3)),
            "scales": nn.Parameter(torch.log(torch.tensor(scales)).unsqueeze(1).repeat(1, 3)),
            "quats": nn.Parameter(torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)),
            "opacities": nn.Parameter(torch.logit(torch.tensor(opacities))),
        }
    )
    optim = Optimizers([ParamGroup(k, [p], 0.01) for k, p in params.items()])
    return params, optim.for_splats(params)


def _render(grad_px, visible, size=(100, 80), radii=None):
    """One view's stats with a preset pixel-space gradient of the projected means."""
    means2d = torch.zeros(len(visible), 2, requires_grad=True)
    means2d.grad = torch.tensor(grad_px, dtype=torch.float32)
    vis = torch.tensor(visible)
    radii = torch.tensor(radii if radii is not None else [3] * len(visible), dtype=torch.int32) * vis
    return {"means2d": means2d, "visible": vis, "radii": radii, "width": size[0], "height": size[1]}


def test_gradient_is_accumulated_in_ndc_units():
    params, opts = _params([0.001] * 3, [0.5] * 3)
    strategy = ADCStrategy()
    state = strategy.initialize_state(1.0)
    # W = 100, H = 80: NDC gradient = pixel gradient * (W/2, H/2) = (50 gx, 40 gy)
    info = {"renders": [_render([[2e-6, 0.0], [0.0, 5e-6], [1.0, 1.0]], [True, True, False])]}
    strategy.step_post_backward(params, opts, state, 1, info)
    torch.testing.assert_close(state["grad2d"], torch.tensor([1e-4, 2e-4, 0.0]))
    torch.testing.assert_close(state["count"], torch.tensor([1.0, 1.0, 0.0]))
    # a batch of two views: the mean loss halves each view's gradient, the strategy doubles it back
    info = {
        "renders": [
            _render([[1e-6, 0.0]] * 3, [True, False, False]),
            _render([[1e-6, 0.0]] * 3, [True, True, False]),
        ]
    }
    strategy.step_post_backward(params, opts, state, 2, info)
    torch.testing.assert_close(state["grad2d"], torch.tensor([1e-4 + 2e-4, 2e-4 + 1e-4, 0.0]))
    torch.testing.assert_close(state["count"], torch.tensor([3.0, 2.0, 0.0]))


def test_a_steps_views_enter_the_statistics_as_each_methods_code_has_it():
    """Two views, the loss their mean. 3DGS / gsplat: each view's norm (times the batch) and a count per
    view; 4DGaussians / E-D3DGS: the gradients summed before the norm, one count for any view; STG: the last
    view's tensors only (``train.py:257-258``), its gradient times the batch."""
    params, _ = _params([0.001] * 3, [0.5] * 3)
    first = _render([[4e-6, 0.0], [2e-6, 0.0], [0.0, 0.0]], [True, True, False], radii=[9, 9, 9])
    last = _render([[0.0, 0.0], [-1e-6, 0.0], [1e-6, 0.0]], [False, True, True], radii=[2, 4, 6])
    expected = {  # grad2d (NDC: 50 gx), count, max_radii
        "per_view": ([4e-4, 3e-4, 1e-4], [1, 2, 1], [9, 9, 6]),
        "summed": ([2e-4, 0.5e-4, 0.5e-4], [1, 1, 1], [9, 9, 6]),
        "last": ([0.0, 1e-4, 1e-4], [0, 1, 1], [0, 4, 6]),
    }
    for convention, (grad2d, count, max_radii) in expected.items():
        strategy = ADCStrategy(batch_stats=convention)
        state = strategy.initialize_state(1.0)
        strategy._update_stats(params, state, {"renders": [first, last]})
        torch.testing.assert_close(state["grad2d"], torch.tensor(grad2d), msg=convention)
        torch.testing.assert_close(state["count"], torch.tensor(count, dtype=torch.float32), msg=convention)
        torch.testing.assert_close(state["max_radii"], torch.tensor(max_radii, dtype=torch.float32))
    assert STGStrategy().batch_stats == "last" and FourDGSStrategy().batch_stats == "summed"
    assert ED3DGSStrategy().batch_stats == "summed"
    with pytest.raises(ValueError, match=r"ADCStrategy.batch_stats must be one of .*got 'mean'"):
        ADCStrategy(batch_stats="mean")


def test_densify_clones_small_splits_large_prunes_transparent():
    # 0: small + high grad -> clone; 1: large + high grad -> split; 2: low grad; 3: transparent -> prune
    params, opts = _params([0.001, 1.0, 0.001, 0.001], [0.5, 0.6, 0.7, 0.001])
    before = {k: v.detach().clone() for k, v in params.items()}
    strategy = ADCStrategy(densify_from=0, densify_every=10, reset_every=1000, grad_threshold=2e-4)
    state = strategy.initialize_state(scene_scale=1.0)  # percent_dense * extent = 0.01
    grads = [[1e-5, 0.0], [1e-5, 0.0], [1e-6, 0.0], [1e-6, 0.0]]  # NDC 5e-4, 5e-4, 5e-5, 5e-5
    strategy.step_post_backward(params, opts, state, 10, {"renders": [_render(grads, [True] * 4)]})
    assert state["last_refine"] == {"clone": 1, "split": 1, "prune": 1}
    opac = torch.sigmoid(params["opacities"]).detach()
    # rows: kept [0, 2] (3 was pruned, 1 replaced), the clone of 0, then two children of 1
    torch.testing.assert_close(opac, torch.tensor([0.5, 0.7, 0.5, 0.6, 0.6]))
    torch.testing.assert_close(params["scales"][:3], before["scales"][[0, 2, 0]])
    torch.testing.assert_close(torch.exp(params["scales"][3:]), torch.full((2, 3), 1.0 / 1.6))
    assert state["grad2d"].shape == (5,) and (state["grad2d"] == 0).all()  # statistics restart
    assert all(opt.param_groups[0]["params"][0] is params[key] for key, opt in opts.items())


def test_large_gaussians_pruned_only_after_first_reset_interval():
    def run(step):
        params, opts = _params([0.001, 0.5], [0.5, 0.5])
        strategy = ADCStrategy(densify_from=0, densify_every=10, reset_every=100, prune_world_scale=0.1)
        state = strategy.initialize_state(scene_scale=1.0)
        strategy.step_post_backward(
            params, opts, state, step, {"renders": [_render([[0.0, 0.0]] * 2, [True] * 2)]}
        )
        return params["means"].shape[0]

    assert run(50) == 2
    assert run(110) == 1  # max scale 0.5 > 0.1 * extent


def test_the_boundaries_of_3dgs_densification():
    """3DGS ``train.py`` / ``densify_and_prune``: densify when ``iteration > densify_from_iter`` on the
    interval; clone or split where the *mean* view-space gradient ``>=`` the threshold; large Gaussians
    pruned once ``iteration > opacity_reset_interval``, "large" relative to the scene extent."""

    def refine(step, grads_px, strategy, scene_scale=1.0, scales=(0.001, 0.001)):
        params, opts = _params(list(scales), [0.5] * len(scales))
        state = strategy.initialize_state(scene_scale=scene_scale)
        renders = [_render(g, [True] * len(scales), size=(128, 128)) for g in grads_px]
        strategy.step_post_backward(params, opts, state, step, {"renders": renders})
        return state.get("last_refine"), params["means"].shape[0]

    at = 2.0**-12  # exact in float32: pixel gradient 2^-18 times W / 2 = 64
    strategy = ADCStrategy(densify_from=10, densify_every=10, reset_every=1000, grad_threshold=at)
    one_view = [[[2.0**-18, 0.0], [2.0**-19, 0.0]]]
    assert refine(10, one_view, strategy) == (None, 2)  # not yet at densify_from
    assert refine(20, one_view, strategy)[0] == {"clone": 1, "split": 0, "prune": 0}  # == threshold
    # two views of a batch: per view 2^-13 (the batch's mean loss halves it, the strategy doubles it back),
    # accumulated 2^-12 over a count of 2: the mean 2^-13 stays under the threshold
    two_views = [[[2.0**-20, 0.0], [0.0, 0.0]]] * 2
    assert refine(20, two_views, strategy)[0]["clone"] == 0
    big = dict(scales=(0.001, 0.5), grads_px=[[[0.0, 0.0]] * 2])
    pruning = ADCStrategy(densify_from=0, densify_every=10, reset_every=100, prune_world_scale=0.1)
    assert refine(100, strategy=pruning, **big)[1] == 2  # at the reset interval: not yet
    assert refine(110, strategy=pruning, **big)[1] == 1  # 0.5 > 0.1 x extent 1
    assert refine(110, strategy=pruning, scene_scale=10.0, **big)[1] == 2  # 0.5 < 0.1 x extent 10


def test_screen_size_prune_is_off_by_default_as_in_3dgs():
    def run(size):
        params, opts = _params([0.001, 0.001], [0.5, 0.5])
        strategy = ADCStrategy(densify_from=0, densify_every=10, reset_every=5, prune_screen_size=size)
        state = strategy.initialize_state(scene_scale=1.0)
        info = {"renders": [_render([[0.0, 0.0]] * 2, [True] * 2, radii=[3, 40])]}
        strategy.step_post_backward(params, opts, state, 10, info)
        return params["means"].shape[0]

    assert run(None) == 2
    assert run(20.0) == 1


def test_opacity_reset_schedule():
    strategy = ADCStrategy(densify_from=50, densify_every=1000, reset_every=300, densify_until=1000)

    def max_opacity_after(step, white):
        params, opts = _params([0.001], [0.9])
        state = strategy.initialize_state(1.0, white_background=white)
        strategy.step_post_backward(params, opts, state, step, {"renders": [_render([[0.0, 0.0]], [True])]})
        return torch.sigmoid(params["opacities"]).item()

    assert max_opacity_after(299, False) == pytest.approx(0.9)
    assert max_opacity_after(300, False) == pytest.approx(0.01)
    assert max_opacity_after(50, False) == pytest.approx(0.9)
    assert max_opacity_after(50, True) == pytest.approx(0.01)  # 3DGS white-background reset
    assert max_opacity_after(1200, False) == pytest.approx(0.9)  # after densify_until: nothing


def test_frame_must_cover_every_gaussian():
    params, opts = _params([0.001] * 3, [0.5] * 3)
    strategy = ADCStrategy()
    with pytest.raises(ValueError, match="one projected mean per Gaussian: got 2, the expert has 3"):
        strategy.step_post_backward(
            params,
            opts,
            strategy.initialize_state(1.0),
            1,
            {"renders": [_render([[0.0, 0.0]] * 2, [True] * 2)]},
        )


def test_split_scale_divisor_default_matches_3dgs():
    assert ADCStrategy().split_scale_divisor == pytest.approx(0.8 * 2)
    assert math.isclose(ADCStrategy().grad_threshold, 0.0002)
