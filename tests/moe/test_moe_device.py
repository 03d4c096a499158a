"""MoE-GS on a device, checked on the CPU: the router follows its experts' device; router training,
evaluation, pruning, lifting and distillation create no tensor without a device
(``poisoned_default_device``); a router step reads nothing back from the device (the losses are read every
``LOG_EVERY`` steps) and a NaN loss is still named by its step and view; the bounded teacher cache changes
no number.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import torch
from helpers.devices import HostReads, poisoned_default_device
from helpers.scenes import tiny_scene, untrained_experts

import moegs.moe.train as router_training
from moegs.data.scene import ImageCache
from moegs.experts import get_expert_class
from moegs.experts.base import splat_inputs_bytes
from moegs.moe import DistillConfig, MoEGS, RouterConfig, compute_responsibilities, distill, lift, prune
from moegs.moe.distill import TeacherCache, kd_view_loss
from moegs.moe.model import read_router
from moegs.moe.train import LOG_EVERY, evaluate_moe, router_param_groups, router_step, train_router
from moegs.train.loop import TrainingRun
from moegs.train.optim import Optimizers


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=2, cameras=3, size=32, num_points=60)


@pytest.fixture(scope="module")
def experts(scene):
    """An untrained static 3DGS and an untrained 3DGS-MCMC (per-frame rows: ``frame_rows``)."""
    return untrained_experts(scene)


def config(variant: str = "vapr", **kw) -> RouterConfig:
    return replace(RouterConfig.from_preset("quick"), variant=variant, **kw)


def test_the_router_lives_on_its_experts_device(experts):
    """``MoEGS`` builds the router beside the experts (meta experts stand in for a GPU's)."""
    on_meta = [copy.deepcopy(e).to("meta") for e in experts]
    for variant in ("vapr", "pixel", "volume"):
        model = MoEGS(on_meta, config(variant))
        assert model.device == torch.device("meta")
        assert {p.device.type for p in model.router.parameters()} == {"meta"}


@pytest.mark.parametrize("variant", ["vapr", "pixel", "volume"])
def test_router_steps_and_evaluation_name_their_devices(scene, experts, variant):
    model = MoEGS(experts, config(variant)).train()
    optimizers = Optimizers(router_param_groups(model))
    frozen = ImageCache(max_bytes=1 << 30, nbytes=splat_inputs_bytes)
    router_step(model, scene.train[0], scene.background, frozen, optimizers, 1)  # the optimisers' state
    with poisoned_default_device():
        losses = [
            router_step(model, view, scene.background, frozen, optimizers, step)
            for step, view in enumerate(scene.train[1:4], start=2)
        ]
    assert all(loss.device.type == "cpu" for loss in losses)

    model.eval()
    with poisoned_default_device():
        scores = evaluate_moe(model, scene.test[:1], scene.background)
    assert len(scores["winner_share"]) == 2


@pytest.mark.parametrize("variant", ["vapr", "volume"])
def test_pruning_names_its_devices(scene, experts, variant):
    model = MoEGS(copy.deepcopy(experts), config(variant))
    with poisoned_default_device():
        result = prune(model, scene, ratio=0.5, max_views=4)
    assert result["after"] == [n - n // 2 for n in result["before"]]


def test_lifting_names_its_devices(scene, experts):
    model = MoEGS(experts, config())
    with poisoned_default_device():
        resp = compute_responsibilities(model, scene.train[:2], scene.background)
        frame = lift(model, 0.0)
    assert [r.device.type for r in resp] == ["cpu", "cpu"] and frame.opacities.device.type == "cpu"


def test_distillation_steps_name_their_devices(scene, experts):
    """Steps of the training loop with the KD loss, the teacher rendering views it has not seen yet."""
    teacher = MoEGS(experts, config())
    cls = get_expert_class("static")
    cfg = cls.config_class.from_preset("quick")
    student = cls.from_scene(scene, cfg).train()
    teacher_of = TeacherCache(teacher, 0, scene.background)
    train = replace(cfg.train, iterations=10)
    run = TrainingRun(student, scene, train, kd_view_loss(teacher_of, DistillConfig()))
    run.iteration(1)  # the optimisers' state
    with poisoned_default_device():
        for step in (2, 3, 4):
            run.iteration(step)
    assert len(teacher_of.outputs) == 4


def _reads(experts, scene, variant: str, steps: int) -> HostReads:
    with HostReads() as reads:
        result = train_router(experts, scene, config(variant, iterations=100), stop_after=steps)
    assert result["test"] is None  # stopped early: no evaluation
    return reads


@pytest.mark.parametrize(("variant", "budget"), [("vapr", 12), ("pixel", 8), ("volume", 15)])
def test_a_router_step_reads_nothing_back_but_the_render_checks(scene, experts, variant, budget):
    """Reads per step over steps 11-30: MoE-GS's own, one per ``LOG_EVERY`` steps (the loss history);
    all of them, at most ``budget`` (measured: vapr 11.25, pixel 7.25, volume 14.25 with the pure-torch
    rasterizer: the render's input checks, the rasterizer's own reads and MCMC's ``frame_rows``)."""
    first, last = _reads(experts, scene, variant, 10), _reads(experts, scene, variant, 30)
    per_step = {k: (last.counts[k] - first.counts[k]) / 20 for k in last.counts}
    own = sum(n for where, n in per_step.items() if where.startswith("moegs/moe/"))
    assert own <= 1 / LOG_EVERY, per_step
    assert sum(per_step.values()) <= budget, per_step


@pytest.mark.parametrize("variant", ["vapr", "pixel"])
def test_a_nan_loss_is_named_by_step_and_view_and_never_checkpointed(scene, experts, variant, tmp_path):
    """The loss of step 3 is NaN; the router's next render meets NaN weights (vapr: the rasterizer
    refuses them) or the checkpoint of step 4 reads the history (pixel): either way the error names
    step 3 and its view, and the checkpoint keeps step 2."""
    photometric, calls = router_training.photometric, []

    def nan_at_step_3(pred, target, lambda_dssim):
        calls.append(None)
        loss = photometric(pred, target, lambda_dssim)
        return loss * float("nan") if len(calls) == 3 else loss

    views = []
    render = MoEGS.render

    def spy(self, camera, *args, **kwargs):
        views.append(camera)
        return render(self, camera, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(router_training, "photometric", nan_at_step_3)
        patch.setattr(MoEGS, "render", spy)
        with pytest.raises(FloatingPointError, match=r"router step 3: loss of view (\S+) is nan") as err:
            train_router(experts, scene, config(variant, iterations=8, checkpoint_every=2), tmp_path)
    key = err.value.args[0].split("loss of view ")[1].split(" ")[0]
    assert next(v.key for v in scene.train if v.camera is views[2]) == key
    state = read_router(tmp_path / "router.safetensors")
    assert state["step"] == 2 and len(state["history"]) == 2


def test_a_teacher_cache_that_holds_no_view_changes_nothing(scene, experts, monkeypatch):
    """With no memory, every teacher output is rendered again when needed: the same student, bit for
    bit, as with every view kept."""
    teacher = MoEGS(experts, RouterConfig.from_preset("quick"))
    cls = get_expert_class("static")
    cfg = cls.config_class.from_preset("quick")
    renders: dict[int, list[str]] = {}
    original = TeacherCache.render

    def counted(self, view):
        renders.setdefault(self.outputs.max_bytes, []).append(view.key)
        return original(self, view)

    monkeypatch.setattr(TeacherCache, "render", counted)
    students = []
    for budget in (1 << 30, 0):
        student = cls.from_scene(scene, cfg)
        distill(student, teacher, scene, DistillConfig(iterations=8), teacher_cache_bytes=budget)
        students.append(student.state_dict())
    kept, bounded = students
    assert kept.keys() == bounded.keys() and all(torch.equal(kept[k], bounded[k]) for k in kept)
    assert len(renders[1 << 30]) == len(set(renders[1 << 30])) < 8  # each view once
    assert len(renders[0]) == 8  # every step
