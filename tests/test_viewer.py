"""`evsplat view`: the viser page is served on loopback, renders through evsplat's rasterizer,
refuses a taken port in one line; a headless-Chromium screenshot is a benchmark-marked test
(Chromium is not part of the default set-up)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
import urllib.request

import numpy as np
import pytest
import torch

from evsplat.cli import main
from evsplat.video import to_rgb8
from evsplat.viewer import RunView, ViewState, open_viewer


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from test_video import tiny_run_dir  # the same run as the output tests, trained once

    return tiny_run_dir(tmp_path_factory)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_follow_view_is_the_run_rendered_at_the_measured_pose(tiny_run):
    from evsplat.data.poses import read_tum

    view = RunView(tiny_run)
    img = view.render(ViewState(time=0.5, c2w=np.eye(4), fov_y=1.0, aspect=1.0, follow=True))
    r = view.renderer
    # Independent pose source: the dataset's own poses.txt, interpolated by the trajectory fit.
    assert img.shape == (r.height, r.width, 3)
    with torch.no_grad():
        ref = r.render(view.t_us(0.5), view.pose(0.5)).image.clamp(0, 1).numpy()
    np.testing.assert_array_equal(img, to_rgb8(ref))
    times, _ = read_tum(tiny_run.parent / "data" / "poses.txt")
    assert times.min() <= view.t_us(0.5) <= times.max()
    # With the run's events: the overlay marks exactly the pixels that saw events.
    from evsplat.data.dataset import load_dataset

    view.events = load_dataset(tiny_run.parent / "data").events
    over = view.render(
        ViewState(time=0.5, c2w=np.eye(4), fov_y=1.0, aspect=1.0, follow=True, events=True)
    )
    ev = view.event_image(0.5)
    marked = (ev < 0.999).any(-1)
    assert marked.any()
    np.testing.assert_array_equal((over != img).any(-1) & ~marked, False)
    free = view.render(ViewState(time=0.5, c2w=view.pose(0.5), fov_y=0.8, aspect=1.5, depth=True))
    assert free.shape[1] > free.shape[0] and free.std() > 0


def test_viewer_serves_its_page_on_loopback_and_stops(tiny_run):
    port = _free_port()
    viewer = open_viewer(tiny_run, port)
    try:
        assert viewer.view.events is not None  # the run's dataset was found: overlay enabled
        with urllib.request.urlopen(viewer.url, timeout=30) as resp:
            assert resp.status == 200 and b"<html" in resp.read().lower()
    finally:
        viewer.stop()
    with socket.socket() as s:  # the port is released (TIME_WAIT allowed, as servers do)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))


def test_viewer_refuses_a_port_in_use_in_one_line(tiny_run, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["view", str(tiny_run), "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"--port {port}" in err and "pick another port" in err


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(url: str, out, wait_s: float) -> None:
    """Loads ``url`` in headless Chromium, waits ``wait_s`` of real time (the page connects
    by websocket and the server renders), then saves a PNG through the DevTools protocol
    (``--screenshot`` alone fires before the page's scripts have drawn)."""
    import base64
    import json
    import re

    from websockets.sync.client import connect

    proc = subprocess.Popen(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--window-size=1000,700",
            "--hide-scrollbars",
            "--remote-debugging-port=0",
            "about:blank",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        for line in proc.stderr:
            m = re.search(r"DevTools listening on ws://127.0.0.1:(\d+)/", line)
            if m:
                break
        with urllib.request.urlopen(f"http://127.0.0.1:{m.group(1)}/json", timeout=30) as r:
            page = next(t for t in json.load(r) if t["type"] == "page")
        with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
            ws.send(json.dumps({"id": 1, "method": "Page.navigate", "params": {"url": url}}))
            time.sleep(wait_s)
            ws.send(json.dumps({"id": 2, "method": "Page.captureScreenshot"}))
            while (msg := json.loads(ws.recv())).get("id") != 2:
                pass
        out.write_bytes(base64.b64decode(msg["result"]["data"]))
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.benchmark
@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_viewer_page_screenshot_in_headless_chromium_is_not_blank(tiny_run, tmp_path):
    from evsplat.data.images import read_png

    viewer = open_viewer(tiny_run, _free_port())
    shot = tmp_path / "viewer.png"
    try:
        screenshot(viewer.url, shot, wait_s=20.0)
    finally:
        viewer.stop()
    img = read_png(shot)[..., :3].astype(float)
    assert img.shape[1] == 1000
    # Not blank: the page is far from one flat colour, and most of it is the grey-ish render
    # and 3-D view rather than an empty white page.
    assert img.std() > 0.05
    assert (img.mean(-1) < 0.9).mean() > 0.5
