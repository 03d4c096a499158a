"""The one way a resolved recipe becomes a trained expert: seed, build, train (``moegs train``,
``moegs compare``, ``moegs route`` and every bench cell call :func:`train_recipe`), and the one way a run
folder becomes that expert again (:func:`load_trained`). A recipe whose expert trains in temporal segments
(STG's ``segment_frames``) trains and loads as ``moegs.train.segments`` does."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from moegs.data.scene import Scene
from moegs.device import resolve_device
from moegs.experts import get_expert_class
from moegs.experts.base import Expert
from moegs.recipes import Recipe
from moegs.train.checkpoint import load_expert
from moegs.train.loop import train
from moegs.train.segments import SEGMENTS_NAME, load_segments, scene_segments, train_segments


def build_expert(recipe: Recipe, scene: Scene, device: torch.device | str | None = None) -> Expert:
    """The freshly initialised expert of ``recipe`` on ``scene``, on ``device`` (None: the CPU). torch's
    global generator is seeded with the run's seed first, so network initialisation does not depend on
    what ran before; the expert is built on the CPU and then moved, so it starts from the same values on
    every device."""
    torch.manual_seed(recipe.config.train.seed)
    expert = get_expert_class(recipe.expert).from_scene(scene, recipe.config)
    return expert if device is None else expert.to(resolve_device(device))


def finished_run(out_dir: str | Path) -> dict[str, Any] | None:
    """The loop's ``metrics.json`` in ``out_dir`` when that run completed and was evaluated, else None (an
    interrupted run is resumed from its checkpoint by training into the same folder)."""
    path = Path(out_dir) / "metrics.json"
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON ({err}); remove it to run again") from err
    return result if result.get("completed") and result.get("test") else None


def train_recipe(
    recipe: Recipe,
    scene: Scene,
    out_dir: str | Path | None = None,
    *,
    device: torch.device | str | None = None,
    **kwargs: Any,
) -> tuple[Expert, dict[str, Any]]:
    """Build and train the expert of ``recipe`` on ``scene`` (loaded with ``recipe.load_kwargs``) on
    ``device`` (None: the CPU); ``kwargs`` go to ``moegs.train.loop.train``. Returns the expert (eval mode)
    and the loop's result; an expert with several temporal segments on ``scene`` trains one model per
    segment (``moegs.train.segments.train_segments``: an ``STGSegments`` and the whole run's result)."""
    if len(scene_segments(scene, recipe.config)) > 1:
        return train_segments(
            scene, recipe.config, out_dir, recipe=recipe.provenance(), device=device, **kwargs
        )
    expert = build_expert(recipe, scene, device)
    result = train(expert, scene, out_dir=out_dir, recipe=recipe.provenance(), **kwargs)
    return expert, result


def load_trained(
    out_dir: str | Path, scene: Scene, expect: str | None = None, device: torch.device | str | None = None
) -> tuple[Any, dict[str, Any]]:
    """The trained expert of the run folder ``out_dir`` on ``scene`` (eval mode, on ``device``; None: the
    CPU) and its state: the ``STGSegments`` of a segmented run (``segments.json``), else
    ``moegs.train.checkpoint.load_expert``'s expert (``expect`` refuses another expert's run, naming
    both)."""
    out = Path(out_dir)
    if (out / SEGMENTS_NAME).is_file():
        return load_segments(out, scene, expect=expect, device=device)
    return load_expert(out, scene, expect=expect, device=device)
