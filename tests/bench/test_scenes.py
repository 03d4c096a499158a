"""``bench.scenes``: which scenes a dataset's cells run on (the real ones present, at most the preset's
count, in paper order; else one stand-in that says so), how they are loaded, and the input hash a result
records; with them the datasets' printed names and the presets' budgeted step counts."""

from __future__ import annotations

import json
import os

from bench.datasets import get_dataset
from bench.presets import get_preset
from bench.scenes import SceneRef, folder_hash, load, load_kwargs, resolve_scenes


def test_real_scenes_in_paper_order_up_to_the_presets_count(tmp_path, monkeypatch):
    for scene in ("mutant", "lego"):
        (tmp_path / "dnerf" / scene).mkdir(parents=True)
        (tmp_path / "dnerf" / scene / "transforms_train.json").write_text("{}")
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    lego, mutant = (
        SceneRef("dnerf:lego", "dnerf", "Lego", True),
        SceneRef("dnerf:mutant", "dnerf", "Mutant", True),
    )
    assert resolve_scenes("dnerf", get_preset("quick")) == [lego]  # quick: one real scene a dataset
    assert resolve_scenes("dnerf", get_preset("standard")) == [lego, mutant]
    assert resolve_scenes("dnerf", get_preset("quick"), only=("mutant",)) == [mutant]
    assert lego.label == "dnerf:lego"


def test_a_dataset_without_real_scenes_gets_one_stand_in_that_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    (stand_in,) = resolve_scenes("n3v", get_preset("standard"))
    assert stand_in == SceneRef("synthetic:n3v_like", "n3v", None, False)
    assert stand_in.label == "synthetic:n3v_like (synthetic stand-in for N3V (Neural 3D Video))"


def test_load_kwargs_are_the_papers_protocol_under_the_presets_scale():
    n3v = SceneRef("n3v:coffee_martini", "n3v", "Coffee Martini", True)
    assert load_kwargs(n3v, get_preset("paper")) == {"resolution_scale": 0.5, "frames": [0, 300]}
    assert load_kwargs(n3v, get_preset("quick")) == {
        "resolution_scale": 0.125,
        "frames": [0, 16],
        "num_points": 5000,
    }
    stand_in = SceneRef("synthetic:n3v_like", "n3v", None, False)
    assert load_kwargs(stand_in, get_preset("quick")) == {"preset": "quick", "seed": 0}
    assert load_kwargs(stand_in, get_preset("quick32")) == {
        "preset": "quick",
        "seed": 0,
        "overrides": {"num_frames": 32},
    }


def test_load_restores_the_tuples_json_made_lists(monkeypatch):
    calls = []
    monkeypatch.setattr("moegs.data.load_scene", lambda name, **kwargs: calls.append((name, kwargs)))
    load("n3v:coffee_martini", {"frames": [0, 16], "resolution_scale": 0.125})
    load("synthetic:n3v_like", {"preset": "quick"})
    assert calls == [
        ("n3v:coffee_martini", {"frames": (0, 16), "resolution_scale": 0.125}),
        ("synthetic:n3v_like", {"preset": "quick", "progress": False}),
    ]


def test_folder_hash_follows_contents_and_names_past_its_cache(tmp_path):
    folder, cache = tmp_path / "scene", tmp_path / "hashes.json"
    folder.mkdir()
    (folder / "a.png").write_bytes(b"aaaa")
    first = folder_hash(folder, cache)
    assert folder_hash(folder, cache) == first == folder_hash(folder)  # cached, and as computed afresh
    assert json.loads(cache.read_text())[str(folder.resolve())]["sha256"] == first
    (folder / "a.png").write_bytes(b"bbbb")  # same name and size, new content and time: recomputed
    os.utime(folder / "a.png", ns=(1_000_000_000, 1_000_000_000))
    second = folder_hash(folder, cache)
    assert second == folder_hash(folder) != first
    (folder / "a.png").rename(folder / "b.png")
    assert folder_hash(folder, cache) != second  # the same bytes under another name


def test_a_scene_printed_under_two_names_is_one_scene_with_its_first_name():
    n3v = get_dataset("n3v")  # Table XII prints "Cut Roast Beef" for the "Cut Roasted Beef" of Table II
    assert n3v.scenes["Cut Roast Beef"] == n3v.scenes["Cut Roasted Beef"] == "cut_roasted_beef"
    assert n3v.scene_names().count("cut_roasted_beef") == 1 and len(n3v.scene_names()) == 6
    assert n3v.column_of("cut_roasted_beef") == "Cut Roasted Beef"


def test_a_budget_scales_the_training_steps_rounded_and_at_least_one():
    preset = get_preset("quick")
    assert preset.steps(600, None, 0.1) == 60 and preset.steps(600, 150, 0.5) == 75
    assert preset.steps(7, None, 0.5) == 4  # 3.5 rounds to even, not down
    assert preset.steps(3, None, 0.1) == 1
