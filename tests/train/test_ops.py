"""Densification ops: they do what they say and keep Adam state aligned with the Gaussians."""

import math

import pytest
import torch
from torch import nn

from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.strategy import ops

N = 5


def _setup():
    """Five Gaussians with Adam state whose rows differ (row i got gradient i + 1)."""
    g = torch.Generator().manual_seed(0)
    params = nn.ParameterDict(
        {
            "means": nn.Parameter(torch.randn(N, 3, generator=g)),
            "scales": nn.Parameter(torch.log(torch.rand(N, 3, generator=g) + 0.1)),
            "quats": nn.Parameter(torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(N, 1)),
            "opacities": nn.Parameter(torch.logit(torch.linspace(0.1, 0.9, N))),
            "sh0": nn.Parameter(torch.randn(N, 1, 3, generator=g)),
        }
    )
    optim = Optimizers([ParamGroup(k, [p], 0.01) for k, p in params.items()])
    rows = torch.arange(1.0, N + 1)
    for p in params.values():
        p.grad = rows.reshape(N, *[1] * (p.ndim - 1)).expand_as(p).clone()
    optim.step()
    optim.zero_grad()
    return params, optim, optim.for_splats(params)


def _moments(optimizers, key):
    state = optimizers[key].state[optimizers[key].param_groups[0]["params"][0]]
    return state["exp_avg"], state["exp_avg_sq"], state["step"]


def _check_aligned(params, optimizers):
    for key, p in params.items():
        opt = optimizers[key]
        assert opt.param_groups[0]["params"][0] is p
        m, v, _ = _moments(optimizers, key)
        assert m.shape == p.shape and v.shape == p.shape


def test_duplicate_appends_copies_with_zero_moments():
    params, optim, opts = _setup()
    before = {k: v.detach().clone() for k, v in params.items()}
    m0 = _moments(opts, "means")[0].clone()
    ops.duplicate(params, opts, torch.tensor([True, False, True, False, False]))
    _check_aligned(params, opts)
    assert params["means"].shape[0] == N + 2
    for k in params:
        torch.testing.assert_close(params[k][:N], before[k])
        torch.testing.assert_close(params[k][N:], before[k][[0, 2]])
    m, v, step = _moments(opts, "means")
    torch.testing.assert_close(m[:N], m0)
    assert (m[N:] == 0).all() and (v[N:] == 0).all()
    assert float(step) == 1.0
    # the optimiser still steps every tensor after the op
    for p in params.values():
        p.grad = torch.ones_like(p)
    optim.step()
    assert float(_moments(opts, "means")[2]) == 2.0


def test_split_replaces_parents_by_children():
    params, _, opts = _setup()
    before = {k: v.detach().clone() for k, v in params.items()}
    m0 = _moments(opts, "sh0")[0].clone()
    mask = torch.tensor([False, True, False, False, True])
    ops.split(params, opts, mask, samples=2, scale_divisor=1.6)
    _check_aligned(params, opts)
    keep = [0, 2, 3]
    assert params["means"].shape[0] == len(keep) + 2 * 2
    for k in params:
        torch.testing.assert_close(params[k][:3], before[k][keep])
    # children: scale / 1.6, other attributes copied, order [sample 0 of parents, sample 1 of parents]
    parents = [1, 4, 1, 4]
    torch.testing.assert_close(params["scales"][3:], before["scales"][parents] - math.log(1.6))
    torch.testing.assert_close(params["opacities"][3:], before["opacities"][parents])
    torch.testing.assert_close(params["sh0"][3:], before["sh0"][parents])
    # identity rotation: offsets are parent-scale-sized normal samples
    offsets = (params["means"][3:] - before["means"][parents]) / torch.exp(before["scales"][parents])
    assert offsets.abs().max() < 6 and offsets.abs().max() > 0
    m = _moments(opts, "sh0")[0]
    torch.testing.assert_close(m[:3], m0[keep])
    assert (m[3:] == 0).all()


def test_split_sample_distribution_follows_rotation():
    torch.manual_seed(0)
    q = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])  # 90 deg about z
    params = nn.ParameterDict(
        {
            "means": nn.Parameter(torch.zeros(1, 3)),
            "scales": nn.Parameter(torch.log(torch.tensor([[1.0, 0.01, 0.01]]))),
            "quats": nn.Parameter(q),
            "opacities": nn.Parameter(torch.zeros(1)),
        }
    )
    ops.split(params, {}, torch.tensor([True]), samples=2000)
    spread = params["means"].detach().std(dim=0)
    assert spread[1] == pytest.approx(1.0, rel=0.1)  # the long local x axis now points along world y
    assert spread[0] < 0.05 and spread[2] < 0.05


