"""3DGS-MCMC relocation formula (hand-checked values), relocation / growth per model, noise gate."""

import math

import pytest
import torch
from torch import nn

from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.strategy import MCMCStrategy
from moegs.train.strategy.mcmc import binomial_table, relocation_update


def _reference(o: float, s: float, n: int) -> tuple[float, float]:
    """The formula of the 3DGS-MCMC paper written out with math.comb."""
    new_o = 1.0 - (1.0 - o) ** (1.0 / n)
    denom = sum(
        math.comb(i - 1, k) * (-1) ** k * new_o ** (k + 1) / math.sqrt(k + 1)
        for i in range(1, n + 1)
        for k in range(i)
    )
    return new_o, s * o / denom


def test_binomial_table():
    table = binomial_table()
    assert table.shape == (51, 51)
    assert table[4, :5].tolist() == [1, 4, 6, 4, 1]
    assert table[50, 25] == math.comb(50, 25)
    assert table[3, 4] == 0


@pytest.mark.parametrize(
    ("o", "n", "o_new", "s_ratio"),
    [
        (0.5, 1, 0.5, 1.0),  # nothing shared: unchanged
        (0.5, 2, 0.292893, 0.952152),  # 1 - sqrt(0.5); 0.5 / (2 o' - o'^2 / sqrt 2)
        (0.9, 3, 0.535841, 0.827758),  # hand-computed: denominator 1.087272
    ],
)
def test_relocation_update_hand_values(o, n, o_new, s_ratio):
    new_o, new_s = relocation_update(torch.tensor([o]), torch.tensor([[2.0, 1.0, 0.5]]), torch.tensor([n]))
    assert new_o.item() == pytest.approx(o_new, abs=1e-6)
    torch.testing.assert_close(new_s, torch.tensor([[2.0, 1.0, 0.5]]) * s_ratio, rtol=1e-5, atol=0)
    ref_o, ref_s = _reference(o, 1.0, n)
    assert new_o.item() == pytest.approx(ref_o, rel=1e-6) and new_s[0, 0].item() == pytest.approx(
        2 * ref_s, rel=1e-6
    )


def test_relocation_update_clamps():
    new_o, _ = relocation_update(torch.tensor([0.001]), torch.ones(1, 3), torch.tensor([2]))
    assert new_o.item() == pytest.approx(0.005)  # floor at min_opacity
    many = relocation_update(torch.tensor([0.99]), torch.ones(1, 3), torch.tensor([80]))
    fifty = relocation_update(torch.tensor([0.99]), torch.ones(1, 3), torch.tensor([50]))
    torch.testing.assert_close(many, fifty)  # N is clamped to 50


def _params(opacities, models, means=None):
    n = len(opacities)
    params = nn.ParameterDict(
        {
            "means": nn.Parameter(
                torch.arange(n, dtype=torch.float32)[:, None].repeat(1, 3) if means is None else means
            ),
            "scales": nn.Parameter(torch.full((n, 3), math.log(0.1))),
            "quats": nn.Parameter(torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)),
            "opacities": nn.Parameter(torch.logit(torch.tensor(opacities))),
            "model": nn.Parameter(torch.tensor(models), requires_grad=False),
        }
    )
    optim = Optimizers([ParamGroup(k, [p], 0.01) for k, p in params.items() if k != "model"])
    return params, optim.for_splats(params)


def test_dead_gaussians_move_within_their_model():
    torch.manual_seed(0)
    params, opts = _params([0.5, 0.001, 0.8, 0.7, 0.004, 0.6], [0, 0, 0, 1, 1, 1])
    strategy = MCMCStrategy(cap_max=6, refine_from=0, refine_every=1, group_key="model")  # cap: no growth
    state = strategy.initialize_state(1.0)
    strategy.step_post_backward(params, opts, state, 1, {})
    assert state["last_refine"] == {"relocated": 2, "added": 0}
    x = params["means"][:, 0].tolist()
    assert x[1] in (0.0, 2.0) and x[4] in (3.0, 5.0)
    assert torch.sigmoid(params["opacities"]).min() >= 0.005 - 1e-7
    assert params["model"].tolist() == [0, 0, 0, 1, 1, 1]


