"""``bench.context.Context``: a cell's scene is loaded once per loader arguments (the background
included), and its native-resolution twin only where the preset scores upsampled renders of a real scene
loaded smaller."""

from __future__ import annotations

from bench.context import Context
from bench.store import Workspace
from bench.tasks import Task


def _task(scene: str, scale: float) -> Task:
    return Task("eval", "expert", {"expert": "static"}, scene, {"resolution_scale": scale}, "standard", 0)


def test_a_scene_is_loaded_once_per_arguments_and_its_native_twin_only_where_scored(tmp_path, monkeypatch):
    loads = []

    def load(name, kwargs):
        loads.append((name, kwargs))
        return object()

    monkeypatch.setattr("bench.scenes.load", load)
    ctx = Context(Workspace(tmp_path), "standard")  # scores real scenes upsampled to native
    small = _task("dnerf:mutant", 0.125)
    black = ctx.scene(small, "black")
    assert ctx.scene(small, "black") is black and len(loads) == 1
    white = ctx.scene(small, "white")
    assert white is not black and loads[-1] == (
        "dnerf:mutant",
        {"resolution_scale": 0.125, "background": "white"},
    )
    ctx.native_scene(white)
    assert loads[-1] == ("dnerf:mutant", {"resolution_scale": 1.0, "background": "white"})
    count = len(loads)
    assert ctx.native_scene(ctx.scene(_task("dnerf:mutant", 1.0), "black")) is None  # already native
    assert ctx.native_scene(ctx.scene(_task("synthetic:dnerf_like", 0.5))) is None  # a stand-in has no native
    quick = Context(Workspace(tmp_path), "quick")  # does not score upsampled renders
    assert quick.native_scene(quick.scene(small, "white")) is None
    assert len(loads) == count + 3  # the three scenes, no native twin
