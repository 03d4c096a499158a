"""Kind ``moe``: MoE-GS over independently trained experts (build: router training; eval: the blend).

Params: ``experts`` (registry names), ``router`` (``vapr`` volume-aware pixel router | ``pixel`` |
``volume``), optional ``single_pass`` (default True; False renders each expert separately),
``prune`` (``"train"``: the router trains with gate-aware pruning on the authors' schedule, moved to the
run's length, ``RouterConfig.with_progressive_pruning``; ``"gate"``: the trained model is pruned once
with the library's default threshold; or a ratio in (0, 1), once),
``budget`` (experts trained with that fraction of their iterations, Table XVIII), ``convention``
(``code``, default: the authors' code conventions that produced the paper's numbers; ``paper``: the
paper's wording, an extra row of Table VI). The router is trained and evaluated on the experts' shared
background (``_lib.shared_background``), on the device the experts are loaded on (``ctx.device``).

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.moe.router_config_for(scale, convention, scene=, dataset=)``: a ``RouterConfig`` dataclass with
  ``variant``, ``iterations``, ``seed`` (the authors' per-dataset rates under the ``code`` convention).
* ``moegs.moe.train_router(experts, scene, config, out_dir, progress=False) -> {"train_seconds", ...}``
  (experts frozen; writes the router checkpoint into ``out_dir``).
* ``moegs.moe.load_moe(out_dir, experts, scene) -> model`` (``nn.Module``) whose
  ``render(camera, background, single_pass=True)`` returns an object with ``image [H, W, 3]``,
  ``gates [K, H, W]`` and ``expert_images [K, H, W, 3]``.
* ``moegs.moe.prune(model, scene, ratio=None) -> dict`` (gate-aware pruning in place).
* ``RouterConfig.with_progressive_pruning()``; ``load_moe``'s model has ``kept`` after such a router.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import experts_missing, module_missing
from bench.cells import scene as scene_kind
from bench.cells._eval import evaluate_cell, module_megabytes
from bench.cells._lib import expert_task, load_trained_expert, shared_background, train_hours
from bench.tasks import Task

ROUTERS = ("vapr", "pixel", "volume")
PRUNE_WHILE_TRAINING = "train"
ROUTER_API = ("moegs.moe:router_config_for", "moegs.moe:train_router", "moegs.moe:load_moe")


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


def router_task(
    task: Task,
    experts: list[str],
    router: str = "vapr",
    budget: float | None = None,
    convention: str = "code",
    prune: Any = None,
) -> Task:
    """Build task of a trained router over ``experts`` (and the experts' budget and dataset configs); a
    router pruning while it trains (``prune="train"``) is a build of its own."""
    params: dict[str, Any] = {
        "experts": list(experts),
        "router": router,
        "dataset": task.params.get("dataset"),
    }
    if prune == PRUNE_WHILE_TRAINING:
        params["prune"] = PRUNE_WHILE_TRAINING
    if budget is not None and float(budget) != 1.0:
        params["budget"] = float(budget)
    if convention != "code":
        params["convention"] = convention
    configs = {e: c for e, c in task.params.get("expert_config", {}).items() if e in experts}
    if configs:
        params["expert_config"] = configs
    return task.derive("build", "moe", params)


def artifacts(task: Task) -> list[Task]:
    p = task.params
    return [
        router_task(
            task,
            p["experts"],
            p.get("router", "vapr"),
            p.get("budget"),
            p.get("convention", "code"),
            p.get("prune"),
        )
    ]


def deps(task: Task) -> list[Task]:
    budget = task.params.get("budget")
    return [scene_kind.task_for(task), *(expert_task(task, e, budget) for e in task.params["experts"])]


def router_config(ctx: Any, task: Task):
    """The ``RouterConfig`` of a router build task: the preset of the bench scale (``router_scale``, else
    the experts' scale) and convention, with the bench preset's iteration override and checkpoint
    interval (an interrupted router build resumes from its last checkpoint)."""
    from moegs.moe import router_config_for

    cfg = router_config_for(
        ctx.preset.router_scale or ctx.preset.expert_preset,
        task.params.get("convention", "code"),
        scene=task.scene,
        dataset=task.params.get("dataset"),
    )
    cfg = replace(
        cfg,
        variant=task.params["router"],
        seed=task.seed,
        iterations=ctx.preset.steps(cfg.iterations, ctx.preset.router_steps),
        checkpoint_every=ctx.preset.checkpoint_every,
    )
    return cfg.with_progressive_pruning() if task.params.get("prune") == PRUNE_WHILE_TRAINING else cfg


def moe_scene(ctx: Any, build_task: Task):
    """The scene a router build task trains and evaluates on (the experts' shared background)."""
    return ctx.scene(build_task, shared_background(ctx, deps(build_task)[1:]))


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    from moegs.moe import train_router

    experts = [load_trained_expert(ctx, d) for d in deps(task)[1:]]
    cfg = router_config(ctx, task)
    result = train_router(experts, moe_scene(ctx, task), cfg, out, progress=ctx.progress)
    return {"train_seconds": result.get("train_seconds"), "router": task.params["router"]}


def load_model(ctx: Any, build_task: Task):
    """The MoE-GS model of a router build task (experts and router loaded, eval mode)."""
    from moegs.moe import load_moe

    experts = [load_trained_expert(ctx, d) for d in deps(build_task)[1:]]
    return load_moe(ctx.artifact(build_task), experts, moe_scene(ctx, build_task)).eval()


def routing_signal(gates: list[Any], views: list[Any]) -> dict[str, Any]:
    """Mean over ``views`` (with their gate maps, in order) of the winner map's spatial coherence and of
    the share of dynamic / static pixels each expert wins (views without a mask: coherence only)."""
    from moegs.moe import region_shares, winner_coherence

    coherence, shares = [], []
    for g, view in zip(gates, views, strict=False):
        coherence.append(winner_coherence(g))
        mask = view.mask()
        if mask is not None:
            shares.append(region_shares(g, mask))
    out: dict[str, Any] = {"coherence": sum(coherence) / len(coherence), "views": len(coherence)}
    for region in ("dynamic", "static"):
        per_view = [s[region] for s in shares]
        out[f"{region}_share"] = (
            [sum(col) / len(per_view) for col in zip(*per_view, strict=True)] if per_view else []
        )
    return out


def run(task: Task, ctx: Any) -> dict[str, Any]:
    from moegs.train.evaluate import eval_views

    build_task = artifacts(task)[0]
    scene = moe_scene(ctx, build_task)
    model = load_model(ctx, build_task)
    details: dict[str, Any] = {}
    prune = task.params.get("prune")
    if prune == PRUNE_WHILE_TRAINING:
        if model.kept is None:
            raise RuntimeError(f"moe: the router of {build_task.key} was to prune while training and did not")
        before = [int(m.numel()) for m in model.kept]
        after = [e.num_gaussians for e in model.experts]
        details["pruning"] = {
            "when": "training",
            "before": before,
            "after": after,
            "removed_fraction": 1.0 - sum(after) / max(sum(before), 1),
            "threshold": model.config.prune_threshold,
        }
    elif prune is not None:
        from moegs.moe import prune as gate_prune

        ratio = None if prune == "gate" else float(prune)
        details["pruning"] = {"when": "after training", **gate_prune(model, scene, ratio=ratio)}
    native = ctx.native_scene(scene)
    scene = ctx.on_device(scene)
    single_pass = bool(task.params.get("single_pass", True))
    gates: list[Any] = []  # the gate maps of the evaluation renders (the speed renders come after)

    def render(camera: Any) -> Any:
        out = model.render(camera, scene.background, single_pass=single_pass)
        gates.append(out.gates)
        return out.image

    out = evaluate_cell(render, scene, ctx.preset, native=native)
    details["routing"] = routing_signal(gates, eval_views(scene.test, ctx.preset.test_views))
    out["metrics"]["memory_mb"] = module_megabytes(model)
    out["metrics"]["train_time_h"] = train_hours(ctx, [*deps(build_task)[1:], build_task])
    out["details"].update(details, single_pass=single_pass)
    return out
