"""SetOptimizer: each set's rows move bit for bit as torch's Adam / RAdam on that set's own tensor."""

from __future__ import annotations

from functools import partial

import pytest
import torch

from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.set_optim import SetOptimizer, row_sets

TORCH = {
    kind: partial(cls, foreach=True)  # the implementation moegs.train.optim runs (torch's CUDA default)
    for kind, cls in (("adam", torch.optim.Adam), ("radam", torch.optim.RAdam))
}
OPTIONS = {"lr": 0.01, "betas": (0.9, 0.999), "eps": 1e-8}


def _grads(steps: int, rows: int = 8) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return [torch.randn(rows, 3, generator=g) for _ in range(steps)]


def _step(opt, param, grad) -> None:
    param.grad = grad.clone()
    opt.step()


@pytest.mark.parametrize("kind", ["adam", "radam"])
def test_without_second_rows_it_is_torchs_optimizer(kind):
    start = torch.randn(8, 3, generator=torch.Generator().manual_seed(1))
    ours, ref = torch.nn.Parameter(start.clone()), torch.nn.Parameter(start.clone())
    opt = SetOptimizer([ours], kind, lambda: torch.zeros(8, dtype=torch.bool), **OPTIONS)
    ref_opt = TORCH[kind]([ref], **OPTIONS)
    for grad in _grads(12):
        _step(opt, ours, grad)
        _step(ref_opt, ref, grad)
    assert torch.equal(ours, ref)
    assert float(opt.state[ours]["step"]) == 12 and float(opt.state[ours]["step_second"]) == 0


@pytest.mark.parametrize("kind", ["adam", "radam"])
def test_rows_joining_the_second_set_late_start_its_count(kind):
    """Rows 4-7 join the second set after 3 updates with fresh moments (as an Ex4DGS conversion): from then
    on they move as a fresh torch optimiser on their own tensor, rows 0-3 as the first one went on."""
    start = torch.randn(8, 3, generator=torch.Generator().manual_seed(1))
    second = torch.zeros(8, dtype=torch.bool)
    ours = torch.nn.Parameter(start.clone())
    opt = SetOptimizer([ours], kind, lambda: second, **OPTIONS)
    first_ref = torch.nn.Parameter(start[:4].clone())
    first_opt = TORCH[kind]([first_ref], **OPTIONS)
    grads = _grads(10)
    for grad in grads[:3]:
        _step(opt, ours, grad)
        _step(first_opt, first_ref, grad[:4])
    second[4:] = True
    for key in ("exp_avg", "exp_avg_sq"):
        opt.state[ours][key][4:] = 0
    second_ref = torch.nn.Parameter(ours.detach()[4:].clone())
    second_opt = TORCH[kind]([second_ref], **OPTIONS)
    for grad in grads[3:]:
        _step(opt, ours, grad)
        _step(first_opt, first_ref, grad[:4])
        _step(second_opt, second_ref, grad[4:])
    assert torch.equal(ours[:4], first_ref) and torch.equal(ours[4:], second_ref)
    assert (float(opt.state[ours]["step"]), float(opt.state[ours]["step_second"])) == (10, 7)


def test_a_set_that_held_rows_goes_on_counting_when_emptied():
    second = torch.zeros(4, dtype=torch.bool)
    p = torch.nn.Parameter(torch.zeros(4, 3))
    opt = SetOptimizer([p], "adam", lambda: second, **OPTIONS)
    second[1] = True
    _step(opt, p, torch.ones(4, 3))
    second[1] = False
    _step(opt, p, torch.ones(4, 3))
    assert (float(opt.state[p]["step"]), float(opt.state[p]["step_second"])) == (2, 2)


