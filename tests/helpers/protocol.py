"""The protocol every registered expert follows, built-in or plugin (``tests/experts/test_protocol.py``,
``tests/test_plugin_tutorial.py``): checks on a tiny scene at the expert's ``quick`` preset."""

from __future__ import annotations

import copy
from pathlib import Path

import torch

from helpers.scenes import tiny_scene
from moegs.experts import get_expert_class
from moegs.io import save_checkpoint
from moegs.train.checkpoint import load_expert, training_state

TIMES = (0.0, 0.5, 1.0)


def build(name: str, scene=None):
    """The expert ``name`` at its quick preset on ``scene`` (default: the tiny test scene), seeded."""
    cls = get_expert_class(name)
    scene = scene or tiny_scene(num_frames=3, cameras=3, size=16)
    torch.manual_seed(0)
    return cls.from_scene(scene, cls.config_class.from_preset("quick")), scene


def check_frames(expert) -> None:
    """Shapes (``GaussianFrame`` validates them), finite values, activated ranges, a deterministic
    ``frame(t)``."""
    with torch.no_grad():
        for t in TIMES:
            frame = expert.frame(t)
            assert len(frame) > 0, f"frame({t}) is empty"
            frame.check_finite(f"{expert.name}.frame({t})")
            frame.check_values(f"{expert.name}.frame({t})")
            again = expert.frame(t)
            assert torch.equal(frame.means, again.means) and torch.equal(frame.opacities, again.opacities)


def check_gradients(expert, scene) -> None:
    """Half-way through training (every stage and SH band active), a loss on renders at each frame's time
    reaches every per-Gaussian tensor the optimiser trains (a finite gradient; it may be exactly zero where
    the maths says so, e.g. the rotation of an isotropic Gaussian)."""
    expert.train()
    expert.on_step(expert.config.train.iterations // 2)
    if "dynamic" in expert.splats:  # Ex4DGS: exercise the keyframed path of dynamic Gaussians too
        expert.splats["dynamic"][::2] = True
    loss = sum(expert.render(v.camera, scene.background)[0].mean() for v in scene.train)
    loss.backward()
    trained = {id(p) for g in expert.param_groups() for p in g.params}
    for key, value in expert.splats.items():
        if id(value) in trained and value.requires_grad:
            assert value.grad is not None, f"no gradient reaches {key}"
            assert bool(value.grad.isfinite().all()), f"non-finite gradient of {key}"


def check_inputs_key(expert, scene) -> None:
    """In eval mode, views whose ``splat_inputs_key`` are equal get equal ``splat_inputs`` (the promise that
    lets router training compute a frozen expert's inputs once per key), and keys are hashable."""
    expert.eval()
    seen: dict = {}
    features = None
    compared = 0
    views = [*scene.train, *scene.test]
    with torch.no_grad():  # every view twice: the second time through a copy of its camera
        for view, camera in [*((v, v.camera) for v in views), *((v, copy.copy(v.camera)) for v in views)]:
            key = expert.splat_inputs_key(camera)
            hash(key)
            inputs = expert.splat_inputs(camera, scene.background)
            if features is None:
                channels = inputs.frame.colors if inputs.frame.colors is not None else inputs.frame.sh[:, 0]
                features = torch.rand(view.camera.height, view.camera.width, channels.shape[-1])
            decoded = inputs.decoded(features)
            if key not in seen:
                seen[key] = (inputs, decoded)
                continue
            first, first_decoded = seen[key]
            assert_same_frame(first.frame, inputs.frame, f"{view.key}, same key")
            assert first.antialiased == inputs.antialiased and torch.equal(first_decoded, decoded), view.key
            compared += 1
    assert compared >= len(views), f"only {compared} views shared a key with an earlier one"


def assert_same_frame(a, b, where: str) -> None:
    """Two ``GaussianFrame``s hold equal tensors in every field (or both lack it)."""
    for field in ("means", "quats", "scales", "opacities", "colors", "sh"):
        x, y = getattr(a, field), getattr(b, field)
        assert (x is None and y is None) or (x is not None and y is not None and torch.equal(x, y)), (
            f"{where}: {field} differs"
        )


def check_checkpoint(expert, scene, folder: Path) -> None:
    """``save_checkpoint`` then ``load_expert`` (which replays the stage of the saved step) gives the same
    frames."""
    state = training_state(expert, expert.config.train.iterations // 2, {}, {}, {}, [], 0.0)
    save_checkpoint(folder / "checkpoint.safetensors", state)
    back, _ = load_expert(folder, scene, expect=expert.name)
    expert.eval()
    with torch.no_grad():
        for t in TIMES:
            assert_same_frame(expert.frame(t), back.frame(t), f"t={t}")


def check_protocol(name: str, folder: Path) -> None:
    expert, scene = build(name)
    assert expert.name == name
    check_frames(expert)
    check_gradients(expert, scene)
    check_inputs_key(expert, scene)
    check_checkpoint(expert, scene, folder)
