"""Outputs of a trained run: MP4 videos (decoded back with ffmpeg), the side-by-side event
video, PLY sequences, and the plots command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evsplat.cli import main
from evsplat.data.events import EventStream
from evsplat.data.images import read_png
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError
from evsplat.video import event_frame, read_mp4_frame, write_mp4


def tiny_run_dir(tmp_path_factory) -> Path:
    """A 2-iteration run on the tiny ball, trained once per session and shared by the output
    and viewer tests (training costs seconds per iteration)."""
    from evsplat.train import train

    root = tmp_path_factory.getbasetemp() / "shared_tiny_run"
    if not (root / "run" / "log.jsonl").is_file():
        root.mkdir(exist_ok=True)
        data = simulate_dataset("ball", root / "data", tiny=True, seed=0, progress=False)
        train(data, root / "run", preset_name="tiny", iterations=2, progress=False)
    return root / "run"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    return tiny_run_dir(tmp_path_factory)


def test_mp4_decodes_back_to_the_frames_written(tmp_path):
    # Smooth frames (H.264 is lossy on noise); odd size exercises the padding.
    yy, xx = np.mgrid[0:45, 0:61]
    frames = [
        np.stack([(xx + 5 * i) % 61 / 60, yy / 44, np.full_like(xx, i / 9.0, float)], -1)
        for i in range(10)
    ]
    n = write_mp4(tmp_path / "a.mp4", frames, fps=10, min_side=0)
    assert n == 10
    for i in (0, 9):
        got = read_mp4_frame(tmp_path / "a.mp4", i)
        assert got.shape == (46, 62, 3)
        want = (frames[i] * 255).round()
        assert np.abs(got[:45, :61].astype(float) - want).mean() < 6.0


def test_event_frame_colours_positive_red_and_negative_blue():
    ev = EventStream.from_arrays([1, 2, 2], [0, 1, 1], [0, 1, 2], [1, 0, 0], 4, 3)
    img = event_frame(ev, 0, 3)
    np.testing.assert_allclose(img[0, 1], [1.0, 2 / 3, 2 / 3])  # one positive event
    np.testing.assert_allclose(img[1, 2], [1 / 3, 1 / 3, 1.0])  # two negative events
    np.testing.assert_allclose(img[2, 3], [1.0, 1.0, 1.0])  # no events: white


def test_render_video_matches_the_png_frames_and_puts_events_beside(tiny_run, tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["render", str(tiny_run), "--times", "0:1:0.25", "--out", str(out), "--video"]) == 0
    frame = read_png(out / "frame_00002.png")
    rgb = frame if frame.ndim == 3 else np.repeat(frame[..., None], 3, -1)
    h, w = rgb.shape[:2]
    video = read_mp4_frame(out / "render.mp4", 2)
    s = video.shape[0] // h  # small sensors are enlarged by a whole factor
    assert s >= 1 and min(h, w) * s >= 240
    got = video[s // 2 :: s, s // 2 :: s][:h, :w].astype(float)
    assert np.abs(got - rgb.astype(float) * (255 if rgb.dtype.kind == "f" else 1)).mean() < 8.0
    panel = read_mp4_frame(out / "render_events.mp4", 2)[s // 2 :: s, s // 2 :: s]
    assert panel.shape[1] >= 3 * w
    events_panel = panel[:h, w : 2 * w].astype(float)
    assert (events_panel < 200).any(-1).mean() > 0.001  # some event pixels are coloured


def test_ply_sequence_holds_the_gaussians_at_each_time(tiny_run, tmp_path):
    plyfile = pytest.importorskip("plyfile")
    from evsplat.render import Renderer

    d = tmp_path / "plys"
    assert main(["export", str(tiny_run), "--times", "0:1:0.5", "--ply-dir", str(d)]) == 0
    renderer, _ = Renderer.from_run(tiny_run)
    times = np.loadtxt(d / "times.txt")
    assert times.shape == (3, 2)
    for i, t_us in times:
        v = plyfile.PlyData.read(d / f"ply_{int(i):05d}.ply")["vertex"]
        means = renderer.gaussians_at(t_us)[0].detach().numpy()
        np.testing.assert_allclose(np.stack([v["x"], v["y"], v["z"]], 1), means, atol=1e-6)


def test_plots_draw_losses_and_metrics_against_time(tiny_run, tmp_path, capsys):
    out = tmp_path / "plots"
    result = {
        "frames": [
            {"time_us": 1000 * k, "psnr": 20 + k, "ssim": 0.5, "lpips": None, "psnr_moving": None}
            for k in range(5)
        ]
    }
    (tiny_run / "eval.json").write_text(json.dumps(result))
    try:
        assert main(["plots", str(tiny_run), "--out", str(out)]) == 0
    finally:
        (tiny_run / "eval.json").unlink()
    for name in ("losses.png", "metrics_vs_time.png"):
        img = read_png(out / name).astype(float)
        assert img.std() > 0.02, name  # a drawn figure (values in [0, 1]), not a blank page


def test_bad_output_requests_fail_in_one_line(tiny_run, tmp_path, capsys):
    cases = [
        (["plots", str(tmp_path)], "log.jsonl: missing"),
        (["export", str(tiny_run), "--ply", "a.ply", "--ply-dir", str(tmp_path)], "give --ply"),
        (
            ["export", str(tiny_run), "--times", "0:2:0.5", "--ply-dir", str(tmp_path / "p")],
            "fractions of the sequence",
        ),
        (
            [
                "render",
                str(tiny_run),
                "--times",
                "0:1:0.5",
                "--out",
                str(tmp_path / "v"),
                "--video",
                "--fps",
                "0",
            ],
            "fps 0",
        ),
    ]
    for argv, match in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and match in err, (argv, err)
    with pytest.raises(EvsplatError, match="share one size"):
        write_mp4(tmp_path / "x.mp4", [np.zeros((4, 4, 3)), np.zeros((6, 4, 3))])
    assert not (tmp_path / "x.mp4").exists()
