"""Kind ``moe``: MoE-GS over independently trained experts (build: router training; eval: the blend).

Params: ``experts`` (registry names), ``router`` (``vapr`` volume-aware pixel router | ``pixel`` |
``volume``), optional ``single_pass`` (default True; False renders each expert separately),
``prune`` (``"gate"``: gate-aware pruning with the library's default threshold, or a ratio in (0, 1)),
``budget`` (experts trained with that fraction of their iterations, Table XVIII).

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.moe.RouterConfig.from_preset(name)``: dataclass with ``variant``, ``iterations``, ``seed``.
* ``moegs.moe.train_router(experts, scene, config, out_dir, progress=False) -> {"train_seconds", ...}``
  (experts frozen; writes the router checkpoint into ``out_dir``).
* ``moegs.moe.load_moe(out_dir, experts, scene) -> model`` (``nn.Module``) whose
  ``render(camera, background, single_pass=True)`` returns an object with ``image [H, W, 3]``,
  ``gates [K, H, W]`` and ``expert_images [K, H, W, 3]``.
* ``moegs.moe.prune(model, scene, ratio=None) -> dict`` (gate-aware pruning in place).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._eval import evaluate_renderer, module_megabytes
from bench.cells._lib import expert_task, load_trained_expert, train_hours
from bench.tasks import Task

ROUTERS = ("vapr", "pixel", "volume")
ROUTER_API = ("moegs.moe:RouterConfig", "moegs.moe:train_router", "moegs.moe:load_moe")


def missing(params: dict) -> list[str]:
    if params.get("router", "vapr") not in ROUTERS:
        raise ValueError(f"moe: router must be one of {ROUTERS}, got {params.get('router')!r}")
    out = experts_missing(list(params["experts"]))
    for e in params["experts"]:
        out += expert_kind.missing({"expert": e})
    out += [m for m in map(module_missing, ROUTER_API) if m]
    if params.get("prune") is not None:
        out += [m for m in (module_missing("moegs.moe:prune"),) if m]
    return out


def router_task(task: Task, experts: list[str], router: str = "vapr", budget: float | None = None) -> Task:
    """Build task of a trained router over ``experts`` (and the experts' budget and dataset configs)."""
    params: dict[str, Any] = {"experts": list(experts), "router": router}
    if budget is not None and float(budget) != 1.0:
        params["budget"] = float(budget)
    configs = {e: c for e, c in task.params.get("expert_config", {}).items() if e in experts}
    if configs:
        params["expert_config"] = configs
    return task.derive("build", "moe", params)


def artifacts(task: Task) -> list[Task]:
    p = task.params
    return [router_task(task, p["experts"], p.get("router", "vapr"), p.get("budget"))]


def deps(task: Task) -> list[Task]:
    budget = task.params.get("budget")
    return [scene_kind.task_for(task), *(expert_task(task, e, budget) for e in task.params["experts"])]


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    from moegs.moe import RouterConfig, train_router

    experts = [load_trained_expert(ctx, d) for d in deps(task)[1:]]
    cfg = RouterConfig.from_preset(ctx.preset.expert_preset)
    cfg = replace(
        cfg,
        variant=task.params["router"],
        seed=task.seed,
        iterations=ctx.preset.steps(cfg.iterations, ctx.preset.router_steps),
    )
    result = train_router(experts, ctx.scene(task), cfg, out, progress=ctx.progress)
    return {"train_seconds": result.get("train_seconds"), "router": task.params["router"]}


def load_model(ctx: Any, build_task: Task):
    """The MoE-GS model of a router build task (experts and router loaded, eval mode)."""
    from moegs.moe import load_moe

    experts = [load_trained_expert(ctx, d) for d in deps(build_task)[1:]]
    return load_moe(ctx.artifact(build_task), experts, ctx.scene(build_task)).eval()


def run(task: Task, ctx: Any) -> dict[str, Any]:
    scene = ctx.scene(task)
    build_task = artifacts(task)[0]
    model = load_model(ctx, build_task)
    details: dict[str, Any] = {}
    prune = task.params.get("prune")
    if prune is not None:
        from moegs.moe import prune as gate_prune

        details["pruning"] = gate_prune(model, scene, ratio=None if prune == "gate" else float(prune))
    single_pass = bool(task.params.get("single_pass", True))

    def render(camera: Any) -> Any:
        return model.render(camera, scene.background, single_pass=single_pass).image

    out = evaluate_renderer(render, scene, ctx.preset)
    out["metrics"]["memory_mb"] = module_megabytes(model)
    out["metrics"]["train_time_h"] = train_hours(ctx, [*deps(build_task)[1:], build_task])
    out["details"].update(details, single_pass=single_pass)
    return out
