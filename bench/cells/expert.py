"""Kind ``expert``: train one expert with the GT loss (build) and score it (eval).

Params: ``expert`` (registry name), ``dataset`` (whose recipe applies), optional ``budget`` (fraction of
the training iterations, with the expert's schedules unchanged: the run is cut short, as the paper's
wall-clock budgets) and ``config`` (the dataset's conventions, e.g. STG† on N3V).
Training settings are the recipe (``moegs.recipes.config_for`` at ``BenchPreset.expert_preset``, see
``_lib.recipe_of``); the bench preset may override the number of iterations (``train_steps``), and sets
seed and evaluation views. The scene is loaded on the recipe's background.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.cells import LOAD_EXPERT, TRAIN_LOOP, experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._lib import evaluate_model, expert_task, load_trained_expert, recipe_of, train_build
from bench.tasks import Task


def missing(params: dict) -> list[str]:
    return experts_missing([params["expert"]]) + [
        m for m in map(module_missing, (TRAIN_LOOP, LOAD_EXPERT)) if m
    ]


def artifacts(task: Task) -> list[Task]:
    return [expert_task(task, task.params["expert"], task.params.get("budget"))]


def deps(task: Task) -> list[Task]:
    return [scene_kind.task_for(task)]


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    return train_build(ctx, task, recipe_of(ctx, task), out)


def run(task: Task, ctx: Any) -> dict[str, Any]:
    build_task = artifacts(task)[0]
    expert = load_trained_expert(ctx, build_task)
    recipe = recipe_of(ctx, build_task)
    scene = ctx.scene(task, recipe.background, **recipe.loader_args)  # the ground truth it trained on
    out = evaluate_model(ctx, expert, scene, [build_task])
    out["details"]["iterations"] = ctx.meta(build_task).get("iterations")
    return out
