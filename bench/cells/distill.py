"""Kind ``distill``: an expert trained from scratch under MoE-GS supervision (KD loss).

Params: ``student`` (expert name), ``teacher`` (the MoE-GS expert set), ``router``, ``weighted``
(True: the routing-weighted KD loss, "Distilled (Ours)"; False: "w/o Weight").

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.moe.DistillConfig.from_preset(name)``: dataclass with ``iterations`` (None: the student's
  own), ``weighted``, ``seed``;
* ``moegs.moe.distill(student, teacher, scene, config, out_dir, progress=False) -> {"train_seconds"}``,
  writing a checkpoint that ``moegs.train.checkpoint.load_expert`` reads.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import module_missing
from bench.cells import moe as moe_kind
from bench.cells._lib import evaluate_model, expert_task, load_trained_expert, recipe_of
from bench.tasks import Task

DISTILL_API = ("moegs.moe:DistillConfig", "moegs.moe:distill")


def missing(params: dict) -> list[str]:
    out = moe_kind.missing({"experts": params["teacher"], "router": params.get("router", "vapr")})
    out += expert_kind.missing({"expert": params["student"]})
    return out + [m for m in map(module_missing, DISTILL_API) if m]


def _teacher(task: Task) -> Task:
    return moe_kind.router_task(task, task.params["teacher"], task.params.get("router", "vapr"))


def artifacts(task: Task) -> list[Task]:
    return [task.derive("build", "distill", dict(task.params))]


def deps(task: Task) -> list[Task]:
    return [_teacher(task)]


def config(ctx: Any, task: Task) -> tuple[Any, Any]:
    """``(the student's recipe, the DistillConfig)`` of a distillation build task at ``ctx.preset``."""
    from moegs.moe import DistillConfig

    recipe = recipe_of(ctx, expert_task(task, task.params["student"]))
    cfg = DistillConfig.from_preset(ctx.preset.expert_preset)
    cfg = replace(
        cfg,
        weighted=bool(task.params["weighted"]),
        seed=task.seed,
        iterations=ctx.preset.steps(
            cfg.iterations or recipe.config.train.iterations, ctx.preset.distill_steps
        ),
    )
    return recipe, cfg


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    from moegs.moe import distill
    from moegs.train.entry import build_expert

    scene = moe_kind.moe_scene(ctx, _teacher(task))
    teacher = moe_kind.load_model(ctx, _teacher(task))  # on ctx.device: distill moves the student there
    recipe, cfg = config(ctx, task)
    student = build_expert(recipe, scene)
    result = distill(student, teacher, scene, cfg, out, progress=ctx.progress)
    return {"train_seconds": result.get("train_seconds")}


def run(task: Task, ctx: Any) -> dict[str, Any]:
    scene = moe_kind.moe_scene(ctx, _teacher(task))
    build_task = artifacts(task)[0]
    student = load_trained_expert(ctx, build_task, scene)
    return evaluate_model(ctx, student, scene, [build_task])
