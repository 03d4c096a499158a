"""Kind ``bestmap``: which expert is best where and when (Fig. 1b spatial, Fig. 1c temporal).

Params: ``experts``. Renders every expert on the evaluation views:

* spatial: on the view in the middle of the sequence, the per-pixel winner (lowest L1 error),
  ``winners`` = how many experts win at least 5 % of the pixels, the winner map's spatial coherence and
  each expert's share of the dynamic and of the static pixels (when the scene has masks);
* temporal: per time step the expert with the best PSNR on the **dynamic region** (averaged over the
  views of that time; the full image when the scene has no masks) and ``switches`` = how often that
  winner changes along time; ``switches_full`` is the same on full-image PSNR.
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


def spatial_winners(errors: Any, mask: Any, names: list[str]) -> dict[str, Any]:
    """The per-pixel winner of ``errors [K, H, W]`` (lowest error; ``K = len(names)``): ``winner [H, W]``,
    each expert's ``shares`` of all pixels, how many ``winners`` hold at least ``MIN_SHARE``, the winner
    map's ``coherence``, and ``region_shares`` of the dynamic and static pixels (None without ``mask``)."""
    import torch

    from moegs.moe.model import region_shares, winner_coherence

    scores = -errors  # the best expert scores highest
    winner = scores.argmax(0)
    shares = torch.bincount(winner.flatten(), minlength=len(names)).float() / winner.numel()
    return {
        "winner": winner,
        "shares": dict(zip(names, shares.tolist(), strict=True)),
        "winners": int((shares >= MIN_SHARE).sum()),
        "coherence": winner_coherence(scores),
        "region_shares": region_shares(scores, mask) if mask is not None else None,
    }


def run(task: Task, ctx: Any) -> dict[str, Any]:
    import numpy as np
    import torch

    from moegs.metrics import psnr
    from moegs.train.evaluate import eval_views

    loaded = ctx.scene(task, shared_background(ctx, artifacts(task)))
    scene = ctx.on_device(loaded)
    names = list(task.params["experts"])
    renders = [
        expert_renderer(load_trained_expert(ctx, b, loaded), scene.background) for b in artifacts(task)
    ]
    views = sorted(eval_views(scene.test, ctx.preset.test_views), key=lambda v: v.camera.time)
    per_time: dict[float, list[list[float]]] = {}  # full-image PSNR per view and expert
    per_time_dynamic: dict[float, list[list[float]]] = {}
    mid = views[len(views) // 2]
    spatial = None
    with torch.no_grad():
        for view in views:
            gt, mask = view.image(), view.mask()
            images = [r(view.camera).detach().clamp(0, 1) for r in renders]
            t = round(float(view.camera.time), 6)
            per_time.setdefault(t, []).append([float(psnr(img, gt)) for img in images])
            if mask is not None and bool((mask > 0.5).any()):
                dynamic = (mask > 0.5).float()
                per_time_dynamic.setdefault(t, []).append([float(psnr(img, gt, dynamic)) for img in images])
            if view is mid:
                errors = torch.stack([(img - gt).abs().mean(-1) for img in images])  # [K, H, W]
                spatial = (errors, gt, torch.stack(images), mask)
    errors, gt, images, mask = spatial
    where = spatial_winners(errors, mask, names)
    times = sorted(per_time)
    mean_psnr = np.array([np.mean(per_time[t], axis=0) for t in times])  # [T, K]
    by_region = len(per_time_dynamic) == len(per_time)  # every time step has dynamic pixels
    mean_dynamic = np.array([np.mean(per_time_dynamic[t], axis=0) for t in times]) if by_region else None
    best = (mean_dynamic if by_region else mean_psnr).argmax(1)
    best_full = mean_psnr.argmax(1)
    switches = int((best[1:] != best[:-1]).sum())
    files_dir = ctx.workspace.files_dir(ctx.task)
    files_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        files_dir / "bestmap.npz",
        experts=np.array(names),
        winner=where["winner"].cpu().numpy(),
        errors=errors.cpu().numpy(),
        gt=gt.cpu().numpy(),
        images=images.clamp(0, 1).cpu().numpy(),
        times=np.array(times),
        psnr=mean_psnr,
        psnr_dynamic=mean_dynamic if by_region else np.zeros((0, len(names))),
        view=str(mid.key),
    )
    return {
        "metrics": {
            "winners": where["winners"],
            "switches": switches,
            "switches_full": int((best_full[1:] != best_full[:-1]).sum()),
            "coherence": where["coherence"],
        },
        "details": {
            "shares": where["shares"],
            "region_shares": where["region_shares"],
            "temporal_region": "dynamic" if by_region else "full",
            "best_per_time": [names[i] for i in best],
            "best_per_time_full": [names[i] for i in best_full],
            "view": mid.key,
            "min_share": MIN_SHARE,
        },
        "files": ["bestmap.npz"],
    }
