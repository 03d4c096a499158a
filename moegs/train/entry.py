"""The one way a resolved recipe becomes a trained expert: seed, build, train (``moegs train``,
``moegs compare``, ``moegs route`` and every bench cell call :func:`train_recipe`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from moegs.data.scene import Scene
from moegs.experts import get_expert_class
from moegs.experts.base import Expert
from moegs.recipes import Recipe
from moegs.train.loop import train


def build_expert(recipe: Recipe, scene: Scene) -> Expert:
    """The freshly initialised expert of ``recipe`` on ``scene``; torch's global generator is seeded with
    the run's seed first, so network initialisation does not depend on what ran before."""
    torch.manual_seed(recipe.config.train.seed)
    return get_expert_class(recipe.expert).from_scene(scene, recipe.config)


def train_recipe(
    recipe: Recipe, scene: Scene, out_dir: str | Path | None = None, **kwargs: Any
) -> tuple[Expert, dict[str, Any]]:
    """Build and train the expert of ``recipe`` on ``scene`` (loaded with ``recipe.load_kwargs``);
    ``kwargs`` go to ``moegs.train.loop.train``. Returns the expert (eval mode) and the loop's result."""
    expert = build_expert(recipe, scene)
    result = train(expert, scene, out_dir=out_dir, recipe=recipe.provenance(), **kwargs)
    return expert, result
