"""3DGS exponential learning-rate schedule at hand-checked steps."""

import math

import pytest
import torch

from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.schedules import expon_lr, group_lr

LR0, LR1, STEPS = 1.6e-4, 1.6e-6, 30_000  # 3DGS position_lr_init / _final / _max_steps


@pytest.mark.parametrize(
    ("step", "expected"),
    [
        (0, 1.6e-4),
        (3_000, 1.6e-4 * 100**-0.1),  # 10 % of the way in log space: 1.00953e-4
        (15_000, 1.6e-5),  # geometric mean
        (30_000, 1.6e-6),
        (45_000, 1.6e-6),  # held after max_steps
    ],
)
def test_expon_lr_values(step, expected):
    assert expon_lr(step, LR0, LR1, STEPS) == pytest.approx(expected, rel=1e-12)


def test_expon_lr_delay_ramp():
    # 3DGS delay: delay_mult + (1 - delay_mult) * sin(pi/2 * clip(step / delay_steps, 0, 1))
    assert expon_lr(0, 1.0, 0.01, 100, delay_steps=10, delay_mult=0.01) == pytest.approx(0.01)
    lerp = math.exp(math.log(0.01) * 0.05)
    expected = (0.01 + 0.99 * math.sin(math.pi / 4)) * lerp
    assert expon_lr(5, 1.0, 0.01, 100, delay_steps=10, delay_mult=0.01) == pytest.approx(expected)
    assert expon_lr(20, 1.0, 0.01, 100, delay_steps=10, delay_mult=0.01) == pytest.approx(0.01**0.2)


def test_expon_lr_edge_cases():
    assert expon_lr(-1, LR0, LR1, STEPS) == 0.0
    assert expon_lr(10, 0.0, 0.0, STEPS) == 0.0
    with pytest.raises(ValueError, match="max_steps must be positive"):
        expon_lr(0, LR0, LR1, 0)
    with pytest.raises(ValueError, match="both be > 0"):
        expon_lr(0, LR0, 0.0, STEPS)


def test_group_lr_constant_and_stage_offset():
    p = [torch.zeros(1, requires_grad=True)]
    assert group_lr(ParamGroup("opacities", p, 0.05), 12_345) == 0.05
    staged = ParamGroup("means", p, LR0, lr_final=LR1, max_steps=STEPS, start_step=3_000)
    assert group_lr(staged, 3_000) == pytest.approx(LR0)
    assert group_lr(staged, 18_000) == pytest.approx(1.6e-5)


def test_optimizers_apply_schedule_and_eps():
    means, opac = torch.zeros(4, 3, requires_grad=True), torch.zeros(4, requires_grad=True)
    opt = Optimizers(
        [
            ParamGroup("means", [means], LR0, lr_final=LR1, max_steps=STEPS),
            ParamGroup("opacities", [opac], 0.05, optimizer="radam"),
        ]
    )
    rates = opt.set_step(15_000)
    assert rates == {"means": pytest.approx(1.6e-5), "opacities": 0.05}
    assert opt.optimizers["means"].param_groups[0]["lr"] == pytest.approx(1.6e-5)
    assert opt.optimizers["means"].param_groups[0]["eps"] == 1e-15
    assert isinstance(opt.optimizers["opacities"], torch.optim.RAdam)
    with pytest.raises(ValueError, match="unknown optimizer 'sgd'"):
        Optimizers([ParamGroup("x", [means], 1.0, optimizer="sgd")])
