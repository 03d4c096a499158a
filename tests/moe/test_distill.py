"""Distillation: the KD loss by hand, the teacher supervises through the one training loop, bad students
are named."""

from __future__ import annotations

import importlib
import math
from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.experts import get_expert_class
from moegs.metrics import psnr
from moegs.moe import DistillConfig, MoEGS, RouterConfig, distill
from moegs.moe.distill import kd_loss
from moegs.train.checkpoint import load_expert
from moegs.train.evaluate import render_view
from moegs.train.losses import l1


def test_kd_loss_by_hand():
    rgb, gt, moe = torch.full((4, 4, 3), 0.2), torch.full((4, 4, 3), 0.6), torch.full((4, 4, 3), 0.5)
    gate = torch.zeros(4, 4)
    gate[:, :2] = 1.0  # expert trusted on the left half
    # L1 only: left half compares to GT (0.4 error), right half to the MoE image (0.3 error); halves masked
    got = kd_loss(rgb, gt, moe, gate, kd_lambda=0.25, lambda_dssim=0.0)
    assert float(got) == pytest.approx(0.25 * 0.4 / 2 + 0.75 * 0.3 / 2)
    plain = kd_loss(rgb, gt, moe, None, kd_lambda=0.25, lambda_dssim=0.0)
    assert float(plain) == pytest.approx(0.25 * float(l1(rgb, gt)) + 0.75 * float(l1(rgb, moe)))


@pytest.mark.parametrize("weighted", [True, False])
def test_the_kd_loss_weights_by_the_students_own_gate(monkeypatch, weighted):
    """The student (the teacher's second expert here) is weighted by its own gate ``G'_k``, not another
    expert's; ``weighted=False`` passes no gate ("w/o Weight")."""
    scene = tiny_scene(num_frames=2, cameras=3, size=32, num_points=80)
    make = {n: get_expert_class(n) for n in ("mcmc", "static")}
    experts = [cls.from_scene(scene, cls.config_class.from_preset("quick")).eval() for cls in make.values()]
    teacher = MoEGS(experts, RouterConfig.from_preset("quick"))
    with torch.no_grad():
        for p in teacher.router.parameters():
            p.normal_()
        gates = [teacher.render(v.camera, scene.background).gates for v in scene.train]
    seen = []

    def spy(rgb, target, moe_image, gate, kd_lambda, lambda_dssim):
        seen.append(gate)
        return kd_loss(rgb, target, moe_image, gate, kd_lambda, lambda_dssim)

    # the package exports the function ``distill`` under the module's name: reach the module itself
    monkeypatch.setattr(importlib.import_module("moegs.moe.distill"), "kd_loss", spy)
    student = make["static"].from_scene(scene, make["static"].config_class.from_preset("quick"))
    distill(student, teacher, scene, DistillConfig(iterations=3, weighted=weighted))
    assert len(seen) >= 3
    for gate in seen:
        if not weighted:
            assert gate is None
            continue
        assert any(torch.equal(gate, g[1]) for g in gates)
        assert not any(torch.allclose(gate, g[0]) for g in gates)


def test_distilled_student_trains_and_reloads(tmp_path):
    scene = tiny_scene(num_frames=2, cameras=3, size=32, num_points=120)
    cls = get_expert_class("static")
    cfg = cls.config_class.from_preset("quick")
    cfg = replace(cfg, train=replace(cfg.train, iterations=20))
    experts = [
        cls.from_scene(scene, cfg).eval(),
        get_expert_class("mcmc")
        .from_scene(scene, get_expert_class("mcmc").config_class.from_preset("quick"))
        .eval(),
    ]
    teacher = MoEGS(experts, RouterConfig.from_preset("quick"))
    student = cls.from_scene(scene, cfg)

    def agreement() -> float:
        """PSNR of the student's render against the teacher's, over the test views."""
        with torch.no_grad():
            pairs = [
                (
                    render_view(student, v.camera, scene.background)[0],
                    teacher.render(v.camera, scene.background),
                )
                for v in scene.test
            ]
            return float(torch.stack([psnr(s, t.image) for s, t in pairs]).mean())

    before = agreement()
    result = distill(student, teacher, scene, DistillConfig(iterations=12), tmp_path, progress=False)
    assert result["completed"] and result["iterations"] == 12 and math.isfinite(result["test"]["psnr"])
    assert agreement() > before + 1.0  # the student learned the teacher's images
    reloaded, state = load_expert(tmp_path, scene)
    assert state["step"] == 12 and reloaded.num_gaussians == student.num_gaussians
    with pytest.raises(ValueError, match="not one of the teacher's experts"):
        distill(
            get_expert_class("deformable").from_scene(
                scene, get_expert_class("deformable").config_class.from_preset("quick")
            ),
            teacher,
            scene,
            DistillConfig(iterations=1),
        )
    with pytest.raises(ValueError, match="kd_lambda"):
        DistillConfig(kd_lambda=2.0)
