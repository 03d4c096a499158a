"""``bench.sidebyside.compare``: a paper | standard | quick comparison exists for a table on the scenes axis
whose scenes are real under every compared preset; it shows the dynamic-region PSNR beside PSNR only."""

from __future__ import annotations

from dataclasses import replace

import pytest
from helpers.cells import staged_scenes, write_ok_result

import bench.plan
from bench.plan import plan_spec
from bench.presets import get_preset
from bench.registry import get_spec
from bench.scenes import SceneRef
from bench.sidebyside import compare
from bench.store import Workspace


@pytest.fixture
def tab17(tmp_path, monkeypatch):
    """Table XVII with finished standard and quick cells on a staged mutant, and its workspace."""
    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes("dnerf:mutant"))
    ws = Workspace(tmp_path)
    spec = get_spec("tab17")
    for preset in ("standard", "quick"):
        for slot in plan_spec(spec, get_preset(preset)).slots:
            if slot.task is not None:
                write_ok_result(ws, slot.task, psnr=30.0, ssim=0.9, psnr_dynamic=25.0)
    return spec, ws


def test_psnr_tables_show_the_dynamic_region_and_other_metrics_do_not(tab17):
    spec, ws = tab17
    psnr = compare(spec, ws)
    assert psnr.scenes == ["Mutant"] and psnr.ours[("Grid4D", "Mutant", "standard")].dynamic == 25.0
    ssim = compare(replace(spec, id="tab17_ssim", metrics=("SSIM",)), ws)
    cell = ssim.ours[("Grid4D", "Mutant", "standard")]
    assert cell.value == pytest.approx(0.9) and cell.dynamic is None


def test_no_comparison_off_the_scenes_axis_or_where_a_preset_has_a_stand_in(tab17, monkeypatch):
    spec, ws = tab17
    assert compare(replace(spec, id="tab17_metrics", axis="metrics", metrics=("PSNR",)), ws) is None
    staged = staged_scenes("dnerf:mutant")

    def quick_has_a_stand_in(dataset, preset, only=()):
        if preset.name == "quick":
            return [SceneRef("synthetic:dnerf_like", dataset, None, False)]
        return staged(dataset, preset, only)

    monkeypatch.setattr(bench.plan, "resolve_scenes", quick_has_a_stand_in)
    assert compare(spec, ws) is None
