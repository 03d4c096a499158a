"""Adapters to the library used by several kinds: recipes of build tasks, training, loading, rendering and
scoring experts."""

from __future__ import annotations

from typing import Any

from bench.cells._eval import evaluate_cell, module_megabytes
from bench.tasks import Task

RUN_FIELDS = (
    "train.seed",
    "train.max_eval_views",
    "train.metric_profile",
    "train.eval_every",
    "train.checkpoint_every",
    "train.select_best_at",
)
"""Fields the bench sets on every recipe (seed and evaluation protocol); everything else is the
resolver's (``moegs.recipes.config_for``), plus a dataset's conventions (``params["config"]``) and the
bench preset's iteration override or budget."""


def expert_task(task: Task, expert: str, budget: float | None = None) -> Task:
    """Build task of a trained ``expert`` on ``task``'s scene/preset/seed/dataset (budget 1.0 = default
    run); the config fields that ``task``'s dataset sets for this expert (``params["expert_config"]``)
    go with it as ``params["config"]``."""
    params: dict[str, Any] = {"expert": expert, "dataset": task.params.get("dataset")}
    if budget is not None and float(budget) != 1.0:
        params["budget"] = float(budget)
    config = task.params.get("expert_config", {}).get(expert)
    if config:
        params["config"] = dict(config)
    return task.derive("build", "expert", params)


def recipe_of(ctx: Any, task: Task, expert: str | None = None, extra: dict | None = None, steps=None):
    """The ``moegs.recipes.Recipe`` a build task trains with: the resolver's recipe at the bench preset's
    expert preset, the dataset's conventions (``params["config"]``) and ``extra`` fields, the preset's
    iteration override (``steps``, default ``train_steps``) times the budget (schedules unchanged: the run
    is cut short) and the run fields (``RUN_FIELDS``). On a real scene of a dataset the preset stretches
    (``BenchPreset.stretched``), the quick schedules are first stretched to that length
    (``bench.schedules.scaled_overrides``). ``expert`` defaults to ``params["expert"]``."""
    from bench.schedules import scaled_overrides
    from moegs.recipes import config_for

    p = ctx.preset
    name = expert or task.params["expert"]
    overrides = {**task.params.get("config", {}), **(extra or {})}
    dataset = task.params.get("dataset")
    stretch = p.stretched(dataset, not task.scene.startswith("synthetic:"))
    if stretch is not None:
        overrides = {**scaled_overrides(name, task.scene, stretch), **overrides}
    base = config_for(name, task.scene, p.expert_preset, dataset=dataset, overrides=overrides)
    overrides["train.iterations"] = p.steps(
        base.config.train.iterations,
        p.train_steps if steps is None else steps,
        task.params.get("budget", 1.0),
    )
    overrides.update(
        {
            "train.seed": task.seed,
            "train.max_eval_views": p.test_views,
            "train.metric_profile": p.metric_profile,
            "train.eval_every": 0,
            "train.checkpoint_every": p.checkpoint_every,
            "train.select_best_at": (),  # the tables score the last model; no test-set selection
        }
    )
    return config_for(name, task.scene, p.expert_preset, dataset=dataset, overrides=overrides)


def load_trained_expert(ctx: Any, build: Task, scene: Any = None):
    """The trained expert of a build task, in eval mode, on ``ctx.device``, for ``scene`` (default: the
    task's scene on its recipe's background)."""
    from moegs.train.entry import load_trained

    folder = ctx.artifact(build)
    if scene is None:
        recipe = recipe_of(ctx, build)
        scene = ctx.scene(build, recipe.background, **recipe.loader_args)
    expert, _state = load_trained(folder, scene, device=ctx.device)
    return expert


def shared_background(ctx: Any, builds: list[Task]) -> str:
    """The background several experts are combined on: the first one's; on RGBA data (D-NeRF) every
    expert must have trained on it (``ValueError`` otherwise)."""
    from moegs.recipes import dataset_of

    recipes = [recipe_of(ctx, b) for b in builds]
    backgrounds = {r.background for r in recipes}
    if len(backgrounds) > 1 and dataset_of(builds[0].scene) == "dnerf":
        raise ValueError(
            f"{builds[0].scene}: experts train on different backgrounds "
            f"({', '.join(f'{r.expert} {r.background}' for r in recipes)}); RGBA ground truth needs one"
        )
    return recipes[0].background


def expert_renderer(expert: Any, background: Any):
    """``camera -> rgb [H, W, 3]`` for one expert (the training loop's own render path)."""
    from moegs.train.evaluate import render_view

    def render(camera: Any) -> Any:
        return render_view(expert, camera, background)[0]

    return render


def train_hours(ctx: Any, builds: list[Task]) -> float:
    """Sum of the training wall-clock of ``builds`` in hours."""
    total = 0.0
    for b in builds:
        meta = ctx.meta(b)
        total += float(meta.get("train_seconds") or meta.get("build_seconds") or 0.0)
    return total / 3600.0


def train_build(ctx: Any, task: Task, recipe: Any, out: Any) -> dict[str, Any]:
    """Train ``recipe`` on ``task``'s scene (on the recipe's background) into ``out``, on ``ctx.device``; the
    build's record."""
    from moegs.train.entry import train_recipe

    scene = ctx.scene(task, recipe.background, **recipe.loader_args)
    _, result = train_recipe(recipe, scene, out, device=ctx.device, progress=ctx.progress)
    return {
        "train_seconds": result["train_seconds"],
        "iterations": result["iterations"],
        "num_gaussians": result["num_gaussians"],
        "final_loss": result["final_loss"],
        "train_eval_psnr": (result.get("test") or {}).get("psnr"),
        "recipe": recipe.provenance(),
    }


def evaluate_model(ctx: Any, model: Any, scene: Any, builds: list[Task]) -> dict[str, Any]:
    """The cell of one trained model (``evaluate_cell`` on ``scene`` placed on the model's device) with its
    memory, the training hours of ``builds`` and its number of Gaussians."""
    native = ctx.native_scene(scene)
    scene = ctx.on_device(scene)
    out = evaluate_cell(expert_renderer(model, scene.background), scene, ctx.preset, native=native)
    out["metrics"]["memory_mb"] = module_megabytes(model)
    out["metrics"]["train_time_h"] = train_hours(ctx, builds)
    out["details"]["num_gaussians"] = model.num_gaussians
    return out
