"""Kind ``gates``: the router's gate maps, each expert's render and the blend on one test view.

Params: ``experts``, ``router``. ``gate_experts`` = how many experts have the largest gate on at
least 5 % of the pixels (spatially adaptive routing). Needs the MoE-GS API of ``bench.cells.moe``.
"""

from __future__ import annotations

from typing import Any

from bench.cells import moe as moe_kind
from bench.tasks import Task

MIN_SHARE = 0.05


def missing(params: dict) -> list[str]:
    return moe_kind.missing({"experts": params["experts"], "router": params.get("router", "vapr")})


def artifacts(task: Task) -> list[Task]:
    return [moe_kind.router_task(task, task.params["experts"], task.params.get("router", "vapr"))]


def run(task: Task, ctx: Any) -> dict[str, Any]:
    import numpy as np
    import torch

    from moegs.metrics import psnr
    from moegs.train.evaluate import eval_views

    scene = ctx.on_device(moe_kind.moe_scene(ctx, artifacts(task)[0]))
    model = moe_kind.load_model(ctx, artifacts(task)[0])
    views = sorted(eval_views(scene.test, ctx.preset.test_views), key=lambda v: v.camera.time)
    view = views[len(views) // 2]
    with torch.no_grad():
        out = model.render(view.camera, scene.background, single_pass=True)
    gates = out.gates.float()  # [K, H, W]
    lead = torch.bincount(gates.argmax(0).flatten(), minlength=gates.shape[0]).float() / gates[0].numel()
    gt = view.image()
    files_dir = ctx.workspace.files_dir(ctx.task)
    files_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        files_dir / "gates.npz",
        experts=np.array(task.params["experts"]),
        gates=gates.cpu().numpy(),
        expert_images=out.expert_images.clamp(0, 1).cpu().numpy(),
        image=out.image.clamp(0, 1).cpu().numpy(),
        gt=gt.cpu().numpy(),
        view=str(view.key),
    )
    return {
        "metrics": {"gate_experts": int((lead >= MIN_SHARE).sum()), "psnr": float(psnr(out.image, gt))},
        "details": {"lead_share": lead.tolist(), "view": view.key},
        "files": ["gates.npz"],
    }
