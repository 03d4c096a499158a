"""``bench.schedules``: quick schedules stretched to N iterations (``standard`` preset, convergence study)."""

from __future__ import annotations

import pytest

from bench import schedules
from moegs.experts.static import QUICK_ITERATIONS
from moegs.recipes import config_for
from moegs.train.strategy import NEVER

SCENE = "dnerf:mutant"
KEPT = ("strategy.densify_every", "strategy.prune_every")
"""Iteration-valued quick fields that are intervals and keep their quick value (see the module docstring)."""


def test_quick_length_matches_the_library():
    assert schedules.QUICK_ITERATIONS == QUICK_ITERATIONS


@pytest.mark.parametrize("expert", sorted(schedules.SCHEDULE_FIELDS))
def test_scaling_is_the_identity_at_the_quick_length_and_linear_beyond(expert):
    quick = config_for(expert, SCENE, "quick").reductions
    same = schedules.scaled_overrides(expert, SCENE, QUICK_ITERATIONS)
    assert all(quick[k] == v for k, v in same.items())
    five = schedules.scaled_overrides(expert, SCENE, 5 * QUICK_ITERATIONS)
    assert five["train.iterations"] == 3000
    for key in schedules.SCHEDULE_FIELDS[expert]:
        assert five[key] == (quick[key] if quick[key] >= NEVER else 5 * quick[key]), key
    scaled = config_for(expert, SCENE, "quick", overrides=five).config
    assert scaled.strategy.densify_every == config_for(expert, SCENE, "quick").config.strategy.densify_every


@pytest.mark.parametrize("expert", sorted(schedules.SCHEDULE_FIELDS))
def test_no_schedule_field_of_the_quick_reduction_is_forgotten(expert):
    quick = config_for(expert, SCENE, "quick").reductions
    words = ("steps", "warm_up", "_from", "_until", "reset_every", "_every", "iterations", "_at")
    schedule_like = {k for k in quick if any(w in k for w in words) and k != "train.iterations"}
    assert schedule_like == set(schedules.SCHEDULE_FIELDS[expert]) | (schedule_like & set(KEPT))


def test_unknown_expert_names_the_table():
    with pytest.raises(ValueError, match="no schedule table for expert 'stg'.*deformable"):
        schedules.scaled_overrides("stg", SCENE, 600)
