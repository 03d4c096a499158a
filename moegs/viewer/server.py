"""The viser glue of ``moegs view``: a web page with the model's render as the background, a free camera,
the dataset's cameras to jump to, a time slider with play/pause, the modes and the frame rate.

    viewer = Viewer(load_model(["runs/route/router_vapr"]), "127.0.0.1", 8080)
    viewer.wait()          # until Ctrl+C; viewer.stop() from another thread

Each browser tab gets a thread that renders whenever the camera, time or mode changed: at half the
resolution while the camera moves or time plays, at full resolution once it rests (``REST_SECONDS``).
Rendering is serialised (one model, one lock); what is drawn comes from ``moegs.viewer.render``.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

from moegs.viewer.render import (
    BLEND,
    SOURCED_MODES,
    camera_from_pose,
    check_choice,
    letterbox,
    pose_of_camera,
    render_mode,
    sized,
)

REST_SECONDS = 0.3
"""How long the camera must rest before a full-resolution frame."""

DEFAULT_SIZE = 256
"""The least default size of a frame at rest (longer side): the quick preset's images are smaller."""

FREE = "free camera"
"""The camera list's entry of the viewer's own camera."""


def check_port(host: str, port: int) -> None:
    """``OSError`` in one line when ``host:port`` cannot be listened on (viser would move to the next port
    in silence); port 0 picks a free one."""
    if not 0 <= port <= 65535:
        raise ValueError(f"--port must be in [0, 65535], got {port}")
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as err:
            raise OSError(f"cannot listen on {host}:{port} ({err.strerror}); choose another --port") from None


@dataclass
class _Tab:
    """One browser tab's state: the dataset view it shows (None: free camera) and its last frame."""

    view: object | None = None
    view_pose: tuple | None = None
    last_pose: tuple | None = None
    moved_at: float = 0.0
    drawn: tuple | None = None
    fps: float = 0.0


