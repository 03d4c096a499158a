"""Kind ``mode``: MoDE, several deformation experts on one shared canonical Gaussian set.

Params: ``base`` (the canonical-deformation baseline) and ``experts`` (deformation experts, base
first). MoDE is trained by the one training loop like any expert, so this kind reuses ``expert``'s
build and eval with the MoDE expert.

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.mode.MoDEExpert``: an ``Expert`` registered as ``"mode"`` in ``moegs.experts``;
* ``moegs.mode.MoDEConfig.from_preset(name)``: its config, with a ``experts`` field (deformation
  expert names, base first) and the usual ``train`` field.

The config is MoDE's recipe (``moegs.recipes.config_for("mode", ...)``: the authors' code conventions,
members on the scene's dataset recipes) with the bench's run fields (``_lib.recipe_of``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.cells import expert_missing, experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._lib import evaluate_model, load_trained_expert, recipe_of, train_build
from bench.tasks import Task

MODE_API = ("moegs.mode:MoDEExpert", "moegs.mode:MoDEConfig")


def missing(params: dict) -> list[str]:
    out = [m for m in map(module_missing, MODE_API) if m]
    if not out:
        out += [m for m in (expert_missing("mode"),) if m]
    return out + experts_missing(list(params["experts"]))


def mode_task(task: Task, experts: list[str]) -> Task:
    return task.derive("build", "mode", {"experts": list(experts), "dataset": task.params.get("dataset")})


def artifacts(task: Task) -> list[Task]:
    return [mode_task(task, task.params["experts"])]


def deps(task: Task) -> list[Task]:
    return [scene_kind.task_for(task)]


def recipe(ctx: Any, task: Task):
    """MoDE's recipe for a build task (members ``params["experts"]``, base first)."""
    extra = {"experts": tuple(task.params["experts"])}
    return recipe_of(ctx, task, expert="mode", extra=extra, steps=ctx.preset.mode_steps)


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    return train_build(ctx, task, recipe(ctx, task), out)


def run(task: Task, ctx: Any) -> dict[str, Any]:
    build_task = artifacts(task)[0]
    scene = ctx.scene(task, recipe(ctx, build_task).background)
    model = load_trained_expert(ctx, build_task, scene)
    return evaluate_model(ctx, model, scene, [build_task])
