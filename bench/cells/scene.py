"""Build kind ``scene``: prepare a scene once (generate a synthetic stand-in, hash real inputs).

Every other build depends on it, so concurrent workers never generate the same stand-in twice and
every result can name the exact input data it was computed from.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.tasks import Task


def missing(params: dict) -> list[str]:
    from bench.cells import module_missing

    return [m for m in (module_missing("moegs.data:load_scene"),) if m]


def task_for(task: Task) -> Task:
    """The scene build task of any task (same scene, loader arguments, preset and device; seed 0)."""
    return Task("build", "scene", {}, task.scene, task.scene_kwargs, task.preset, 0, task.device)


def deps(task: Task) -> list[Task]:
    return []


def build(task: Task, ctx: Any, out: Path) -> dict[str, Any]:
    from bench.scenes import scene_input_hash

    scene = ctx.scene(task)
    return {
        "scene": scene.name,
        "summary": scene.summary(),
        "stand_in": scene.stand_in,
        "real": scene.is_real,
        "num_train": len(scene.train),
        "num_test": len(scene.test),
        "input_hash": scene_input_hash(task.scene, dict(task.scene_kwargs), ctx.workspace.scene_hash_cache),
    }
