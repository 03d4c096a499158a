"""Trained experts shared across tests, cached on disk.

``trained_expert("static", "dnerf:mutant", "quick")`` trains once and keeps the run under
``<cache_root>/test-runs/<expert>_<scene>_<preset>_<code hash>/`` (``MOEGS_CACHE`` or ``.cache/``);
later calls (in this or a later session) reload the checkpoint. The code hash is the library's code
version (every module and the C kernel; docstrings and comments aside), so any library change retrains.
An interrupted run resumes from its last checkpoint. Scenes whose data is absent skip the calling test
with the reason.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

from bench.keys import code_version
from moegs.data.scene import Scene
from moegs.experts import list_experts
from moegs.experts.base import Expert
from moegs.paths import cache_root


def builtin_experts() -> list[str]:
    """Registry names of the built-in single experts (no composite, no plugin), sorted."""
    return [s.name for s in list_experts() if not s.composite and s.plugin is None]


@dataclass
class TrainedRun:
    """A finished training run. Treat ``expert`` as read-only: it is shared between tests."""

    expert: Expert
    scene: Scene
    metrics: dict
    path: Path


def code_hash() -> str:
    """12 hex digits of the library's code version (``bench.keys.code_version``: every ``moegs`` module's
    syntax tree without docstrings, and the C kernel's sources)."""
    return code_version()[:12]


def run_dir(name: str, scene: str, preset: str) -> Path:
    return cache_root() / "test-runs" / f"{name}_{scene.replace(':', '_')}_{preset}_{code_hash()}"


@cache
def load_test_scene(scene: str, **load_kwargs) -> Scene:
    """A scene by name, loaded with ``load_kwargs`` (cached per session); skips the test when its data
    is not staged."""
    from moegs.data import load_scene

    try:
        return load_scene(scene, **load_kwargs)
    except FileNotFoundError as err:
        pytest.skip(f"scene {scene!r} unavailable: {err}")


@cache
def trained_expert(name: str, scene: str, preset: str = "quick") -> TrainedRun:
    """The expert ``name`` trained on ``scene`` with the resolver's recipe at ``preset``
    (``moegs.recipes.config_for``: what ``moegs train`` and the bench run), from the cache or trained now."""
    from moegs.recipes import config_for
    from moegs.train.entry import load_trained, train_recipe

    recipe = config_for(name, scene, preset)
    loaded = load_test_scene(scene, **recipe.load_kwargs)
    path = run_dir(name, scene, preset)
    metrics_file = path / "metrics.json"
    if metrics_file.is_file() and json.loads(metrics_file.read_text()).get("completed"):
        expert, _ = load_trained(path, loaded, expect=name)  # a segmented run (STG on mutant) too
        return TrainedRun(expert, loaded, json.loads(metrics_file.read_text()), path)
    expert, metrics = train_recipe(recipe, loaded, path, progress=False)
    return TrainedRun(expert, loaded, metrics, path)
