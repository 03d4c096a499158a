"""MoE-GS end to end on the real D-NeRF ``mutant`` scene (quick preset): DeformableGS + Grid4D experts,
the volume-aware pixel router trained by ``moegs route``, gate figures. The blend must reach at least the
better expert's test PSNR and the gates must not be uniform."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from helpers.training import trained_expert

from moegs.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.realdata]
EXPERTS = ("deformable", "grid4d")


@pytest.fixture(scope="module")
def routed(tmp_path_factory, mutant_root):
    out = tmp_path_factory.mktemp("route")
    for name in EXPERTS:  # the shared, cached expert runs become the route command's stage 1
        shutil.copytree(trained_expert(name, "dnerf:mutant").path, out / name)
    assert (
        main(
            [
                "route",
                "--experts",
                ",".join(EXPERTS),
                "--scene",
                "dnerf:mutant",
                "--out",
                str(out),
                "--gate-views",
                "2",
                "--quiet",
            ]
        )
        == 0
    )
    return out / "router_vapr"


def test_moe_reaches_the_better_expert(routed):
    result = json.loads((routed / "metrics.json").read_text())
    test = result["test"]
    assert result["completed"] and result["experts"] == list(EXPERTS)
    experts = {e["name"]: e["psnr"] for e in test["experts"]}
    for name in EXPERTS:  # the experts inside MoE-GS render exactly as when they were evaluated alone
        alone = trained_expert(name, "dnerf:mutant").metrics["test"]
        if alone["num_views"] == test["num_views"]:
            assert experts[name] == pytest.approx(alone["psnr"], abs=1e-3)
    # the blend lands at the better expert: bench.floors measured MoE minus the better expert from -0.138
    # to +0.051 dB over 3 seeds x {1, 2} threads (MoE 28.39-28.89 dB, 2026-12-03); the 0.3 dB band holds
    assert test["psnr"] >= max(experts.values()) - 0.3, (test["psnr"], experts)
    assert test["psnr"] > min(experts.values()) + 1.0, (test["psnr"], experts)


def test_gate_maps_are_not_uniform(routed):
    from moegs.moe import load_moe

    runs = [trained_expert(name, "dnerf:mutant") for name in EXPERTS]
    model = load_moe(routed, [r.expert for r in runs])
    scene = runs[0].scene
    with torch.no_grad():
        out = model.render(scene.test[0].camera, scene.background)
    spread = (out.gates[0] - 0.5).abs()
    # the router commits to one expert in places: |gate - 0.5| averages 0.0405-0.0459 over 3 seeds x {1, 2}
    # threads (bench.floors, 2026-12-03); 0.05 sat above most measurements, the issue-15 coin flip
    assert float(spread.mean()) > 0.035
    shares = json.loads((routed / "metrics.json").read_text())["test"]["winner_share"]
    assert min(shares) > 0.001  # and each expert wins somewhere (smaller share measured: 0.35-1.49%)
    figures = sorted((routed / "gates").glob("view_*.png"))
    assert len(figures) == 2
    import imageio.v3 as iio

    winner = iio.imread(routed / "gates" / "winner_000.png")
    assert winner.ndim == 3 and len(np.unique(winner.reshape(-1, 3), axis=0)) > 10