class Viewer:
    """A running viewer of ``model`` (``moegs.viewer.model.ViewModel``) on ``host:port``.

    ``size``: the longer side of a frame at rest (default: the scene's image size, at least
    ``DEFAULT_SIZE``); ``mode`` and
    ``source``: what is shown first (``model.modes``, ``model.sources``)."""

    def __init__(
        self,
        model,
        host: str = "127.0.0.1",
        port: int = 8080,
        size: int | None = None,
        mode: str = "rgb",
        source: str | None = None,
    ) -> None:
        try:
            import viser
        except ImportError:
            raise ImportError("moegs view needs viser: pip install 'moegs[viewer]'") from None

        self.model = model
        check_choice(mode, model.modes, "mode")
        source = check_choice(source or model.sources[0], model.sources, "source")
        reference = (model.scene.test or model.scene.train)[0].camera
        self.size = size or max(DEFAULT_SIZE, reference.width, reference.height)
        self.views = dict(model.views())
        self._lock = threading.Lock()
        self._stopped = threading.Event()
        self._tabs: dict[int, _Tab] = {}

        self.server = viser.ViserServer(host=host, port=port, label="moegs view", verbose=False)
        if port and self.server.get_port() != port:
            self.server.stop()
            raise OSError(f"cannot listen on {host}:{port} (in use); choose another --port")
        self.host, self.port = host, self.server.get_port()
        self._setup_scene(reference)
        self._setup_gui(mode, source)
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(lambda client: self._tabs.pop(client.client_id, None))

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    # -- page ----------------------------------------------------------------------------------------------
    def _setup_scene(self, reference) -> None:
        from moegs.render_path import look_at_centre, world_up

        cameras = [v.camera for v in self.views.values()]
        up = world_up(cameras).numpy()
        self.server.scene.set_up_direction(up)
        wxyz, position, fov = pose_of_camera(reference)
        centre = look_at_centre(cameras).numpy()
        initial = self.server.initial_camera
        initial.position, initial.look_at, initial.up, initial.fov = position, centre, up, fov

    def _setup_gui(self, mode: str, source: str) -> None:
        gui, model = self.server.gui, self.model
        gui.configure_theme(control_width="medium", show_logo=False, show_share_button=False)
        gui.add_markdown(f"**{model.label}**  \n{', '.join(model.names)}: {model.num_gaussians:,} Gaussians")
        times = model.times()
        self.time = gui.add_slider("Time", min(times), max(times), step=0.001, initial_value=min(times))
        self.play = gui.add_checkbox("Play", initial_value=False)
        self.camera = gui.add_dropdown("Camera", [FREE, *self.views], initial_value=FREE)
        self.mode = gui.add_dropdown("Mode", model.modes, initial_value=mode)
        self.source = gui.add_dropdown("Render", model.sources, initial_value=source)
        self.source.visible = len(model.sources) > 1
        self.resolution = gui.add_slider("Resolution", 64, max(1024, self.size), 16, self.size)
        self.status = gui.add_markdown("starting")
        self.camera.on_update(self._jump)

    def _jump(self, event) -> None:
        """A dataset camera was picked: move the tab's camera there and the time slider to its time."""
        label = self.camera.value
        clients = [event.client] if event.client is not None else list(self.server.get_clients().values())
        view = self.views.get(label)
        for client in clients:
            tab = self._tabs.setdefault(client.client_id, _Tab())
            if view is None:
                tab.view = None
                continue
            wxyz, position, fov = pose_of_camera(view.camera)
            R = view.camera.world_to_camera[:3, :3].detach().cpu().double().numpy()
            with client.atomic():
                client.camera.fov = fov
                client.camera.position = position
                client.camera.look_at = position + R[2]
                client.camera.up_direction = -R[1]
            tab.view_pose, tab.view = (tuple(wxyz), tuple(position)), view
        if view is not None:
            self.time.value = float(np.clip(view.camera.time, self.time.min, self.time.max))

    # -- rendering ----------------------------------------------------------------------------------------
    def _connect(self, client) -> None:
        self._tabs.setdefault(client.client_id, _Tab())
        threading.Thread(target=self._serve_tab, args=(client,), daemon=True).start()

    def _serve_tab(self, client) -> None:
        while not self._stopped.is_set() and client.client_id in self._tabs:
            try:
                drew = self._frame(client, self._tabs[client.client_id])
            except (AssertionError, KeyError):  # the tab's camera is not known yet, or it closed
                drew = False
            except Exception as err:  # noqa: BLE001 - shown on the page; the viewer keeps serving
                from moegs.errors import describe_error

                self.status.content = f"render failed: {describe_error(err)}"
                time.sleep(0.5)
                drew = False
            if not drew:
                time.sleep(0.01)

    def _frame(self, client, tab: _Tab) -> bool:
        """Render and send one frame when anything changed; returns whether it did."""
        cam = client.camera
        pose = (tuple(np.round(cam.wxyz, 6)), tuple(np.round(cam.position, 6)), round(cam.fov, 6), cam.aspect)
        now = time.perf_counter()
        if pose != tab.last_pose:
            tab.last_pose, tab.moved_at = pose, now
            if tab.view is not None and not _same_pose(tab.view_pose, cam.wxyz, cam.position):
                tab.view = None  # the user moved away from the dataset camera
                self.camera.value = FREE
        playing = self.play.value
        moving = playing or now - tab.moved_at < REST_SECONDS
        size = max(32, int(self.resolution.value) // (2 if moving else 1))
        t, mode, source, view = self.time.value, self.mode.value, self.source.value, tab.view
        state = (pose, t, mode, source, size, id(view))
        if state == tab.drawn:
            return False
        if view is not None:  # the dataset camera itself (its intrinsics), padded to the page's aspect
            camera = view.camera.scaled(size / max(view.camera.width, view.camera.height)).at_time(t)
            truth = self.model.truth(view)
        else:
            width, height = sized(round(cam.aspect * 1000), 1000, size)
            camera = camera_from_pose(cam.wxyz, cam.position, cam.fov, width, height, t)
            truth = None
        with self._lock:
            image = render_mode(self.model, camera, mode, source, truth)
        if view is not None:
            image = letterbox(image, cam.aspect)
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)
        tab.drawn = state
        seconds = time.perf_counter() - now
        tab.fps = 1 / seconds if tab.fps == 0 else 0.8 * tab.fps + 0.2 / seconds
        what = "moving" if moving else "at rest"
        shown = f"{mode} of {source}" if mode in SOURCED_MODES else mode
        self.status.content = (
            f"**{tab.fps:.1f}** fps · {camera.width}x{camera.height} ({what}) · t={t:.3f} · {shown}"
        )
        if playing:
            self.time.value = _next_time(self.model.times(), t)
        return True

    # -- life ---------------------------------------------------------------------------------------------
    def wait(self) -> None:
        """Block until ``stop`` (or Ctrl+C, which stops it)."""
        try:
            while not self._stopped.wait(0.5):
                pass
        finally:
            self.stop()

    def stop(self) -> None:
        if not self._stopped.is_set():
            self._stopped.set()
            self.server.stop()


def _same_pose(view_pose: tuple | None, wxyz, position) -> bool:
    if view_pose is None:
        return False
    q, p = np.asarray(view_pose[0]), np.asarray(view_pose[1])
    scale = max(1.0, float(np.linalg.norm(p)))
    return abs(float(q @ np.asarray(wxyz))) > 1 - 1e-6 and float(np.linalg.norm(p - position)) < 1e-4 * scale


def _next_time(times: list[float], t: float) -> float:
    """The first of ``times`` after ``t``, wrapping to the first."""
    later = [u for u in times if u > t + 1e-9]
    return later[0] if later else times[0]


__all__ = ["BLEND", "FREE", "Viewer", "check_port"]
