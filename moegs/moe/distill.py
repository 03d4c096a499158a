"""Distillation of MoE-GS into one expert (paper Sec. "Practical Efficiency Design" (iii)).

The student ``E_k`` (one of the teacher's experts, trained again from scratch with its own schedule and
the one training loop) replaces its photometric loss by::

    L_k^KD = lambda L(G'_k I_Ek, G'_k I_GT) + (1 - lambda) L((1 - G'_k) I_Ek, (1 - G'_k) I_MoE)

with ``L`` = the student's own L1 + D-SSIM mix, ``G'_k`` the teacher's gate of expert ``k`` and ``I_MoE``
the teacher's image ("Distilled (Ours)"). ``weighted=False`` drops the gates: ``lambda L(I_Ek, I_GT) +
(1 - lambda) L(I_Ek, I_MoE)`` ("w/o Weight", paper Table XV). The paper gives no lambda (the authors'
code has no distillation); 0.5 is our default. Teacher outputs are rendered on first use and kept while a
memory budget holds them (``TeacherCache``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from moegs.data.scene import ImageCache, Scene, View, tensor_bytes
from moegs.experts.base import Expert
from moegs.io.config import Presets
from moegs.moe.model import MoEGS
from moegs.train.losses import photometric

TEACHER_CACHE_BYTES = 4 << 30
"""Default memory for the teacher's outputs (4 GiB: every view of the quick presets; at full resolution a
view takes 16 bytes a pixel, 22 MB on N3V, so about 190 of N3V's 5700 training views)."""


@dataclass
class DistillConfig(Presets):
    """Settings of distillation into one expert."""

    iterations: int | None = None
    """Student iterations; None = the student's own preset."""
    weighted: bool = True
    """Routing-weighted KD loss (paper's) or plain GT + MoE supervision ("w/o Weight")."""
    kd_lambda: float = 0.5
    """Balance of ground truth vs MoE supervision (the paper gives no value)."""
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.kd_lambda <= 1.0:
            raise ValueError(f"DistillConfig.kd_lambda must be in [0, 1], got {self.kd_lambda}")

    @classmethod
    def presets(cls) -> dict[str, Callable[[], DistillConfig]]:
        return {"quick": cls, "paper": cls}


def kd_loss(
    rgb: Tensor, target: Tensor, moe_image: Tensor, gate: Tensor | None, kd_lambda: float, lambda_dssim: float
) -> Tensor:
    """``L_k^KD`` for one view; ``gate [H, W]`` is G'_k (None: the unweighted variant)."""
    if gate is None:
        gt_term = photometric(rgb, target, lambda_dssim)
        moe_term = photometric(rgb, moe_image, lambda_dssim)
    else:
        g = gate[..., None]
        gt_term = photometric(g * rgb, g * target, lambda_dssim)
        moe_term = photometric((1 - g) * rgb, (1 - g) * moe_image, lambda_dssim)
    return kd_lambda * gt_term + (1.0 - kd_lambda) * moe_term


class TeacherCache:
    """The teacher's image and the student's gate per training view, rendered on first use and kept while
    ``max_bytes`` holds them (LRU, 16 bytes a pixel); a view that does not fit is rendered again each time
    it is needed. The teacher is deterministic on the CPU, so the budget changes no number there.

    Entries stay on the teacher's device: on a GPU, a kept view costs nothing, while a view kept on the
    host would cost a copy of its 16 bytes a pixel per use, a sizeable fraction of rendering it again (one
    forward pass of the teacher, without gradients); so the budget is GPU memory, beside the student's."""

    def __init__(
        self, teacher: MoEGS, index: int, background: Tensor | None, max_bytes: int = TEACHER_CACHE_BYTES
    ) -> None:
        self.teacher, self.index, self.background = teacher.eval(), index, background
        self.outputs = ImageCache(max_bytes=max_bytes, nbytes=lambda pair: sum(map(tensor_bytes, pair)))

    def render(self, view: View) -> tuple[Tensor, Tensor]:
        """``(image [H, W, 3], gate [H, W])`` of the teacher for ``view``."""
        with torch.no_grad():
            out = self.teacher.render(view.camera, self.background)
        return out.image, out.gates[self.index].clone()  # a copy: the kept gate alone, not all K

    def __call__(self, view: View) -> tuple[Tensor, Tensor]:
        return self.outputs.get(view.key, lambda: self.render(view))


def student_index(student: Expert, teacher: MoEGS) -> int:
    """Position of the student's method among the teacher's experts (ValueError when absent)."""
    names = [e.name for e in teacher.experts]
    if student.name not in names:
        raise ValueError(f"distillation student {student.name!r} is not one of the teacher's experts {names}")
    return names.index(student.name)


def kd_view_loss(teacher_of: TeacherCache, config: DistillConfig):
    """The training loop's per-view loss (``moegs.train.loop.ViewLoss``): ``kd_loss`` against the teacher."""

    def loss(view: View, rgb: Tensor, target: Tensor, lambda_dssim: float) -> Tensor:
        moe_image, gate = teacher_of(view)
        return kd_loss(
            rgb, target, moe_image, gate if config.weighted else None, config.kd_lambda, lambda_dssim
        )

    return loss


def distill(
    student: Expert,
    teacher: MoEGS,
    scene: Scene,
    config: DistillConfig | None = None,
    out_dir: str | Path | None = None,
    progress: bool = False,
    teacher_cache_bytes: int = TEACHER_CACHE_BYTES,
) -> dict[str, Any]:
    """Train ``student`` (freshly built with ``from_scene``, moved here to the teacher's device) under the
    teacher's supervision; ``teacher_cache_bytes`` bounds the teacher outputs kept (``TeacherCache``).

    Returns the training loop's result (``moegs.train.loop.train``); ``out_dir`` holds a checkpoint that
    ``moegs.train.checkpoint.load_expert`` reads.
    """
    from moegs.train.loop import train

    config = config or DistillConfig()
    index = student_index(student, teacher)
    scene = scene.to(teacher.device)
    student.to(teacher.device)
    teacher_of = TeacherCache(teacher, index, scene.background, max_bytes=teacher_cache_bytes)
    loss = kd_view_loss(teacher_of, config)
    train_config = student.config.train
    overrides: dict[str, Any] = {"seed": config.seed}
    if config.iterations is not None:
        overrides["iterations"] = config.iterations
    return train(student, scene, replace(train_config, **overrides), out_dir, progress=progress, loss=loss)
