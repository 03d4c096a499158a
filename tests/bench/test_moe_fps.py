"""``bench.moe_fps``: end-to-end render times per expert and MoE-GS single pass against K passes."""

from __future__ import annotations

import json

import pytest

from bench import moe_fps

TINY = "--device cpu --scene synthetic:dnerf_like --views 1 --warmup 1 --repeats 1".split()
TWO = "--experts static,deformable --moe static,deformable".split()


def test_times_each_expert_and_the_moe_both_ways(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- results:moe-fps -->\nold\n<!-- /results:moe-fps -->\nend\n")
    out = tmp_path / "fps.json"
    assert moe_fps.main([*TINY, *TWO, "--json", str(out), "--readme", str(readme)]) == 0
    result = json.loads(out.read_text())
    assert [row["expert"] for row in result["experts"]] == ["static", "deformable"]
    for row in result["experts"]:
        assert row["ok"] and row["gaussians"] > 0 and row["ms"] > 0 and row["device"].startswith("cpu")
    moe = result["moe"]
    assert moe["ok"] and moe["experts"] == ["static", "deformable"]
    assert moe["speedup"] == pytest.approx(moe["separate_ms"] / moe["single_pass_ms"])
    text = readme.read_text()
    assert "old" not in text and "| static + deformable |" in text and text.endswith("end\n")
    # the table is rebuilt from the saved run alone
    assert moe_fps.main(["--json", str(out), "--from-json"]) == 0


def test_the_moe_is_timed_in_separate_passes_and_in_one(tmp_path, monkeypatch):
    from moegs.moe.model import MoEGS

    modes, render = [], MoEGS.render

    def spy(self, camera, background, *args, single_pass=None, **kwargs):
        modes.append(single_pass)
        return render(self, camera, background, *args, single_pass=single_pass, **kwargs)

    monkeypatch.setattr(MoEGS, "render", spy)
    assert moe_fps.main([*TINY, *TWO, "--json", str(tmp_path / "fps.json")]) == 0
    assert modes and set(modes) == {False, True} and modes.index(True) > modes.index(False)


def test_a_failing_expert_is_reported_and_the_moe_says_why(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("no kernel for this device")

    from moegs.experts import get_expert_class

    monkeypatch.setattr(get_expert_class("deformable"), "render", broken)
    out = tmp_path / "fps.json"
    assert moe_fps.main([*TINY, *TWO, "--json", str(out)]) == 1
    result = json.loads(out.read_text())
    failure = {"expert": "deformable", "ok": False, "error": "RuntimeError: no kernel for this device"}
    assert result["experts"][1] == failure
    assert not result["moe"]["ok"] and "deformable" in result["moe"]["error"]
    assert "failed: RuntimeError: no kernel for this device" in moe_fps.markdown(result)


def test_unknown_names_and_missing_json_are_clear_errors(tmp_path, capsys):
    with pytest.raises(ValueError, match="unknown expert 'nope'"):
        moe_fps.main([*TINY, "--experts", "nope"])
    with pytest.raises(SystemExit):
        moe_fps.main(["--from-json", "--json", str(tmp_path / "absent.json")])
    assert "absent.json" in capsys.readouterr().err


def test_resampled_clouds_start_every_expert_from_all_points_at_a_scaled_resolution(tmp_path):
    """``--gaussians N`` lifts each expert's cap on initial points (DeformableGS's quick preset keeps 5k)
    and ``--scale`` renders the test cameras larger; the table names both."""
    out = tmp_path / "fps.json"
    args = [*TINY, *TWO, "--gaussians", "6000", "--scale", "1.5", "--json", str(out)]
    assert moe_fps.main(args) == 0
    result = json.loads(out.read_text())
    assert [row["gaussians"] for row in result["experts"]] == [6000, 6000]
    assert result["resolution"] == "150x150"  # dnerf_like is 100x100
    table = moe_fps.markdown(result)
    assert "--gaussians 6000 --scale 1.5" in table and "resampled to 6000 points" in table


def test_with_points_resamples_without_coincident_points():
    import torch

    from moegs.data import load_scene

    scene = load_scene("synthetic:dnerf_like")
    more = moe_fps.with_points(scene, 3 * len(scene.points))
    assert len(more.points) == 3 * len(scene.points) and more.test is scene.test
    assert len(torch.unique(more.points.xyz, dim=0)) == len(more.points)
    lo, hi = scene.points.xyz.min(0).values, scene.points.xyz.max(0).values
    margin = 0.1 * scene.extent  # steps of 1% of the extent: none strays far
    assert ((more.points.xyz > lo - margin) & (more.points.xyz < hi + margin)).all()
    with pytest.raises(ValueError, match="must be >= 1"):
        moe_fps.with_points(scene, 0)
