"""Gate-aware pruning while the router trains (the authors' accumulator and schedule): which steps prune,
what the accumulator scores, and that a pruning run removes the same rows from experts, router and
optimiser moments, resumes exactly and reloads onto freshly loaded experts."""

from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene, untrained_experts

from moegs.moe import RouterConfig, load_moe, train_router
from moegs.moe.model import MoEGS
from moegs.moe.prune import WeightGradients
from moegs.moe.train import prune_step
from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=3, size=32, num_points=80)


@pytest.fixture(scope="module")
def trained(scene):
    """Two different experts (two copies of one would route by symmetry: every weight gradient zero)."""
    return untrained_experts(scene)


def fresh(trained):
    """Copies of the experts: a pruning run prunes the ones it is given."""
    return copy.deepcopy(trained)


def cfg(**kw) -> RouterConfig:
    return replace(RouterConfig.from_preset("quick"), **{"iterations": 8, **kw})


def test_the_code_schedule_prunes_nine_times_and_scales_with_the_run():
    code = RouterConfig.from_preset("code").with_progressive_pruning()
    assert [s for s in range(1, 5001) if prune_step(code, s)] == list(range(500, 5000, 500))
    quick = RouterConfig.from_preset("quick").with_progressive_pruning()
    assert [s for s in range(1, quick.iterations + 1) if prune_step(quick, s)] == list(range(30, 300, 30))
    assert not any(prune_step(RouterConfig.from_preset("quick"), s) for s in range(1, 301))
    with pytest.raises(ValueError, match="prune_every"):
        RouterConfig(prune_every=-1)


def test_the_score_is_the_mean_over_the_steps_a_gaussian_had_a_gradient(scene, trained):
    model = MoEGS(fresh(trained), cfg())
    gradients = WeightGradients(model)
    mix = model.router.weights.mix[0]
    n = mix.shape[0]
    for values in ([3e-5, 4e-6, 0.0], [1e-5, 0.0, 0.0]):  # Gaussians 0, 1, 2: seen twice, once, never
        grad = torch.zeros_like(mix)
        grad[:3, 0] = torch.tensor(values)
        mix.grad = grad
        gradients.add(model)
    assert gradients.seen[0][:3].tolist() == [2, 1, 0]
    torch.testing.assert_close(gradients.total[0][:3], torch.tensor([4e-5, 4e-6, 0.0]))
    keep = gradients.prune_masks(1e-5)[0]
    assert keep[:3].tolist() == [True, False, True]  # means 2e-5 and 4e-6; the unseen one is not judged
    assert keep[3:].all() and keep.shape == (n,)
    gradients.restart([keep, torch.ones(model.experts[1].num_gaussians, dtype=torch.bool)])
    assert gradients.total[0].shape == (n - 1,) and not gradients.seen[0].any()


def test_keep_rows_carries_the_moments_of_the_kept_rows():
    param = torch.nn.Parameter(torch.arange(10.0).reshape(5, 2))
    optimizers = Optimizers([ParamGroup("w", [param], lr=0.1, optimizer="radam")])
    (param**2).sum().backward()
    optimizers.step()
    state = optimizers.optimizers["w"].state[param]
    keep = torch.tensor([True, False, True, True, False])
    smaller = torch.nn.Parameter(param.detach()[keep].clone())
    optimizers.keep_rows(param, smaller, keep)
    moved = optimizers.optimizers["w"].state[smaller]
    torch.testing.assert_close(moved["exp_avg"], state["exp_avg"][keep])
    assert moved["step"] == state["step"] and param not in optimizers.optimizers["w"].state
    (smaller**2).sum().backward()
    optimizers.step()  # the optimiser goes on with the smaller parameter
    with pytest.raises(ValueError, match="in no optimiser"):
        optimizers.keep_rows(param, smaller, keep)


def every_other(self, threshold):
    """A pruning rule whose rows are known: every second Gaussian of each expert goes."""
    return [torch.arange(len(t), device=t.device) % 2 == 0 for t in self.total]


def test_the_accumulator_survives_a_resume(scene, trained, tmp_path):
    """The sums collected before an interruption count after it: with no pruning due in the run, the
    checkpoint of an interrupted and resumed run holds the same sums as the uninterrupted one's."""
    from moegs.moe.model import read_router

    config = cfg(prune_every=100, prune_from=100)  # accumulates every step, prunes never
    train_router(fresh(trained), scene, config, tmp_path / "whole")
    train_router(fresh(trained), scene, config, tmp_path / "cut", stop_after=4)
    train_router(fresh(trained), scene, config, tmp_path / "cut")
    whole, cut = (read_router(tmp_path / name)["weight_gradients"] for name in ("whole", "cut"))
    for key in ("total", "seen"):
        for a, b in zip(whole[key], cut[key], strict=True):
            torch.testing.assert_close(a, b, atol=1e-9, rtol=0)
    assert all(int(s.max()) > 4 for s in whole["seen"])  # steps after the cut at 4 added to those before


def test_a_pruning_run_resumes_exactly_and_reloads(scene, trained, tmp_path, monkeypatch):
    monkeypatch.setattr(WeightGradients, "prune_masks", every_other)
    config = cfg(prune_every=3, prune_from=3)  # prunes after steps 3 and 6
    counts = [e.num_gaussians for e in trained]
    full_experts = fresh(trained)
    full = train_router(full_experts, scene, config, tmp_path / "full")
    after = [e.num_gaussians for e in full_experts]
    assert after == [len(range(0, len(range(0, n, 2)), 2)) for n in counts]
    assert full["pruned_fraction"] == pytest.approx(1 - sum(after) / sum(counts))

    train_router(fresh(trained), scene, config, tmp_path / "cut", stop_after=4)  # after the first pruning
    resumed = train_router(fresh(trained), scene, config, tmp_path / "cut")
    assert resumed["resumed_from"] == 4 and resumed["test"]["psnr"] == pytest.approx(full["test"]["psnr"])

    assert load_moe(tmp_path / "full", full_experts, scene).num_gaussians == sum(after)  # already pruned
    reloaded_experts = fresh(trained)
    model = load_moe(tmp_path / "full", reloaded_experts, scene)
    assert [e.num_gaussians for e in reloaded_experts] == after
    assert [int(m.sum()) for m in model.kept] == after and [m.numel() for m in model.kept] == counts
    kept_means = trained[0].splats["means"][model.kept[0]]
    torch.testing.assert_close(reloaded_experts[0].splats["means"], kept_means)
    for key, value in load_moe(tmp_path / "cut", fresh(trained)).router.state_dict().items():
        torch.testing.assert_close(value, model.router.state_dict()[key], atol=1e-6, rtol=0)
