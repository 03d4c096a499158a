"""Kind ``mdc``: multi-view depth consistency (Appendix, eq. MDC) of an expert or of lifted MoE-GS.

Params: ``expert``, or ``experts`` + ``router`` (MoE-GS lifted to one Gaussian set). At a few test
times, the model is rendered (depth) from ``preset.mdc_views`` distinct training cameras and the
library's MDC (mean L1 reprojection error over ordered view pairs) is averaged over times.

Library API this kind calls (until it exists, cells report "not implemented yet: <name>"):

* ``moegs.metrics.mdc.mdc(depths: list[Tensor [H, W]], cameras: list[Camera]) -> float``;
* ``moegs.moe.compute_responsibilities(model, views, background)`` and ``moegs.moe.lift(model, t) ->
  GaussianFrame`` (MoE-GS only: gates lifted to Gaussians over all training views, then fused).
"""

from __future__ import annotations

from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import module_missing
from bench.cells import moe as moe_kind
from bench.cells._lib import expert_task, load_trained_expert, recipe_of
from bench.tasks import Task

MDC_API = "moegs.metrics.mdc:mdc"


def missing(params: dict) -> list[str]:
    out = [m for m in (module_missing(MDC_API),) if m]
    if "experts" in params:
        out += moe_kind.missing({"experts": params["experts"], "router": params.get("router", "vapr")})
        out += [m for m in map(module_missing, ("moegs.moe:lift", "moegs.moe:compute_responsibilities")) if m]
    else:
        out += expert_kind.missing({"expert": params["expert"]})
    return out


def artifacts(task: Task) -> list[Task]:
    if "experts" in task.params:
        return [moe_kind.router_task(task, task.params["experts"], task.params.get("router", "vapr"))]
    return [expert_task(task, task.params["expert"])]


def _cameras(scene: Any, k: int) -> list[Any]:
    """``k`` training cameras with distinct poses spread over the rig (multi-view: distinct camera ids;
    monocular: views evenly spaced along the sequence, each its own pose)."""
    by_id: dict[Any, Any] = {}
    for view in scene.train:
        by_id.setdefault(view.camera.camera_id, view.camera)
    cams = list(by_id.values()) if len(by_id) >= k else [v.camera for v in scene.train]
    step = max(1, len(cams) // max(k, 1))
    return cams[::step][:k]


def run(task: Task, ctx: Any) -> dict[str, Any]:
    import torch

    from moegs.metrics.mdc import mdc
    from moegs.render import rasterize
    from moegs.train.evaluate import eval_views

    build_task = artifacts(task)[0]
    if "experts" in task.params:
        from moegs.moe import compute_responsibilities, lift

        scene = moe_kind.moe_scene(ctx, build_task)
        model = moe_kind.load_model(ctx, build_task)
        compute_responsibilities(model, scene.train, scene.background)

        def frame_at(t: float) -> Any:
            return lift(model, t)
    else:
        scene = ctx.scene(task, recipe_of(ctx, build_task).background)
        model = load_trained_expert(ctx, build_task, scene)

        def frame_at(t: float) -> Any:
            return model.frame(t)

    cams = _cameras(ctx.on_device(scene), max(2, ctx.preset.mdc_views))
    times = sorted({round(float(v.camera.time), 6) for v in eval_views(scene.test, ctx.preset.test_views)})
    per_time = []
    with torch.no_grad():
        for t in times:
            frame = frame_at(t)
            depths = [rasterize(frame, cam).depth for cam in cams]
            per_time.append(float(mdc(depths, cams)))
    return {
        "metrics": {"mdc": sum(per_time) / len(per_time)},
        "details": {"per_time": dict(zip(map(str, times), per_time, strict=True)), "cameras": len(cams)},
    }
