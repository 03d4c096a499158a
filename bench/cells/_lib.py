"""Adapters to the library used by several kinds: expert build tasks, loading and rendering experts."""

from __future__ import annotations

from typing import Any

from bench.tasks import Task


def expert_task(task: Task, expert: str, budget: float | None = None) -> Task:
    """Build task of a trained ``expert`` on ``task``'s scene/preset/seed (budget 1.0 = default run);
    the config fields that ``task``'s dataset sets for this expert (``params["expert_config"]``) go with
    it as ``params["config"]``."""
    params: dict[str, Any] = {"expert": expert}
    if budget is not None and float(budget) != 1.0:
        params["budget"] = float(budget)
    config = task.params.get("expert_config", {}).get(expert)
    if config:
        params["config"] = dict(config)
    return task.derive("build", "expert", params)


def load_trained_expert(ctx: Any, build: Task):
    """The trained expert of a build task, in eval mode, on the task's scene."""
    from moegs.train.checkpoint import load_expert

    folder = ctx.artifact(build)
    expert, _state = load_expert(folder, ctx.scene(build))
    return expert


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
