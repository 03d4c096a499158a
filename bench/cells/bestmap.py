"""Kind ``bestmap``: which expert is best where and when (Fig. 1b spatial, Fig. 1c temporal).

Params: ``experts``. Renders every expert on the evaluation views:

* spatial: on the view in the middle of the sequence, the per-pixel winner (lowest L1 error) and
  ``winners`` = how many experts win at least 5 % of the pixels;
* temporal: per time step the expert with the best PSNR (averaged over the views of that time) and
  ``switches`` = how often the winner changes along time.
"""

from __future__ import annotations

from typing import Any

from bench.cells import expert as expert_kind
from bench.cells._lib import expert_renderer, expert_task, load_trained_expert, shared_background
from bench.tasks import Task

MIN_SHARE = 0.05


def missing(params: dict) -> list[str]:
    return [m for e in params["experts"] for m in expert_kind.missing({"expert": e})]


def artifacts(task: Task) -> list[Task]:
    return [expert_task(task, e) for e in task.params["experts"]]


def run(task: Task, ctx: Any) -> dict[str, Any]:
    import numpy as np
    import torch

    from moegs.metrics import psnr
    from moegs.train.evaluate import eval_views

    scene = ctx.scene(task, shared_background(ctx, artifacts(task)))
    names = list(task.params["experts"])
    renders = [expert_renderer(load_trained_expert(ctx, b, scene), scene.background) for b in artifacts(task)]
    views = sorted(eval_views(scene.test, ctx.preset.test_views), key=lambda v: v.camera.time)
    per_time: dict[float, list[list[float]]] = {}
    mid = views[len(views) // 2]
    spatial = None
    with torch.no_grad():
        for view in views:
            gt = view.image()
            images = [r(view.camera).detach() for r in renders]
            per_time.setdefault(round(float(view.camera.time), 6), []).append(
                [float(psnr(img.clamp(0, 1), gt)) for img in images]
            )
            if view is mid:
                errors = torch.stack([(img - gt).abs().mean(-1) for img in images])  # [K, H, W]
                spatial = (errors, gt, torch.stack(images))
    errors, gt, images = spatial
    winner = errors.argmin(0)
    shares = torch.bincount(winner.flatten(), minlength=len(names)).float() / winner.numel()
    times = sorted(per_time)
    mean_psnr = np.array([np.mean(per_time[t], axis=0) for t in times])  # [T, K]
    best = mean_psnr.argmax(1)
    switches = int((best[1:] != best[:-1]).sum())
    files_dir = ctx.workspace.files_dir(ctx.task)
    files_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        files_dir / "bestmap.npz",
        experts=np.array(names),
        winner=winner.numpy(),
        errors=errors.numpy(),
        gt=gt.numpy(),
        images=images.clamp(0, 1).numpy(),
        times=np.array(times),
        psnr=mean_psnr,
        view=str(mid.key),
    )
    return {
        "metrics": {"winners": int((shares >= MIN_SHARE).sum()), "switches": switches},
        "details": {
            "shares": dict(zip(names, shares.tolist(), strict=True)),
            "best_per_time": [names[i] for i in best],
            "view": mid.key,
            "min_share": MIN_SHARE,
        },
        "files": ["bestmap.npz"],
    }
