"""Harness fixtures without training: finished cell results written by hand, and ``resolve_scenes`` as if
only some real scenes were staged."""

from __future__ import annotations

from bench.results import SCHEMA, write_result
from bench.scenes import SceneRef


def write_ok_result(workspace, task, extra: dict | None = None, **metrics: float) -> None:
    """A finished evaluation of ``task`` in ``workspace`` with ``metrics`` (``psnr=...``, ``ssim=...``) and
    the result fields in ``extra`` (``details``, ``artifacts`` ...)."""
    result = {"schema": SCHEMA, "status": "ok", "key": task.key, "task": task.to_dict(), "metrics": metrics}
    write_result(workspace.result_path(task), {**result, "versions": {}, "timings": {}, **(extra or {})})


def staged_scenes(*names: str):
    """A ``bench.plan.resolve_scenes`` replacement: exactly the real scenes ``names`` (``dataset:scene``)
    are staged; every other dataset falls back to its stand-in."""
    from bench.datasets import get_dataset

    def resolve(dataset, preset, only=()):
        ds = get_dataset(dataset)
        mine = [n for n in names if n.startswith(f"{dataset}:")]
        if mine:
            return [SceneRef(n, dataset, ds.column_of(n.split(":", 1)[1]), True) for n in mine]
        return [SceneRef(f"synthetic:{ds.stand_in}", dataset, None, False)]

    return resolve
