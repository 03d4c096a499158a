"""``load_scene`` registry: name parsing, data-root lookup, aliases, explicit paths, clear errors."""

from __future__ import annotations

import sys
import types

import helpers.data_layouts as fx
import pytest

from moegs.data import canonical_scene, list_datasets, list_scenes, load_scene, resolve_scene_path


def test_list_datasets():
    assert list_datasets() == ["dnerf", "panoptic", "n3v", "technicolor", "hypernerf", "synthetic"]


def test_unknown_dataset_lists_valid_ones():
    with pytest.raises(ValueError, match=r"unknown dataset 'blender'.*dnerf.*hypernerf"):
        load_scene("blender:lego")
    with pytest.raises(ValueError, match="<dataset>:<scene>"):
        load_scene("mutant")


def test_missing_scene_says_where_and_what(tmp_path, monkeypatch):
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"dnerf/lego .*transforms_\{train,val,test\}\.json"):
        load_scene("dnerf:lego")
    (tmp_path / "n3v" / "sear_steak").mkdir(parents=True)
    with pytest.raises(
        FileNotFoundError, match=r"sear_steak exists but does not look like a n3v scene.*poses_bounds"
    ):
        load_scene("n3v:sear_steak")


def test_resolution_aliases_and_kwargs(tmp_path, monkeypatch):
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    fx.write_dnerf(tmp_path / "dnerf" / "hook", counts={"train": 2, "test": 1})
    fx.write_hypernerf(tmp_path / "hypernerf" / "vrig-chicken", steps=2)
    fx.write_hypernerf(tmp_path / "hypernerf" / "broom2", steps=2)
    fx.write_technicolor_colmap(tmp_path / "technicolor" / "Birthday", frames=(151, 153), naming="absolute")
    assert list_scenes("hypernerf") == ["broom2", "vrig-chicken"]
    scene = load_scene("dnerf:hook", background="black", num_points=0)
    assert scene.name == "dnerf:hook" and scene.dataset == "dnerf" and scene.background.sum() == 0
    assert resolve_scene_path("hypernerf:chicken").name == "vrig-chicken"
    assert resolve_scene_path("hypernerf:broom").name == "broom2"
    assert resolve_scene_path("hypernerf:vrig_broom").name == "broom2"  # another spelling of the same scene
    assert load_scene("hypernerf:vrig-chicken", num_points=0).name == "hypernerf:vrig-chicken"
    tech = load_scene("technicolor:birthday", frames=(151, 153))
    assert tech.name == "technicolor:birthday" and tech.num_frames == 2


def test_explicit_path(tmp_path):
    fx.write_panoptic(tmp_path / "somewhere", frames=2)
    scene = load_scene("panoptic:mine", path=tmp_path / "somewhere", num_points=50)
    assert scene.name == "panoptic:mine" and scene.num_frames == 2
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_scene("panoptic:mine", path=tmp_path / "nowhere")


def test_synthetic_delegates(monkeypatch):
    calls = {}
    fake = types.ModuleType("moegs.data.synthetic")

    def load_synthetic(name, **kwargs):
        calls["args"] = (name, kwargs)
        return "scene"

    fake.load_synthetic = load_synthetic
    monkeypatch.setitem(sys.modules, "moegs.data.synthetic", fake)
    assert load_scene("synthetic:orbit", frames=(0, 4)) == "scene"
    assert calls["args"] == ("orbit", {"frames": (0, 4)})
    load_scene("synthetic:orbit", path="/tmp/gen")
    assert calls["args"] == ("orbit", {"root": "/tmp/gen"})


@pytest.mark.realdata
def test_real_scenes_by_name(mutant_root, basketball_root):
    assert load_scene("dnerf:mutant", num_points=0).summary().startswith("dnerf:mutant: 150 train / 20 test")
    pan = load_scene("panoptic:basketball", frames=(0, 10), num_points=500)
    assert pan.num_frames == 10 and len(pan.test) == 40


@pytest.mark.parametrize(
    ("name", "canonical"),
    [
        ("n3v:flame_salmon_1", "n3v:flame_salmon"),
        ("n3v:coffee", "n3v:coffee_martini"),
        ("n3v:Coffee_Martini", "n3v:coffee_martini"),
        ("hypernerf:vrig-broom", "hypernerf:broom"),
        ("hypernerf:banana", "hypernerf:peel-banana"),
        ("n3v:sear_steak", "n3v:sear_steak"),
        ("technicolor:Birthday", "technicolor:birthday"),
        ("synthetic:n3v_like", "synthetic:n3v_like"),
    ],
)
def test_canonical_scene_names(name, canonical):
    assert canonical_scene(name) == canonical
