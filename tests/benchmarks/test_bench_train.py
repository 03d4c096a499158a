"""Training-step benchmarks: the first ``STEPS`` quick-preset steps of each expert on D-NeRF ``mutant``
(pytest-benchmark; skipped unless ``--benchmark-enable``, e.g. ``tox -e bench``; needs the real scene).

One round = a fresh run (scene loaded, expert built, seeded) trained for ``STEPS`` steps, so ground-truth
decoding of the views it meets counts, as it does in a real run; ``python -m bench.profile`` splits a
step into its parts. Compare two commits with ``--benchmark-save`` / ``--benchmark-compare``. Each round
also records the mean loss of its steps, so a speed-up that changes results shows in ``extra_info``.
"""

from __future__ import annotations

import math

import pytest
import torch
from helpers.training import builtin_experts

pytestmark = pytest.mark.benchmark

SCENE = "dnerf:mutant"
EXPERTS = builtin_experts()
STEPS = 60


def _train_steps(expert: str) -> float:
    from moegs.data import load_scene
    from moegs.recipes import config_for
    from moegs.train.entry import build_expert
    from moegs.train.loop import TrainingRun

    recipe = config_for(expert, SCENE, "quick")
    scene = load_scene(SCENE, **recipe.load_kwargs)
    model = build_expert(recipe, scene)
    run = TrainingRun(model, scene, recipe.config.train, None)
    torch.manual_seed(recipe.config.train.seed)
    model.train()
    return float(sum(run.iteration(step) for step in range(1, STEPS + 1))) / STEPS


@pytest.mark.realdata
@pytest.mark.parametrize("expert", EXPERTS)
def test_quick_training_steps(benchmark, expert, mutant_root):
    loss = benchmark.pedantic(_train_steps, args=(expert,), rounds=3, warmup_rounds=0, iterations=1)
    benchmark.extra_info.update(expert=expert, scene=SCENE, steps=STEPS, mean_loss=loss)
    assert math.isfinite(loss)  # a NaN or Inf would make every timing meaningless
