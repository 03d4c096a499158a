"""The viewer's drawing without a browser: camera conversion, every mode of a tiny MoE-GS model, colour
bars, legends, and the bad input of ``moegs view``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.camera import look_at
from moegs.cli import main
from moegs.experts import get_expert_class
from moegs.moe import MoEGS, RouterConfig
from moegs.viewer.model import ViewModel
from moegs.viewer.render import (
    BLEND,
    GATE_COLORMAP,
    camera_from_pose,
    colormap,
    colour_bar_box,
    letterbox,
    matrix_to_quat,
    pose_of_camera,
    quat_to_matrix,
    render_mode,
    sized,
    with_colour_bar,
)


@pytest.fixture(scope="module")
def tiny_moe() -> ViewModel:
    """Two untrained experts of a 32x32 scene (one perturbed) and a router with random weights (the gates
    vary)."""
    torch.manual_seed(0)
    scene = tiny_scene(num_frames=3, cameras=3, size=32, num_points=120)
    classes = [get_expert_class(n) for n in ("static", "deformable")]
    experts = [c.from_scene(scene, c.config_class.from_preset("quick")).eval() for c in classes]
    with torch.no_grad():
        for p in experts[1].splats.values():  # the two experts differ
            p.add_(0.3 * torch.randn_like(p))
    moe = MoEGS(experts, RouterConfig.from_preset("quick"))
    with torch.no_grad():
        for p in moe.router.parameters():
            p.normal_()
    return ViewModel(scene, experts, moe, "auto", "tiny")


def test_quaternions_and_poses_round_trip():
    g = torch.Generator().manual_seed(1)
    for q in torch.randn(8, 4, generator=g, dtype=torch.float64).numpy():
        q = q / np.linalg.norm(q)
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        back = matrix_to_quat(R)
        assert abs(abs(back @ q) - 1) < 1e-12 and back[0] >= 0
    w2c = look_at(torch.tensor([2.0, -3.0, 1.5]), torch.tensor([0.1, 0.2, 0.0]))
    camera = camera_from_pose(*_pose(w2c), fov_y=0.7, width=64, height=48, time=0.25)
    wxyz, position, fov = pose_of_camera(camera)
    again = camera_from_pose(wxyz, position, fov, 64, 48, 0.25)
    torch.testing.assert_close(again.world_to_camera, camera.world_to_camera, atol=1e-6, rtol=0)
    torch.testing.assert_close(camera.world_to_camera, w2c, atol=1e-6, rtol=0)
    assert fov == pytest.approx(0.7) and (camera.cx, camera.cy, camera.time) == (32, 24, 0.25)
    assert camera.fy == pytest.approx(24 / math.tan(0.35))


def _pose(w2c: torch.Tensor):
    """``(wxyz, position)`` of a world-to-camera matrix, by hand (viser's convention)."""
    R = w2c[:3, :3].double().numpy().T
    return matrix_to_quat(R), -R @ w2c[:3, 3].double().numpy()


def test_a_dataset_camera_survives_the_viewer_pose(tiny_moe):
    """A dataset camera (square pixels, centred) turned into a viewer pose and back is the same camera."""
    view = tiny_moe.scene.test[0].camera
    again = camera_from_pose(*pose_of_camera(view), view.width, view.height, view.time)
    torch.testing.assert_close(again.world_to_camera, view.world_to_camera, atol=1e-5, rtol=0)
    torch.testing.assert_close(again.K, view.K, atol=1e-4, rtol=0)


def test_every_mode_and_source_draws_an_image(tiny_moe):
    camera = tiny_moe.scene.test[1].camera
    truth = tiny_moe.truth(tiny_moe.scene.test[1])
    assert tiny_moe.modes == [
        "rgb", "depth", "alpha", "ground truth", "error", "gate static", "gate deformable", "winner",
    ]  # fmt: skip
    assert tiny_moe.sources == [BLEND, "static", "deformable"]
    for mode in tiny_moe.modes:
        for source in tiny_moe.sources:
            image = render_mode(tiny_moe, camera, mode, source, truth)
            assert image.shape == (32, 32, 3) and image.dtype == np.uint8, (mode, source)
    rgb = render_mode(tiny_moe, camera, "rgb", BLEND)
    np.testing.assert_array_equal(render_mode(tiny_moe, camera, "ground truth", BLEND, truth), truth)
    assert rgb.std() > 0 and not np.array_equal(rgb, render_mode(tiny_moe, camera, "rgb", "static"))
    # the blend's image is the router's, its alpha the experts' weighted by the gates
    out = tiny_moe.render_moe(camera)
    np.testing.assert_array_equal(rgb, (out.image.clamp(0, 1) * 255).round().byte().numpy())
    alphas = [tiny_moe.render_expert(k, camera)[1] for k in range(2)]
    _, alpha, _ = tiny_moe.render_layers(camera, BLEND)
    torch.testing.assert_close(alpha, out.gates[0] * alphas[0] + out.gates[1] * alphas[1])


def test_every_mode_draws_through_the_cuda_path(tiny_moe, monkeypatch):
    """A model whose runs recorded the CUDA backend draws every mode and source through our gsplat glue
    (gsplat's torch kernels on the CPU here), to the compiled kernel's image within one 8-bit level."""
    from dataclasses import replace

    from helpers.gsplat_reference import install_cpu_glue

    from moegs.render import _cuda

    install_cpu_glue(monkeypatch)
    calls = []
    glue = _cuda.render
    monkeypatch.setattr(_cuda, "render", lambda *a, **k: calls.append(1) or glue(*a, **k))
    moe = MoEGS(tiny_moe.experts, replace(tiny_moe.moe.config, backend="cuda"))
    moe.router.load_state_dict(tiny_moe.moe.router.state_dict())
    cuda = ViewModel(tiny_moe.scene, tiny_moe.experts, moe, "cuda", "tiny on the CUDA path")
    camera = tiny_moe.scene.test[1].camera
    truth = tiny_moe.truth(tiny_moe.scene.test[1])
    for mode in cuda.modes:
        for source in cuda.sources:
            drawn = len(calls)
            ours = render_mode(cuda, camera, mode, source, truth).astype(int)
            reference = render_mode(tiny_moe, camera, mode, source, truth).astype(int)
            assert np.abs(ours - reference).max() <= 1, (mode, source)
            assert len(calls) > drawn or mode == "ground truth", (mode, source)


def test_gate_and_winner_maps(tiny_moe):
    camera = tiny_moe.scene.test[0].camera
    gates = tiny_moe.render_moe(camera).gates
    image = render_mode(tiny_moe, camera, "gate deformable", BLEND)
    x0, y0, x1, y1 = colour_bar_box(32, 32)
    # outside the colour bar and its labels: the gate of expert 1 through viridis
    np.testing.assert_array_equal(image[:8, :8], colormap(gates[1].numpy(), GATE_COLORMAP)[:8, :8])
    assert _has_colour_bar(image, GATE_COLORMAP)
    winner = render_mode(tiny_moe, camera, "winner", BLEND)
    from moegs.moe.visualize import winner_map

    expected = winner_map(gates)
    assert (winner != expected).any(axis=-1).mean() < 0.5  # the legend covers a corner
    np.testing.assert_array_equal(winner[-4:], expected[-4:])


def _has_colour_bar(image: np.ndarray, cmap: str) -> bool:
    h, w = image.shape[:2]
    x0, y0, x1, y1 = colour_bar_box(h, w)
    expected = colormap(np.linspace(0, 1, x1 - x0), cmap)
    return np.array_equal(image[(y0 + y1) // 2, x0:x1], expected)


def test_colour_bars_depth_alpha_and_error(tiny_moe):
    camera = tiny_moe.scene.test[2].camera.scaled(4)  # 128x128: room for the labels
    truth = tiny_moe.truth(tiny_moe.scene.test[2])
    assert _has_colour_bar(render_mode(tiny_moe, camera, "error", "static", truth), "inferno")
    assert not _has_colour_bar(render_mode(tiny_moe, camera, "rgb", "static"), "inferno")
    depth = render_mode(tiny_moe, camera, "depth", "static")
    x0, y0, x1, y1 = colour_bar_box(128, 128)
    ramp = colormap(1 - np.linspace(0, 1, x1 - x0), "turbo")  # near (warm) at the left
    np.testing.assert_array_equal(depth[(y0 + y1) // 2, x0:x1], ramp)
    alpha = render_mode(tiny_moe, camera, "alpha", "static")
    np.testing.assert_array_equal(alpha[..., 0], alpha[..., 2])  # grey
    bar = with_colour_bar(np.zeros((128, 128, 3), np.uint8), "viridis", "0", "1")
    assert bar[(y0 + y1) // 2, : x0 - 8].any()  # the low label, left of the bar


def test_ground_truth_needs_a_dataset_camera(tiny_moe):
    camera = tiny_moe.scene.test[0].camera
    image = render_mode(tiny_moe, camera, "error", BLEND)
    assert image.shape == (32, 32, 3) and (image[0, 0] == 40).all()  # the message image's grey


def test_unknown_mode_and_source_are_named(tiny_moe):
    camera = tiny_moe.scene.test[0].camera
    with pytest.raises(ValueError, match="unknown mode 'gate nope'; this model's modes: rgb, depth"):
        render_mode(tiny_moe, camera, "gate nope", BLEND)
    with pytest.raises(ValueError, match="unknown source 'x'; this model's sources: blend, static, deform"):
        render_mode(tiny_moe, camera, "rgb", "x")


def test_sizes_and_letterbox():
    assert sized(1600, 900, 256) == (256, 144) and sized(400, 400, 128) == (128, 128)
    padded = letterbox(np.full((10, 10, 3), 7, np.uint8), 2.0)
    assert padded.shape == (10, 20, 3) and (padded[:, :5] == 0).all() and (padded[:, 5:15] == 7).all()
    assert letterbox(np.ones((10, 40, 3), np.uint8), 2.0).shape == (20, 40, 3)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["{tmp}"], "{tmp} is no run: it has no config.json (a `moegs train` run) and no router.safetensors"),
        (["{tmp}/missing"], "{tmp}/missing is no folder; give a run folder (moegs train) or a router folder"),
        (["{tmp}", "--port", "70000"], "--port must be in [0, 65535], got 70000"),
    ],
)
def test_view_refuses_bad_input_in_one_line(tmp_path, capsys, argv, message):
    assert main(["view", *[a.format(tmp=tmp_path) for a in argv]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("moegs view: " + message.format(tmp=tmp_path)) and err.count("\n") == 1


def test_view_refuses_a_port_in_use(tmp_path, capsys):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["view", str(tmp_path), "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert (
        err
        == f"moegs view: cannot listen on 127.0.0.1:{port} (Address already in use); choose another --port\n"
    )