def test_bad_sets_and_kinds_are_named():
    p = torch.nn.Parameter(torch.zeros(4, 3))
    with pytest.raises(ValueError, match="kind must be one of"):
        SetOptimizer([p], "sgd", lambda: torch.zeros(4, dtype=torch.bool))
    opt = SetOptimizer([p], "adam", lambda: torch.zeros(5, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"gives \(5,\) rows for \(4, 3\)"):
        _step(opt, p, torch.ones(4, 3))


@pytest.mark.parametrize("kind", ["adam", "radam"])
def test_a_group_with_a_second_set_gets_a_set_optimizer(kind):
    p = torch.nn.Parameter(torch.zeros(4, 3))
    rows = torch.zeros(4, dtype=torch.bool)
    optimizers = Optimizers([ParamGroup("x", [p], 0.1, optimizer=kind, second_set=lambda: rows)])
    opt = optimizers.optimizers["x"]
    assert isinstance(opt, SetOptimizer) and opt.kind == kind and opt.second_set() is rows


@pytest.mark.parametrize("kind", ["adam", "radam"])
def test_the_second_set_learns_at_its_own_rate(kind):
    """Ex4DGS's dynamic colour on Technicolor Birthday (``feature_motion_lr`` 2.5e-4 against 2.5e-3): each
    set moves as torch's optimiser at its own rate on its own tensor."""
    start = torch.randn(8, 3, generator=torch.Generator().manual_seed(1))
    second = torch.arange(8) % 2 == 1
    ours = torch.nn.Parameter(start.clone())
    opt = SetOptimizer([ours], kind, lambda: second, **OPTIONS, second_lr=0.001)
    refs = [torch.nn.Parameter(start[rows].clone()) for rows in (~second, second)]
    ref_opts = [TORCH[kind]([refs[0]], **OPTIONS), TORCH[kind]([refs[1]], **{**OPTIONS, "lr": 0.001})]
    for grad in _grads(12):
        _step(opt, ours, grad)
        for ref, ref_opt, rows in zip(refs, ref_opts, (~second, second), strict=True):
            _step(ref_opt, ref, grad[rows])
    assert torch.equal(ours[~second], refs[0]) and torch.equal(ours[second], refs[1])


def test_a_second_rate_needs_a_second_set_and_a_constant_rate():
    p = torch.nn.Parameter(torch.zeros(4, 3))
    rows = torch.zeros(4, dtype=torch.bool)
    with pytest.raises(ValueError, match="'x': second_lr needs a second_set"):
        ParamGroup("x", [p], 0.1, second_lr=0.01)
    with pytest.raises(ValueError, match="'x': second_lr needs a second_set and a constant lr"):
        ParamGroup("x", [p], 0.1, lr_final=0.001, second_set=lambda: rows, second_lr=0.01)
    group = ParamGroup("x", [p], 0.1, second_set=lambda: rows, second_lr=0.01)
    assert Optimizers([group]).optimizers["x"].param_groups[0]["second_lr"] == 0.01


def test_every_optimizer_runs_torchs_foreach_implementation():
    """The originals ran on CUDA, where torch defaults to foreach; on CPU it would not (RAdam differs)."""
    start = torch.randn(256, 3, generator=torch.Generator().manual_seed(2))
    param = torch.nn.Parameter(start.clone())
    groups = [ParamGroup("means", [param], lr=0.01, optimizer="radam")]
    opt = Optimizers(groups).optimizers["means"]
    assert opt.defaults["foreach"] is True
    single, foreach = (torch.nn.Parameter(start.clone()) for _ in range(2))
    eps = groups[0].eps
    opts = [
        torch.optim.RAdam([p], lr=0.01, eps=eps, foreach=f) for p, f in ((single, False), (foreach, True))
    ]
    for grad in _grads(40, rows=256):  # RAdam rectifies from step 6 on
        for o, p in zip(opts, (single, foreach), strict=True):
            _step(o, p, grad)
        _step(opt, param, grad)
    assert torch.equal(param, foreach) and not torch.equal(foreach, single)


def test_row_sets_are_read_once_per_change_of_the_flags():
    """The answer is kept on the flags for their version and storage: in-place writes, a new tensor and a
    move find the rows again; a read of unchanged flags returns the kept answer."""
    flags = torch.tensor([False, True, False, True])
    rows = row_sets(flags)
    assert rows.first.tolist() == [0, 2] and rows.second.tolist() == [1, 3]
    assert row_sets(flags) is rows
    flags[0] = True
    assert row_sets(flags).second.tolist() == [0, 1, 3]
    param = torch.nn.Parameter(flags.clone(), requires_grad=False)
    kept = row_sets(param)
    param.data = torch.zeros(4, dtype=torch.bool)  # what Module.to does to a parameter
    assert row_sets(param) is not kept and row_sets(param).second.numel() == 0
