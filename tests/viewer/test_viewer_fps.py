"""``python -m bench.viewer_fps``: frame rates of the viewer's drawing along an orbit."""

from __future__ import annotations

import pytest

from bench.viewer_fps import frame_rates, main
from moegs.render_path import camera_path
from moegs.viewer.model import load_model


def test_rates_per_size_for_every_camera(tiny_route):
    model = load_model([tiny_route / "router_vapr"])
    _, orbit = camera_path("orbit", [v.camera for v in model.scene.train], model.scene.test[0].camera, 3)
    rates = frame_rates(model, orbit, "gate grid4d", "blend", [32, 16])
    assert sorted(rates) == [16, 32] and all(len(r) == 3 and (r > 0).all() for r in rates.values())


def test_the_command_prints_each_mode_and_size(tiny_route, capsys):
    assert main([str(tiny_route / "router_vapr"), "--size", "24", "--frames", "4", "--warmup", "1"]) == 0
    out = capsys.readouterr().out
    assert "frames/s over 3 orbit cameras (time swept)" in out
    assert [line.split(":")[0].strip() for line in out.splitlines()[2:]] == [
        "rgb of blend",
        "gate grid4d of blend",
        "rgb of grid4d",
    ]
    assert all("24x24" in line for line in out.splitlines()[2:])


def test_frames_must_exceed_the_warmup(tiny_route, capsys):
    with pytest.raises(SystemExit):
        main([str(tiny_route), "--frames", "3", "--warmup", "5"])
    assert "--frames (3) must exceed --warmup (5)" in capsys.readouterr().err
