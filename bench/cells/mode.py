"""Kind ``mode``: MoDE, several deformation experts on one shared canonical Gaussian set.

Params: ``base`` (the canonical-deformation baseline) and ``experts`` (deformation experts, base
first). MoDE is trained by the one training loop like any expert, so this kind reuses ``expert``'s
build and eval with the MoDE expert.

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.mode.MoDEExpert``: an ``Expert`` registered as ``"mode"`` in ``moegs.experts``;
* ``moegs.mode.MoDEConfig.from_preset(name)``: its config, with a ``experts`` field (deformation
  expert names, base first) and the usual ``train`` field.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import expert_missing, experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._eval import evaluate_renderer, module_megabytes
from bench.cells._lib import expert_renderer, load_trained_expert
from bench.tasks import Task

MODE_API = ("moegs.mode:MoDEExpert", "moegs.mode:MoDEConfig")


def missing(params: dict) -> list[str]:
    out = [m for m in map(module_missing, MODE_API) if m]
    if not out:
        out += [m for m in (expert_missing("mode"),) if m]
    return out + experts_missing(list(params["experts"]))


def mode_task(task: Task, experts: list[str]) -> Task:
    return task.derive("build", "mode", {"experts": list(experts)})


def artifacts(task: Task) -> list[Task]:
    return [mode_task(task, task.params["experts"])]


def deps(task: Task) -> list[Task]:
    return [scene_kind.task_for(task)]


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    import torch
    from moegs.mode import MoDEConfig, MoDEExpert

    from moegs.train.loop import train

    scene = ctx.scene(task)
    cfg = MoDEConfig.from_preset(ctx.preset.expert_preset)
    cfg = replace(cfg, experts=list(task.params["experts"]))
    iterations = ctx.preset.steps(cfg.train.iterations, ctx.preset.mode_steps)
    cfg = replace(
        cfg, train=replace(expert_kind.train_config(MoDEExpert, ctx, task).train, iterations=iterations)
    )
    torch.manual_seed(task.seed)
    model = MoDEExpert.from_scene(scene, cfg)
    result = train(model, scene, cfg.train, out_dir=out, progress=ctx.progress)
    return {
        "train_seconds": result["train_seconds"],
        "iterations": result["iterations"],
        "num_gaussians": result["num_gaussians"],
    }


def run(task: Task, ctx: Any) -> dict[str, Any]:
    scene = ctx.scene(task)
    build_task = artifacts(task)[0]
    model = load_trained_expert(ctx, build_task)
    out = evaluate_renderer(expert_renderer(model, scene.background), scene, ctx.preset)
    meta = ctx.meta(build_task)
    out["metrics"]["memory_mb"] = module_megabytes(model)
    out["metrics"]["train_time_h"] = float(meta.get("train_seconds") or 0.0) / 3600.0
    out["details"]["num_gaussians"] = model.num_gaussians
    return out