def test_a_gaussian_exactly_at_the_opacity_floor_is_dead():
    """3DGS-MCMC ``relocate_gs``: ``opacity <= 0.005`` marks a Gaussian dead."""
    params, opts = _params([0.5, 0.005], [0, 0])
    floor = float(torch.sigmoid(params["opacities"].detach())[1])  # 0.005 as float32 holds it
    strategy = MCMCStrategy(cap_max=2, refine_from=0, refine_every=1, min_opacity=floor)
    state = strategy.initialize_state(1.0)
    strategy.step_post_backward(params, opts, state, 1, {})
    assert state["last_refine"] == {"relocated": 1, "added": 0}


def test_relocated_pair_shares_the_source_opacity():
    torch.manual_seed(0)
    params, opts = _params([0.64, 0.001], [0, 0])
    MCMCStrategy(refine_from=0, refine_every=1, cap_max=2).step_post_backward(params, opts, {}, 1, {})
    opac = torch.sigmoid(params["opacities"]).detach()
    torch.testing.assert_close(opac, torch.full((2,), 0.4))  # 1 - sqrt(1 - 0.64), source and copy
    _, s = relocation_update(torch.tensor([0.64]), torch.full((1, 3), 0.1), torch.tensor([2]))
    torch.testing.assert_close(torch.exp(params["scales"]).detach(), s.repeat(2, 1))


def test_growth_by_five_percent_per_model_up_to_cap():
    torch.manual_seed(0)
    params, opts = _params([0.5] * 80, [0] * 40 + [1] * 40)
    strategy = MCMCStrategy(cap_max=41, refine_from=0, refine_every=1, group_key="model")
    strategy.step_post_backward(params, opts, {}, 1, {})
    assert params["model"].tolist().count(0) == 41 and params["model"].tolist().count(1) == 41
    strategy = MCMCStrategy(cap_max=10_000, refine_from=0, refine_every=1, group_key="model")
    strategy.step_post_backward(params, opts, {}, 1, {})
    assert params["means"].shape[0] == 2 * 43  # floor(1.05 * 41) = 43
    for key, opt in opts.items():
        assert opt.param_groups[0]["params"][0] is params[key]


def test_refinement_schedule():
    strategy = MCMCStrategy(refine_from=500, refine_until=25_000, refine_every=100)
    params, opts = _params([0.5] * 40, [0] * 40)
    for step, grows in [(500, False), (550, False), (600, True), (25_000, False)]:
        n = params["means"].shape[0]
        strategy.step_post_backward(params, opts, {}, step, {})
        assert (params["means"].shape[0] > n) == grows, step


def test_noise_moves_only_transparent_gaussians():
    torch.manual_seed(0)
    params, opts = _params([0.9, 0.001], [0, 0], means=torch.zeros(2, 3))
    opts["means"].param_groups[0]["lr"] = 1.6e-4
    MCMCStrategy().step_post_optimizer(params, opts, {}, 1, {})
    moved = params["means"].detach().norm(dim=1)
    assert moved[0] < 1e-12  # gate sigmoid(-100 (0.9 - 0.005)) ~ 1e-39
    # gate ~ sigmoid(0.4) = 0.6, noise_lr * lr = 80, Sigma = 0.01 I: displacement ~ 0.48 * |eps|
    assert 0.01 < moved[1] < 3.0


def test_noise_stops_at_noise_until_as_gsplat():
    """gsplat ``MCMCStrategy``: noise while ``step < noise_injection_stop_iter`` (-1: never stops)."""
    for until, step, moves in [(-1, 10**6, True), (5, 4, True), (5, 5, False), (5, 6, False)]:
        params, opts = _params([0.001], [0], means=torch.zeros(1, 3))
        opts["means"].param_groups[0]["lr"] = 1.6e-4
        MCMCStrategy(noise_until=until).step_post_optimizer(params, opts, {}, step, {})
        assert (params["means"].detach().norm() > 0).item() == moves, (until, step)


def test_regularization_is_mean_opacity_and_scale():
    strategy = MCMCStrategy(opacity_reg=0.01, scale_reg=0.02)
    value = strategy.regularization(torch.tensor([0.2, 0.4]), torch.full((2, 3), 0.5))
    assert value.item() == pytest.approx(0.01 * 0.3 + 0.02 * 0.5)


def test_group_key_must_exist():
    params, opts = _params([0.5, 0.001], [0, 0])
    del params["model"]
    with pytest.raises(ValueError, match="group_key 'models' is not a splat entry"):
        MCMCStrategy(refine_from=0, refine_every=1, group_key="models").step_post_backward(
            params, opts, {}, 1, {}
        )
