"""The MoE-GS cell kinds (router, gate maps, distillation, MDC) run end to end on the real ``mutant`` scene
at the ``tiny`` preset, in process, over two cheap trained experts (3DGS, 3DGS-MCMC): the contract
between ``bench/cells/{moe,gates,distill,mdc}.py`` and ``moegs.moe`` / ``moegs.metrics.mdc``, and the
routing signal every MoE-GS cell reports. Nothing from here reaches tables or reports (tmp workspace).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.cells import missing_pieces
from bench.context import Context
from bench.store import Workspace
from bench.tasks import Task

pytestmark = pytest.mark.slow
EXPERTS = ["static", "mcmc"]


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    from moegs.paths import data_root

    if data_root() is None or not (data_root() / "dnerf" / "mutant").is_dir():
        pytest.skip("real scene dnerf/mutant not found")
    return Context(Workspace(tmp_path_factory.mktemp("contract")), "tiny")


def _task(kind, params) -> Task:
    return Task(
        "eval",
        kind,
        {**params, "dataset": "dnerf"},
        "dnerf:mutant",
        {"resolution_scale": 1 / 16, "num_points": 2000},
        "tiny",
        0,
    )


def _run(ctx, kind, params):
    from bench.cells import kind_module

    assert missing_pieces(kind, params) == [], missing_pieces(kind, params)
    task = _task(kind, params)
    ctx.task = task
    return kind_module(kind).run(task, ctx)


def test_moe_cell(ctx):
    out = _run(ctx, "moe", {"experts": EXPERTS, "router": "vapr", "prune": 0.55, "single_pass": False})
    m = out["metrics"]
    assert m["psnr"] > 5 and m["fps"] > 0 and m["memory_mb"] > 0 and m["train_time_h"] > 0
    # the routed blend is no worse than its worse expert (measured on an AMD EPYC, seeds 0 and 1: blend
    # 16.29-16.35 dB, static 14.08-14.09, mcmc 14.57-14.66): a router that sends pixels nowhere fails
    experts = {e: _run(ctx, "expert", {"expert": e})["metrics"]["psnr"] for e in EXPERTS}
    assert m["psnr"] >= min(experts.values()), (m["psnr"], experts)
    assert m["psnr_dynamic"] > 5 and m["psnr_static"] > 5  # D-NeRF regions: object alpha vs background
    assert out["details"]["pruning"]["ratio"] == 0.55 and out["details"]["single_pass"] is False
    assert out["details"]["pruning"]["when"] == "after training"
    routing = out["details"]["routing"]
    assert 0.0 <= routing["coherence"] <= 1.0 and routing["views"] == ctx.preset.test_views
    for region in ("dynamic_share", "static_share"):
        assert len(routing[region]) == 2 and sum(routing[region]) == pytest.approx(1.0)


def test_moe_cell_pruning_while_the_router_trains(ctx):
    """``prune="train"``: its own router build, pruned on the authors' schedule moved to the run; the
    cell reports the Gaussians before (as trained) and after."""
    from bench.cells.moe import artifacts, router_config

    task = _task("moe", {"experts": EXPERTS, "router": "vapr", "prune": "train"})
    build = artifacts(task)[0]
    assert (
        build.params["prune"] == "train" and build.key != artifacts(_task("moe", {"experts": EXPERTS}))[0].key
    )
    config = router_config(ctx, build)
    assert config.prune_every == config.prune_from == max(round(500 * config.iterations / 5000), 1)
    out = _run(ctx, "moe", {"experts": EXPERTS, "router": "vapr", "prune": "train"})
    pruning = out["details"]["pruning"]
    assert pruning["when"] == "training" and len(pruning["before"]) == len(pruning["after"]) == 2
    assert all(a <= b for a, b in zip(pruning["after"], pruning["before"], strict=True))
    assert pruning["removed_fraction"] == pytest.approx(1 - sum(pruning["after"]) / sum(pruning["before"]))


def test_gates_cell(ctx):
    out = _run(ctx, "gates", {"experts": EXPERTS, "router": "vapr"})
    assert out["metrics"]["gate_experts"] >= 1 and out["files"] == ["gates.npz"]
    with np.load(ctx.workspace.files_dir(ctx.task) / "gates.npz") as saved:  # what the gate figure draws
        gates, images, gt = saved["gates"], saved["expert_images"], saved["gt"]
        assert list(saved["experts"]) == EXPERTS and str(saved["view"]) == out["details"]["view"]
        assert gates.shape == (2, *gt.shape[:2]) and images.shape == (2, *gt.shape)
        np.testing.assert_allclose(gates.sum(0), 1.0, atol=1e-5)  # a softmax over the experts per pixel
        blend = (gates[..., None] * images).sum(0)
        np.testing.assert_allclose(saved["image"], blend.clip(0, 1), atol=1e-5)
        lead = np.bincount(gates.argmax(0).ravel(), minlength=2) / gates[0].size
        assert lead.tolist() == pytest.approx(out["details"]["lead_share"])


def test_distill_cell(ctx):
    """The KD loss trains the student: its 20 tiny steps lift it clear of the untrained student (measured on
    an AMD EPYC: untrained 6.95 dB, distilled 9.16, the same student trained 20 steps on the ground truth
    9.12), which a floor of 5 dB could not tell apart."""
    from bench.cells import moe as moe_kind
    from bench.cells._lib import evaluate_model, expert_task, recipe_of
    from moegs.train.entry import build_expert

    params = {"student": "static", "teacher": EXPERTS, "router": "vapr", "weighted": True}
    out = _run(ctx, "distill", params)
    assert out["details"]["num_gaussians"] > 0
    scene = moe_kind.moe_scene(ctx, moe_kind.router_task(ctx.task, EXPERTS, "vapr"))
    untrained = build_expert(recipe_of(ctx, expert_task(ctx.task, "static")), scene).eval()
    before = evaluate_model(ctx, untrained, scene, [])["metrics"]["psnr"]
    assert out["metrics"]["psnr"] > before + 1.0, (before, out["metrics"]["psnr"])


@pytest.mark.parametrize("params", [{"expert": "static"}, {"experts": EXPERTS, "router": "vapr"}])
def test_mdc_cell(ctx, params):
    out = _run(ctx, "mdc", params)
    assert (
        math.isfinite(out["metrics"]["mdc"]) and out["metrics"]["mdc"] >= 0 and out["details"]["cameras"] >= 2
    )


def test_bestmap_cell_picks_winners_over_time_on_the_dynamic_region(ctx):
    out = _run(ctx, "bestmap", {"experts": EXPERTS})
    m, d = out["metrics"], out["details"]
    assert d["temporal_region"] == "dynamic"  # D-NeRF: the object alpha is the dynamic region
    assert len(d["best_per_time"]) == len(d["best_per_time_full"]) > 1
    assert set(d["best_per_time"]) <= set(EXPERTS) and 0 <= m["switches"] < len(d["best_per_time"])
    assert 0.0 <= m["coherence"] <= 1.0 and 1 <= m["winners"] <= 2
    for region in ("dynamic", "static"):
        assert sum(d["region_shares"][region]) == pytest.approx(1.0)
