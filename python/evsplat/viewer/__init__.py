"""`evsplat view`: an interactive 4D viewer of a trained run in the browser (viser).

The page shows the run rendered through evsplat's own rasterizer as the background image of
viser's 3-D view: a time slider, a free camera (viser's orbit controls; or "follow training
camera" for the measured trajectory), the training trajectory as a curve with the camera
frustum at the current time, and toggles for depth (turbo colour map) and the event overlay
(events of the sensor around the current time, on the frustum and, when following the training
camera, blended over the render). The server binds to 127.0.0.1 only.
"""

from __future__ import annotations

import socket
import threading
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from evsplat.data.event_store import EventStore
from evsplat.data.poses import matrix_to_quat, quat_to_matrix
from evsplat.data.trajectory import Trajectory
from evsplat.errors import EvsplatError
from evsplat.render import Renderer

#: Longest side of the rendered background image (the rasterizer runs per camera move).
MAX_SIDE = 480
#: Event window of the overlay, as a fraction of the sequence.
EVENT_WINDOW = 0.02


@dataclass
class ViewState:
    """What the page asks for: time fraction, camera pose (c2w) and vertical fov, toggles."""

    time: float
    c2w: np.ndarray
    fov_y: float
    aspect: float
    depth: bool = False
    events: bool = False
    follow: bool = False


class RunView:
    """A run's renderer, trajectory and (optionally) events; renders a :class:`ViewState`."""

    def __init__(self, run_dir: Path, events: EventStore | None = None):
        self.renderer, state = Renderer.from_run(run_dir)
        self.times_us = np.asarray(state.poses.times_us, np.int64)
        self.c2w = np.asarray(state.poses.c2w, np.float64)
        self.trajectory = Trajectory.fit(self.times_us, self.c2w)
        self.events = events

    def t_us(self, frac: float) -> float:
        r = self.renderer
        return r.t_start_us + float(np.clip(frac, 0.0, 1.0)) * (r.t_end_us - r.t_start_us)

    def pose(self, frac: float) -> np.ndarray:
        return self.trajectory.pose(self.t_us(frac))

    def event_image(self, frac: float) -> np.ndarray | None:
        """The events around ``frac`` as an RGB float image (None without events)."""
        from evsplat.video import event_frame

        if self.events is None:
            return None
        r = self.renderer
        half = EVENT_WINDOW * (r.t_end_us - r.t_start_us) / 2
        t = self.t_us(frac)
        ev = self.events.read(int(t - half), int(t + half))
        return event_frame(ev, 0, len(ev))

    def render(self, view: ViewState) -> np.ndarray:
        """[H,W,3] uint8 of ``view``: following the training camera, it is the run's own camera
        (K and size); free, a pinhole with the page's fov and aspect."""
        from evsplat.video import colour_depth, to_rgb8

        r = self.renderer
        if view.follow:
            cam, c2w = r, self.pose(view.time)
        else:
            h = min(MAX_SIDE, int(MAX_SIDE / max(view.aspect, 1e-3)))
            w = max(2, int(round(h * view.aspect)))
            f = (h / 2) / np.tan(np.clip(view.fov_y, 1e-3, 3.0) / 2)
            K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], dtype=torch.float32)
            cam, c2w = replace(r, K=K, width=w, height=h), view.c2w
        with torch.no_grad():
            out = cam.render(self.t_us(view.time), c2w)
        if view.depth:
            img = colour_depth(out.depth.numpy())
        else:
            img = out.image.clamp(0, 1).numpy()
            img = img[..., :1].repeat(3, -1) if img.shape[-1] == 1 else img
        ev = self.event_image(view.time) if (view.events and view.follow) else None
        if ev is not None:
            marked = (ev < 0.999).any(-1, keepdims=True)
            img = np.where(marked, 0.3 * img + 0.7 * ev, img)
        return to_rgb8(img)


def check_port_free(port: int, host: str = "127.0.0.1") -> None:
    """Raises a one-line EvsplatError when ``port`` cannot be bound on ``host``."""
    if not 0 < port < 65536:
        raise EvsplatError(f"--port {port}: must be in 1..65535")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        # As the server will: a port left in TIME_WAIT by a closed connection is free.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            raise EvsplatError(
                f"--port {port}: cannot listen on {host}:{port} ({e.strerror}); another program "
                "uses it: pick another port with --port"
            ) from None