def test_remove_drops_rows_and_moments():
    params, _, opts = _setup()
    before = params["means"].detach().clone()
    m0 = _moments(opts, "means")[0].clone()
    mask = torch.tensor([False, True, True, False, False])
    ops.remove(params, opts, mask)
    _check_aligned(params, opts)
    torch.testing.assert_close(params["means"], before[~mask])
    torch.testing.assert_close(_moments(opts, "means")[0], m0[~mask])


def test_reset_opacity_caps_and_zeroes_opacity_moments_only():
    params, _, opts = _setup()
    means = params["means"]
    with torch.no_grad():
        params["opacities"][0] = torch.logit(torch.tensor(0.001))  # already below the cap: kept
    above = torch.sigmoid(params["opacities"]) > 0.01
    assert above.sum() >= 2
    ops.reset_opacity(params, opts, 0.01)
    assert params["means"] is means  # untouched tensors keep their identity
    opacity = torch.sigmoid(params["opacities"].detach())
    assert float(opacity[0]) == pytest.approx(0.001, rel=1e-4)  # min(opacity, 0.01), not 0.01
    torch.testing.assert_close(opacity[above], torch.full_like(opacity[above], 0.01))
    m, v, _ = _moments(opts, "opacities")
    assert (m == 0).all() and (v == 0).all()
    assert (_moments(opts, "means")[0] != 0).any()


def test_relocate_writes_sources_and_dead_slots():
    params, _, opts = _setup()
    before = {k: v.detach().clone() for k, v in params.items()}
    m0 = _moments(opts, "means")[0].clone()
    dead, sources = torch.tensor([1, 3]), torch.tensor([0, 0])
    new_o, new_s = torch.full((2,), -1.0), torch.full((2, 3), -2.0)
    ops.relocate(params, opts, dead, sources, new_o, new_s)
    _check_aligned(params, opts)
    for i in (0, 1, 3):
        assert params["opacities"][i] == -1.0 and (params["scales"][i] == -2.0).all()
        torch.testing.assert_close(params["means"][i], before["means"][0])
    torch.testing.assert_close(params["means"][[2, 4]], before["means"][[2, 4]])
    m = _moments(opts, "means")[0]
    assert (m[0] == 0).all()  # the source's moments are zeroed (3dgs-mcmc)
    torch.testing.assert_close(
        m[[1, 2, 3, 4]], m0[[1, 2, 3, 4]]
    )  # dead slots keep theirs, as in the original


def test_sample_add_appends_copies_of_sources():
    params, _, opts = _setup()
    before = {k: v.detach().clone() for k, v in params.items()}
    sources = torch.tensor([2, 2, 4])
    new_o, new_s = torch.tensor([0.5, 0.5, 0.7]), torch.zeros(3, 3)
    ops.sample_add(params, opts, sources, new_o, new_s)
    _check_aligned(params, opts)
    assert params["means"].shape[0] == N + 3
    torch.testing.assert_close(params["means"][N:], before["means"][sources])
    torch.testing.assert_close(params["opacities"][[2, 4]], torch.tensor([0.5, 0.7]))
    torch.testing.assert_close(params["opacities"][N:], new_o)
    m = _moments(opts, "means")[0]
    assert (m[[2, 4]] == 0).all() and (m[N:] == 0).all() and (m[[0, 1, 3]] != 0).all()


def test_ops_update_tensors_without_optimiser():
    params, _, opts = _setup()
    params["model"] = nn.Parameter(torch.arange(N), requires_grad=False)
    ops.duplicate(params, opts, torch.tensor([False, False, False, True, True]))
    assert params["model"].tolist() == [0, 1, 2, 3, 4, 3, 4]
    assert not params["model"].requires_grad


def test_inject_noise_uses_full_covariance():
    params, _, _ = _setup()
    params["scales"].data[:] = math.log(2.0)  # isotropic, identity rotation: Sigma = 4 I
    before = params["means"].detach().clone()
    torch.manual_seed(3)
    eps = torch.randn(N, 3)
    torch.manual_seed(3)
    scale = torch.tensor([0.0, 1.0, 0.5, 0.0, 2.0])
    ops.inject_noise(params, scale)
    torch.testing.assert_close(params["means"] - before, 4.0 * eps * scale[:, None])


def test_for_splats_reports_missing_group():
    params, _, _ = _setup()
    optim = Optimizers([ParamGroup("means", [params["means"]], 0.1)])
    with pytest.raises(
        ValueError, match=r"splats\['opacities'\] must be in exactly one param group, found none"
    ):
        optim.for_splats(params)
