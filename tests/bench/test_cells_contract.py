"""The cell kinds that wait for library pieces (MoE-GS routers, pruning, distillation, MDC) run against a
stand-in implementation of the API they document, in process, on tiny trained experts.

This pins the contract ``bench/cells/{moe,gates,distill,mdc}.py`` expect from ``moegs.moe`` and
``moegs.metrics.mdc``: when the real modules land with these names, the cells run unchanged. The fakes
blend experts with uniform gates; no number from them reaches tables or reports (tmp workspace).
"""

from __future__ import annotations

import json
import sys
import types
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import pytest

from bench.cells import expert_missing, missing_pieces, module_missing
from bench.context import Context
from bench.store import Workspace
from bench.tasks import Task

pytestmark = pytest.mark.slow
EXPERTS = ["static", "mcmc"]


def _fake_moe() -> types.ModuleType:
    import torch
    from torch import nn

    from moegs.train.evaluate import render_view

    @dataclass
    class RouterConfig:
        variant: str = "vapr"
        iterations: int = 10
        seed: int = 0

        @classmethod
        def from_preset(cls, name):
            return cls()

    @dataclass
    class DistillConfig:
        iterations: int = 10
        weighted: bool = True
        seed: int = 0

        @classmethod
        def from_preset(cls, name):
            return cls()

    class FakeMoE(nn.Module):
        def __init__(self, experts):
            super().__init__()
            self.experts = nn.ModuleList(experts)

        def render(self, camera, background, single_pass=True):
            images = torch.stack([render_view(e, camera, background)[0] for e in self.experts])
            gates = torch.full(images.shape[:3], 1.0 / len(self.experts))
            return types.SimpleNamespace(
                image=(gates[..., None] * images).sum(0), gates=gates, expert_images=images
            )

    def train_router(experts, scene, config, out_dir, progress=False):
        (Path(out_dir) / "router.json").write_text(json.dumps(asdict(config)))
        return {"train_seconds": 0.25}

    def load_moe(out_dir, experts, scene):
        assert (Path(out_dir) / "router.json").is_file()
        return FakeMoE(experts)

    def distill(student, teacher, scene, config, out_dir, progress=False):
        from moegs.train.loop import train

        return train(
            student,
            scene,
            replace(student.config.train, iterations=config.iterations),
            out_dir,
            progress=False,
        )

    mod = types.ModuleType("moegs.moe")
    mod.__dict__.update(
        RouterConfig=RouterConfig,
        DistillConfig=DistillConfig,
        train_router=train_router,
        load_moe=load_moe,
        prune=lambda model, scene, ratio=None: {"ratio": ratio},
        lift=lambda model, t: model.experts[0].frame(t),
        compute_responsibilities=lambda model, views, background: [
            torch.ones(e.num_gaussians) for e in model.experts
        ],
        distill=distill,
    )
    return mod


def _fake_mdc() -> types.ModuleType:
    mod = types.ModuleType("moegs.metrics.mdc")
    mod.mdc = lambda depths, cameras: float(sum(float((d - depths[0]).abs().mean()) for d in depths))
    return mod


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    from moegs.paths import data_root

    if data_root() is None or not (data_root() / "dnerf" / "mutant").is_dir():
        pytest.skip("real scene dnerf/mutant not found")
    mp = pytest.MonkeyPatch()
    mp.setitem(sys.modules, "moegs.moe", _fake_moe())
    mp.setitem(sys.modules, "moegs.metrics.mdc", _fake_mdc())
    for f in (module_missing, expert_missing):
        f.cache_clear()
    yield Context(Workspace(tmp_path_factory.mktemp("contract")), "tiny")
    mp.undo()
    for f in (module_missing, expert_missing):
        f.cache_clear()


def _task(kind, params) -> Task:
    return Task(
        "eval", kind, params, "dnerf:mutant", {"resolution_scale": 1 / 16, "num_points": 2000}, "tiny", 0
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
    assert out["details"]["pruning"] == {"ratio": 0.55} and out["details"]["single_pass"] is False


def test_gates_cell(ctx):
    out = _run(ctx, "gates", {"experts": EXPERTS, "router": "vapr"})
    assert out["metrics"]["gate_experts"] >= 1 and out["files"] == ["gates.npz"]
    assert (ctx.workspace.files_dir(ctx.task) / "gates.npz").is_file()


def test_distill_cell(ctx):
    out = _run(ctx, "distill", {"student": "static", "teacher": EXPERTS, "router": "vapr", "weighted": True})
    assert out["metrics"]["psnr"] > 5 and out["details"]["num_gaussians"] > 0


@pytest.mark.parametrize("params", [{"expert": "static"}, {"experts": EXPERTS, "router": "vapr"}])
def test_mdc_cell(ctx, params):
    out = _run(ctx, "mdc", params)
    assert out["metrics"]["mdc"] >= 0 and out["details"]["cameras"] >= 2
