"""Headless Chromium driven over the Chrome DevTools protocol (a websocket), for the viewer's browser test.

    with Chromium() as page:              # skips the test when no chromium is installed
        page.open("http://127.0.0.1:8080")
        png = page.screenshot()           # uint8 [H, W, 3]
        page.click(x, y); page.evaluate("document.title")

Only Debian's ``chromium`` (or ``chromium-browser``, ``google-chrome``) is used, with software WebGL
(SwiftShader); nothing is downloaded. The websocket client is ``websockets`` (a dependency of viser).
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
WINDOW = (1000, 700)


def find_chromium() -> str | None:
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


class Chromium:
    """One headless browser with one page."""

    def __init__(self, timeout: float = 60.0) -> None:
        self.timeout = timeout
        self.binary = find_chromium()
        if self.binary is None:
            pytest.skip("no chromium on PATH (Debian: apt-get install chromium); the browser test needs one")

    def __enter__(self) -> Chromium:
        from websockets.sync.client import connect

        self._profile = tempfile.TemporaryDirectory(ignore_cleanup_errors=True)  # children may still write
        flags = ["--headless=new", "--no-sandbox", "--disable-gpu-sandbox", "--use-angle=swiftshader"]
        flags += ["--enable-unsafe-swiftshader", "--no-first-run", "--disable-extensions", "--mute-audio"]
        flags += [
            "--remote-debugging-port=0",
            "--remote-allow-origins=*",
            f"--user-data-dir={self._profile.name}",
        ]
        flags += [f"--window-size={WINDOW[0]},{WINDOW[1]}", "about:blank"]
        self._process = subprocess.Popen(
            [self.binary, *flags], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        port_file = Path(self._profile.name) / "DevToolsActivePort"
        port = self._wait(
            lambda: port_file.is_file() and port_file.read_text().split("\n")[0], "DevTools port"
        )
        pages = self._wait(lambda: self._pages(port), "a page target")
        self._socket = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=self.timeout)
        self._id = 0
        self.send("Page.enable")
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._socket.close()
        finally:
            self._process.terminate()
            try:
                self._process.wait(10)
            except subprocess.TimeoutExpired:
                self._process.kill()
            self._profile.cleanup()

    def _wait(self, probe, what: str):
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            try:
                if value := probe():
                    return value
            except OSError:
                pass
            time.sleep(0.2)
        raise TimeoutError(f"chromium gave no {what} within {self.timeout:.0f} s")

    @staticmethod
    def _pages(port: str) -> list[dict]:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as reply:
            return [t for t in json.load(reply) if t.get("type") == "page"]

    # -- protocol ---------------------------------------------------------------------------------------
    def send(self, method: str, **params):
        """The result of one DevTools command (events in between are dropped)."""
        self._id += 1
        self._socket.send(json.dumps({"id": self._id, "method": method, "params": params}))
        deadline = time.monotonic() + self.timeout
        while True:
            message = json.loads(self._socket.recv(timeout=max(0.1, deadline - time.monotonic())))
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def open(self, url: str) -> None:
        self.send("Page.navigate", url=url)
        self._wait(lambda: self.evaluate("document.readyState") == "complete", f"load of {url}")

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        result = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression!r}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def click(self, x: float, y: float) -> None:
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.send("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)

    def key(self, key: str, code: str, key_code: int) -> None:
        for kind in ("keyDown", "keyUp"):
            self.send("Input.dispatchKeyEvent", type=kind, key=key, code=code, windowsVirtualKeyCode=key_code)

    def screenshot(self) -> np.ndarray:
        """uint8 ``[H, W, 3]`` of the page as drawn now."""
        from PIL import Image

        data = base64.b64decode(self.send("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    def wait_for(self, probe, what: str, timeout: float | None = None):
        """Poll ``probe()`` until it returns something truthy (``TimeoutError`` naming ``what``)."""
        deadline = time.monotonic() + (timeout or self.timeout)
        while time.monotonic() < deadline:
            if value := probe():
                return value
            time.sleep(0.25)
        raise TimeoutError(f"no {what} within {timeout or self.timeout:.0f} s")
