"""Kind ``expert``: train one expert with the GT loss (build) and score it (eval).

Params: ``expert`` (registry name), optional ``budget`` (fraction of the training iterations, with
the expert's schedules unchanged: the run is cut short, as the paper's wall-clock budgets).
Training settings come from the expert's own preset (``BenchPreset.expert_preset``); the bench preset
may override the number of iterations (``train_steps``), and sets seed and evaluation views.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.cells import LOAD_EXPERT, TRAIN_LOOP, experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._eval import evaluate_renderer, module_megabytes
from bench.cells._lib import expert_renderer, expert_task, load_trained_expert
from bench.tasks import Task


def missing(params: dict) -> list[str]:
    return experts_missing([params["expert"]]) + [
        m for m in map(module_missing, (TRAIN_LOOP, LOAD_EXPERT)) if m
    ]


def artifacts(task: Task) -> list[Task]:
    return [expert_task(task, task.params["expert"], task.params.get("budget"))]


def deps(task: Task) -> list[Task]:
    return [scene_kind.task_for(task)]


def train_config(cls: Any, ctx: Any, task: Task):
    """The expert config for ``task``: preset, the dataset's fields (``params["config"]``), seed,
    iterations (override x budget), evaluation."""
    cfg = replace(cls.config_class.from_preset(ctx.preset.expert_preset), **task.params.get("config", {}))
    iterations = ctx.preset.steps(
        cfg.train.iterations, ctx.preset.train_steps, task.params.get("budget", 1.0)
    )
    train = replace(
        cfg.train,
        seed=task.seed,
        iterations=iterations,
        max_eval_views=ctx.preset.test_views,
        metric_profile=ctx.preset.metric_profile,
        eval_every=0,
        checkpoint_every=ctx.preset.checkpoint_every,
    )
    return replace(cfg, train=train)


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    import torch

    from moegs.experts import get_expert_class
    from moegs.train.loop import train

    scene = ctx.scene(task)
    cls = get_expert_class(task.params["expert"])
    cfg = train_config(cls, ctx, task)
    torch.manual_seed(task.seed)
    expert = cls.from_scene(scene, cfg)
    result = train(expert, scene, cfg.train, out_dir=out, progress=ctx.progress)
    return {
        "train_seconds": result["train_seconds"],
        "iterations": result["iterations"],
        "num_gaussians": result["num_gaussians"],
        "final_loss": result["final_loss"],
        "train_eval_psnr": (result.get("test") or {}).get("psnr"),
    }


def run(task: Task, ctx: Any) -> dict[str, Any]:
    scene = ctx.scene(task)
    build_task = artifacts(task)[0]
    expert = load_trained_expert(ctx, build_task)
    out = evaluate_renderer(expert_renderer(expert, scene.background), scene, ctx.preset)
    meta = ctx.meta(build_task)
    out["metrics"]["memory_mb"] = module_megabytes(expert)
    out["metrics"]["train_time_h"] = float(meta.get("train_seconds") or 0.0) / 3600.0
    out["details"].update(num_gaussians=expert.num_gaussians, iterations=meta.get("iterations"))
    return out
