"""Kind ``trajectory``: motion trajectories of an expert's (or MoDE's) Gaussians and their statistics.

Params: ``expert`` (registry name) or ``mode`` (MoDE deformation experts). Samples ``T`` times in
[0, 1], tracks every Gaussian's mean, keeps the ``K`` that move most (the regions the paper's
figures show) and reports, in units of the scene extent:

* ``speed``: mean path length over the sequence;
* ``curvature``: mean turning angle (radians) between successive displacement steps;
* ``coherence``: mean cosine similarity between a Gaussian's displacement sequence and those of its
  8 nearest neighbours (canonical positions at t=0) - high for shared deformation fields.

Experts whose set of Gaussians changes with time (one model per frame) have no trajectories; the
cell then reports ``None`` values with the reason.
"""

from __future__ import annotations

from typing import Any

from bench.cells import expert as expert_kind
from bench.cells import mode as mode_kind
from bench.cells._lib import expert_task, load_trained_expert, recipe_of
from bench.tasks import Task


def missing(params: dict) -> list[str]:
    if "mode" in params:
        return mode_kind.missing({"experts": params["mode"]})
    return expert_kind.missing({"expert": params["expert"]})


def artifacts(task: Task) -> list[Task]:
    if "mode" in task.params:
        return [mode_kind.mode_task(task, task.params["mode"])]
    return [expert_task(task, task.params["expert"])]


def trajectory_stats(means: Any, extent: float, k: int, neighbours: int = 8) -> dict[str, Any]:
    """Statistics of trajectories ``means [T, N, 3]`` (see module docstring) for the ``k`` most moving."""
    import torch

    steps = means[1:] - means[:-1]  # [T-1, N, 3]
    path = steps.norm(dim=-1).sum(0)  # [N]
    k = min(k, means.shape[1])
    order = torch.argsort(path, descending=True)[:k]
    sel_steps, sel_path = steps[:, order], path[order]
    moving = sel_path > 1e-6 * extent
    out: dict[str, Any] = {
        "selected": order,
        "speed": float(sel_path.mean() / extent),
        "curvature": None,
        "coherence": None,
        "moving_fraction": float((path > 1e-6 * extent).float().mean()),
    }
    if int(moving.sum()) == 0:
        out["reason"] = "no selected Gaussian moves"
        return out
    a, b = sel_steps[:-1], sel_steps[1:]
    na, nb = a.norm(dim=-1), b.norm(dim=-1)
    valid = (na > 1e-9 * extent) & (nb > 1e-9 * extent)
    if bool(valid.any()):
        cos = (a * b).sum(-1)[valid] / (na[valid] * nb[valid])
        out["curvature"] = float(torch.arccos(cos.clamp(-1.0, 1.0)).mean())
    seq = sel_steps.permute(1, 0, 2).reshape(k, -1)  # [k, (T-1)*3]
    seq = seq / seq.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if k > 1:
        canon = means[0, order]
        dist = torch.cdist(canon, canon)
        dist.fill_diagonal_(float("inf"))
        nn = torch.topk(dist, min(neighbours, k - 1), largest=False).indices  # [k, m]
        sims = (seq[:, None, :] * seq[nn]).sum(-1)  # [k, m]
        out["coherence"] = float(sims[moving].mean())
    return out


def run(task: Task, ctx: Any) -> dict[str, Any]:
    import numpy as np
    import torch

    build = artifacts(task)[0]
    recipe = mode_kind.recipe(ctx, build) if "mode" in task.params else recipe_of(ctx, build)
    scene = ctx.scene(task, recipe.background)
    model = load_trained_expert(ctx, build, scene)
    times = torch.linspace(0.0, 1.0, max(2, ctx.preset.trajectory_steps)).tolist()
    with torch.no_grad():
        frames = [model.frame(t) for t in times]
    counts = {f.means.shape[0] for f in frames}
    if len(counts) != 1:
        return {
            "metrics": {"speed": None, "curvature": None, "coherence": None},
            "details": {
                "reason": f"the number of Gaussians changes with time ({sorted(counts)[:4]}...): "
                "no per-Gaussian trajectories"
            },
        }
    means = torch.stack([f.means.detach() for f in frames]).float()
    stats = trajectory_stats(means, float(scene.extent), ctx.preset.trajectory_gaussians)
    files_dir = ctx.workspace.files_dir(ctx.task)
    files_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        files_dir / "trajectories.npz",
        times=np.asarray(times),
        means=means[:, stats["selected"]].cpu().numpy(),
        extent=float(scene.extent),
    )
    metrics = {k: stats[k] for k in ("speed", "curvature", "coherence")}
    details = {
        "num_gaussians": int(means.shape[1]),
        "selected": int(len(stats["selected"])),
        "moving_fraction": stats["moving_fraction"],
        "reason": stats.get("reason"),
    }
    return {"metrics": metrics, "details": details, "files": ["trajectories.npz"]}
