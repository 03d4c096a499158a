"""``moegs view`` on a tiny trained MoE-GS model: what it opens, that its server answers HTTP, and a real
headless Chromium that loads the page, sees a render, moves the time slider and switches to a gate map."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

from moegs.viewer.model import load_model
from moegs.viewer.render import GATE_COLORMAP, colormap, colour_bar_box

pytestmark = pytest.mark.slow
pytest.importorskip("viser", reason="moegs view needs viser (pip install 'moegs[viewer]')")


def test_what_the_viewer_opens(tiny_route):
    moe = load_model([tiny_route])  # a route folder holding one router
    assert moe.moe is not None and moe.names == ["deformable", "grid4d"]
    assert moe.modes[-3:] == ["gate deformable", "gate grid4d", "winner"] and moe.sources[0] == "blend"
    both = load_model([tiny_route / "deformable", tiny_route / "grid4d"])
    assert both.moe is None and both.sources == ["deformable", "grid4d"] and "winner" not in both.modes
    one = load_model([tiny_route / "grid4d"])
    assert one.sources == ["grid4d"] and one.modes == ["rgb", "depth", "alpha", "ground truth", "error"]
    assert len(one.views()) == len(one.scene.test) + len(one.scene.train)


def test_the_viewer_serves_its_page(tiny_route):
    from moegs.viewer.server import Viewer

    viewer = Viewer(load_model([tiny_route / "router_vapr"]), "127.0.0.1", 0, mode="gate grid4d")
    try:
        with urllib.request.urlopen(viewer.url, timeout=30) as reply:
            assert reply.status == 200 and b"<html" in reply.read().lower()
    finally:
        viewer.stop()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def served(tiny_route):
    """``moegs view <router>`` in its own process; yields its URL."""
    port = _free_port()
    argv = [sys.executable, "-m", "moegs.cli", "view", str(tiny_route / "router_vapr"), "--port", str(port)]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in process.stdout:
            lines.append(line)
            if "viewer at" in line:
                break
        assert process.poll() is None, "".join(lines)
        yield f"http://127.0.0.1:{port}"
    finally:
        process.terminate()
        process.wait(30)


def test_a_browser_sees_the_render_the_time_slider_and_a_gate_map(served):
    from helpers.browser import Chromium

    with Chromium(timeout=120) as page:
        page.open(served)
        _wait_status(page, "at rest", "t=0.000", "rgb of blend")
        first = page.screenshot()
        region = _render_region(first)
        assert region.std() > 3 and len(np.unique(region.reshape(-1, 3), axis=0)) > 50, "no render drawn"
        assert not _colour_bar(page, first)

        # the time slider: a click near the right end of its track
        track = page.evaluate(
            _RECT % "document.querySelector('[role=slider]').closest('.mantine-Slider-root')"
        )
        page.click(track["right"] - 3, track["top"] + track["height"] / 2)
        status = _wait_status(page, "at rest", "rgb of blend", r"t=0\.9\d\d|t=1\.000")
        later = page.screenshot()
        change = np.abs(_render_region(later).astype(float) - region).mean()
        assert change > 0.5, f"the render did not change with time ({status}; mean change {change:.2f})"

        # the mode list: pick "gate grid4d"
        boxes = page.evaluate(_VISIBLE % "input[role=combobox]")
        mode = boxes[1]  # Camera, Mode, Render
        page.click(mode["x"] + mode["width"] / 2, mode["y"] + mode["height"] / 2)
        option = page.wait_for(
            lambda: next(
                (o for o in page.evaluate(_VISIBLE % "[role=option]") if o["text"] == "gate grid4d"), None
            ),
            "option 'gate grid4d'",
        )
        page.click(option["x"] + option["width"] / 2, option["y"] + option["height"] / 2)
        _wait_status(page, "at rest", "gate grid4d")
        gate = page.screenshot()
        _keep({"render": first, "later": later, "gate": gate})
        assert _colour_bar(page, gate), "no colour bar drawn in the gate view"


def _keep(screenshots: dict[str, np.ndarray]) -> None:
    """Save the screenshots as PNGs into ``$MOEGS_VIEWER_SCREENSHOTS`` when it is set (to look at them)."""
    import os
    from pathlib import Path

    import imageio.v3 as iio

    if folder := os.environ.get("MOEGS_VIEWER_SCREENSHOTS"):
        Path(folder).mkdir(parents=True, exist_ok=True)
        for name, image in screenshots.items():
            iio.imwrite(Path(folder) / f"{name}.png", image)


_RECT = """(() => {
    const r = %s.getBoundingClientRect();
    return {left: r.left, right: r.right, top: r.top, height: r.height};
})()"""
_VISIBLE = """[...document.querySelectorAll('%s')].map(e => {
    const r = e.getBoundingClientRect();
    return {text: e.innerText, x: r.x, y: r.y, width: r.width, height: r.height};
}).filter(r => r.width > 0)"""


def _wait_status(page, *patterns: str) -> str:
    """The viewer's status line once it matches every regular expression of ``patterns``."""

    def status():
        text = page.evaluate("document.body.innerText")
        line = next((x for x in text.splitlines() if " fps · " in x), "")
        return line if all(re.search(p, line) for p in patterns) else None

    line = page.wait_for(status, f"status line matching {patterns}", timeout=180)
    time.sleep(1.0)  # the image was sent before the status: give the page a moment to draw it
    return line


def _render_region(screenshot: np.ndarray) -> np.ndarray:
    """The part of the page where only the render shows (left of the controls, below the notice)."""
    return screenshot[200:540, 20:640].astype(float)


def _colour_bar(page, screenshot: np.ndarray) -> bool:
    """Whether the page shows the gate colour bar where ``with_colour_bar`` puts it on the render (the
    background image fills the canvas)."""
    line = page.evaluate("document.body.innerText")
    width, height = map(int, re.search(r"(\d+)x(\d+) \(", line).groups())
    canvas = page.evaluate(_RECT % "document.querySelector('canvas')")
    scale = screenshot.shape[1] / page.evaluate("window.innerWidth")
    x0, y0, x1, y1 = colour_bar_box(height, width)
    xs = np.arange(x0 + 1, x1 - 1)
    expected = colormap((xs - x0) / (x1 - x0 - 1), GATE_COLORMAP).astype(float)
    px = ((xs + 0.5) / width * (canvas["right"] - canvas["left"]) + canvas["left"]) * scale
    py = (((y0 + y1) / 2) / height * canvas["height"] + canvas["top"]) * scale
    seen = screenshot[int(py), px.astype(int)].astype(float)
    return float(np.abs(seen - expected).mean()) < 25
