"""``moegs compare``: the experts of one scene share a loaded scene only when they load it alike."""

from __future__ import annotations

from types import SimpleNamespace

import moegs.data
import moegs.train.entry
from moegs.compare import run_expert
from moegs.recipes import config_for


def test_a_scene_is_loaded_once_per_set_of_loader_arguments(monkeypatch, tmp_path):
    loads = []

    def load_scene(name, **kwargs):
        loads.append((name, kwargs))
        return SimpleNamespace(label=f"scene {len(loads)}", train=[], test=[])  # no views: no size to check

    monkeypatch.setattr(moegs.data, "load_scene", load_scene)
    monkeypatch.setattr(moegs.train.entry, "train_recipe", lambda recipe, scene, out, **_: (None, scene))
    white = config_for("fourdgs", "dnerf:mutant", "quick")  # 4DGaussians trains on white
    black = config_for("grid4d", "dnerf:mutant", "quick")  # Grid4D on black
    assert white.background == "white" and black.background == "black"
    scenes: dict = {}
    recipes = enumerate((white, black, white))
    got = [run_expert(r, tmp_path / str(i), None, scenes, False).label for i, r in recipes]
    assert got == ["scene 1", "scene 2", "scene 1"]
    assert [kwargs["background"] for _, kwargs in loads] == ["white", "black"]
    windowed = run_expert(white, tmp_path / "w", (0, 2), scenes, False)
    assert windowed.label == "scene 3" and loads[-1][1]["frames"] == (0, 2)
