"""The device switch (``moegs.device``), placing a scene and its cameras (``Scene.to``, ``Camera.to``),
and what a run records of its device. A GPU is mimicked where needed: ``torch.cuda`` queries are patched,
and the ``meta`` device stands for a device whose values cannot be read back."""

from __future__ import annotations

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.cli import main
from moegs.device import device_kind, device_name, resolve_device
from moegs.train.checkpoint import check_device, restore_rng, rng_state


def test_auto_is_the_gpu_when_there_is_one_else_the_cpu(gpus):
    gpus(0)
    assert resolve_device("auto") == resolve_device(None) == torch.device("cpu")
    gpus(2)
    assert resolve_device("auto") == torch.device("cuda", 0)
    assert resolve_device("cuda") == torch.device("cuda", 0)
    assert resolve_device("CUDA:1") == torch.device("cuda", 1)
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")


@pytest.mark.parametrize(
    ("spec", "count", "message"),
    [
        ("cuda", 0, r"device 'cuda': CUDA is not available here"),
        ("cuda:0", 0, r"CUDA is not available here"),
        ("cuda:7", 1, r"device 'cuda:7': this machine has 1 GPU\(s\) \(cuda:0 to cuda:0\)"),
        ("gpu", 1, r"device 'gpu' is not one of auto, cpu, cuda or cuda:<index>"),
        ("cuda:x", 1, r"device 'cuda:x' is not one of"),
        ("mps", 1, r"is not one of"),
    ],
)
def test_a_device_the_machine_lacks_is_one_clear_line(gpus, spec, count, message):
    gpus(count)
    with pytest.raises(ValueError, match=message) as err:
        resolve_device(spec)
    assert "\n" not in str(err.value)


def test_names_and_kinds():
    assert device_name(torch.device("cpu")) == "cpu"
    assert device_name(torch.device("cuda", 1)) == "cuda:1"
    assert device_kind("cuda:3") == device_kind(torch.device("cuda")) == "cuda"


@pytest.mark.parametrize("command", ["train --expert static --scene dnerf:mutant", "eval runs/none"])
def test_the_commands_refuse_a_missing_gpu_before_any_work(command, gpus, capsys):
    gpus(0)
    with pytest.raises(SystemExit) as exit_:
        main([*command.split(), "--device", "cuda"])
    assert exit_.value.code == 2
    assert "argument --device: device 'cuda': CUDA is not available here" in capsys.readouterr().err


def test_a_camera_answers_its_intrinsics_without_reading_its_tensors():
    camera = tiny_scene(num_frames=1, cameras=1, size=16).train[0].camera
    placed = camera.to("meta")  # values on the meta device cannot be read: any read would raise
    assert placed.K.device.type == "meta"
    assert (placed.fx, placed.fy, placed.cx, placed.cy) == (camera.fx, camera.fy, camera.cx, camera.cy)
    moved = placed.at_time(0.5).with_planes(0.3, 9.0)
    assert (moved.time, moved.near, moved.far, moved.fx) == (0.5, 0.3, 9.0, camera.fx)
    assert camera.to("cpu") is camera
    assert camera.scaled(0.5).fx == pytest.approx(camera.fx / 2)


def test_a_scene_placed_on_a_device_moves_cameras_background_and_images_there():
    scene = tiny_scene(num_frames=2, cameras=2, size=16)
    assert scene.to("cpu") is scene
    placed = scene.to("meta")
    assert placed is scene.to(torch.device("meta")) is placed.to("meta")  # once per device
    assert len(placed.train) == len(scene.train) and len(placed.test) == len(scene.test)
    view = placed.train[1]
    assert view.camera.K.device.type == "meta" and placed.background.device.type == "meta"
    image = view.image()
    assert image.device.type == "meta" and image.shape == scene.train[1].image().shape
    assert view.key == scene.train[1].key and view.camera.time == scene.train[1].camera.time
    assert len(placed.cache) == 1 and len(scene.cache) == 1  # decoded once on the host, kept on the device
    assert scene.train[1].camera.K.device.type == "cpu"  # the scene itself is unchanged


def test_a_checkpoint_resumes_only_on_its_kind_of_device():
    check_device({"device": "cuda:0"}, torch.device("cuda", 1), "ckpt")  # another GPU of the same kind
    check_device({}, torch.device("cpu"), "ckpt")  # written before devices were recorded: the CPU
    with pytest.raises(ValueError, match=r"ckpt was trained on cpu; resuming it on cuda:0 .* --device cpu"):
        check_device({"device": "cpu"}, torch.device("cuda", 0), "ckpt")
    with pytest.raises(ValueError, match=r"trained on cuda:0; resuming it on cpu"):
        check_device({"device": "cuda:0"}, torch.device("cpu"), "ckpt")


def test_a_gpu_run_saves_and_restores_the_gpu_generator_too(monkeypatch):
    saved = {}
    monkeypatch.setattr(torch.cuda, "get_rng_state", lambda device: torch.tensor([7], dtype=torch.uint8))
    monkeypatch.setattr(torch.cuda, "set_rng_state", lambda state, device: saved.update(state=state))
    gpu = torch.device("cuda", 0)
    assert set(rng_state(torch.device("cpu"))) == {"torch"}
    state = rng_state(gpu)
    assert set(state) == {"torch", "cuda"}
    restore_rng(state, gpu)
    assert torch.equal(saved["state"], torch.tensor([7], dtype=torch.uint8))
