"""``bench.schedules``: quick schedules stretched to N iterations (``standard`` preset, convergence study)."""

from __future__ import annotations

import pytest

from bench import schedules
from moegs.experts.base import QUICK_ITERATIONS
from moegs.recipes import config_for
from moegs.train.strategy import NEVER

SCENES = ("dnerf:mutant", "n3v:coffee_martini", "technicolor:Birthday")
"""Recipes with different quick values: unset fields (None), a deformation from step 0, never, tuples."""
CASES = [(e, s) for e in sorted(schedules.SCHEDULE_FIELDS) for s in SCENES]


def _times(value, k: int):
    """What stretching by an integer ``k`` must give: unset, 0 and never stay; tuples element-wise."""
    if isinstance(value, tuple):
        return tuple(_times(v, k) for v in value)
    return value if value is None or value == 0 or value >= NEVER else k * value


def test_quick_length_matches_the_library():
    assert schedules.QUICK_ITERATIONS == QUICK_ITERATIONS


@pytest.mark.parametrize(("expert", "scene"), CASES)
def test_scaling_is_the_identity_at_the_quick_length_and_linear_beyond(expert, scene):
    quick = config_for(expert, scene, "quick").reductions
    same = schedules.scaled_overrides(expert, scene, QUICK_ITERATIONS)
    assert all(quick[k] == v for k, v in same.items())
    five = schedules.scaled_overrides(expert, scene, 5 * QUICK_ITERATIONS)
    assert five["train.iterations"] == 3000
    for key in schedules.SCHEDULE_FIELDS[expert]:
        assert five[key] == _times(quick[key], 5), key
    stretched = config_for(expert, scene, "quick", overrides=five).config
    assert stretched.train.iterations == 3000
    for key in set(schedules.INTERVAL_FIELDS) & set(quick):  # the periods keep their quick value
        assert _field(stretched, key) == quick[key], key
    for key in schedules.SCHEDULE_FIELDS[expert]:
        assert _field(stretched, key) == five[key], key


def _field(config, dotted: str):
    for name in dotted.split("."):
        config = getattr(config, name)
    return config


@pytest.mark.parametrize(("expert", "scene"), CASES)
def test_every_schedule_field_is_either_stretched_or_a_kept_period(expert, scene):
    quick = config_for(expert, scene, "quick").reductions
    words = ("steps", "warm_up", "_from", "_until", "_every", "_interval", "iterations", "_at", "_gap")
    schedule_like = {k for k in quick if any(w in k for w in words) and k != "train.iterations"}
    stretched, kept = set(schedules.SCHEDULE_FIELDS[expert]), schedule_like & set(schedules.INTERVAL_FIELDS)
    assert not stretched & kept
    assert schedule_like == stretched | kept


def test_unknown_expert_names_the_table():
    with pytest.raises(ValueError, match="no schedule table for expert 'mode'.*deformable"):
        schedules.scaled_overrides("mode", "dnerf:mutant", 600)


def test_a_run_length_below_one_is_refused():
    with pytest.raises(ValueError, match="iterations must be >= 1, got 0"):
        schedules.scaled_overrides("grid4d", "dnerf:mutant", 0)


def test_a_stretched_value_is_the_nearest_step_and_at_least_one():
    assert schedules._stretch(5, 1.9) == 10  # 9.5: rounded, not truncated
    assert schedules._stretch(7, 1.3) == 9
    assert schedules._stretch(3, 0.1) == 1  # a scheduled event never moves to step 0
    assert schedules._stretch((5, None, 0, NEVER), 1.9) == (10, None, 0, NEVER)