class Viewer:
    """The viser server for one run; :meth:`stop` shuts it down."""

    def __init__(self, view: RunView, port: int, host: str = "127.0.0.1"):
        import viser

        check_port_free(port, host)
        self.view = view
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if self.server.get_port() != port:
            # viser moves to the next free port when one is taken in between; refuse instead.
            self.server.stop()
            raise EvsplatError(f"--port {port}: taken while starting; pick another port")
        self.port = port
        self._wake = threading.Event()
        self._stopping = False
        gui = self.server.gui
        gui.add_markdown("**evsplat** 4D viewer")
        self.slider = gui.add_slider("time", min=0.0, max=1.0, step=0.005, initial_value=0.5)
        self.follow = gui.add_checkbox("follow training camera", True)
        self.depth = gui.add_checkbox("depth", False)
        self.overlay = gui.add_checkbox(
            "event overlay",
            False,
            disabled=view.events is None,
            hint=None if view.events is not None else "the run's dataset was not found",
        )
        for handle in (self.slider, self.follow, self.depth, self.overlay):
            handle.on_update(lambda _: self._wake.set())
        self._draw_trajectory()
        self.server.on_client_connect(self._on_connect)
        self._thread = threading.Thread(target=self._loop, name="evsplat-view", daemon=True)
        self._thread.start()
        self._wake.set()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _draw_trajectory(self) -> None:
        pos = self.view.c2w[:, :3, 3]
        if len(pos) >= 2:
            self.server.scene.add_spline_catmull_rom(
                "/trajectory", pos, color=(230, 120, 20), thickness=3.0, thickness_units="screen"
            )

    def _on_connect(self, client) -> None:
        c2w = self.view.pose(self.slider.value)
        client.camera.wxyz = matrix_to_quat(c2w[:3, :3])
        client.camera.position = c2w[:3, 3]
        client.camera.on_update(lambda _: self._wake.set())
        self._wake.set()

    def _loop(self) -> None:
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            if self._stopping:
                return
            self._refresh()

    def _refresh(self) -> None:
        frac = float(self.slider.value)
        c2w = self.view.pose(frac)
        r = self.view.renderer
        fov = 2 * np.arctan2(r.height / 2, float(r.K[1, 1]))
        ev = self.view.event_image(frac) if self.overlay.value else None
        self.server.scene.add_camera_frustum(
            "/camera",
            fov=float(fov),
            aspect=r.width / r.height,
            scale=0.15,
            color=(230, 120, 20),
            wxyz=matrix_to_quat(c2w[:3, :3]),
            position=c2w[:3, 3],
            image=None if ev is None else (ev * 255).astype(np.uint8),
        )
        for client in self.server.get_clients().values():
            cam = client.camera
            pose = np.eye(4)
            pose[:3, :3] = _quat_to_matrix(np.asarray(cam.wxyz, np.float64))
            pose[:3, 3] = cam.position
            state = ViewState(
                time=frac,
                c2w=pose,
                fov_y=float(cam.fov),
                aspect=float(cam.aspect),
                depth=bool(self.depth.value),
                events=bool(self.overlay.value),
                follow=bool(self.follow.value),
            )
            client.scene.set_background_image(self.view.render(state), format="jpeg")

    def stop(self) -> None:
        self._stopping = True
        self._wake.set()
        self._thread.join(timeout=30)
        self.server.stop()


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    return quat_to_matrix(q / max(float(np.linalg.norm(q)), 1e-12))


def open_viewer(run_dir: Path, port: int = 8080) -> Viewer:
    """Loads ``run_dir`` (and its dataset's events when found) and serves it on 127.0.0.1."""
    from evsplat.data.dataset import load_dataset
    from evsplat.run_state import RunState

    check_port_free(port)
    data_dir = Path(RunState.load(run_dir).dataset)
    events = None
    if (data_dir / "events.h5").is_file():
        try:
            events = load_dataset(data_dir).events
        except EvsplatError:
            events = None  # the overlay is then disabled, with a hint on the page
    return Viewer(RunView(Path(run_dir), events), port)
