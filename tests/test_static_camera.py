"""A static camera needs no pose file: `convert --static-camera` writes the folder's metadata,
the dataset's trajectory is the identity over its time range, and such a dataset trains (with
held-out windows that no read of training touches) and is scored without test frames."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from evsplat.cli import main
from evsplat.config import preset
from evsplat.data.dataset import check_dataset, load_dataset
from evsplat.data.event_files import read_events
from evsplat.data.event_store import EventStore
from evsplat.eval import evaluate_run
from evsplat.run_state import RunState
from evsplat.train import train
from evsplat.train.heldout import heldout_intervals


@pytest.fixture(scope="module")
def static_still(tiny_scene, tmp_path_factory) -> Path:
    """The tiny `still` scene's events as a static-camera folder: events, intrinsics and
    meta.json with "camera": "static"; no poses, no test frames."""
    src, root = tiny_scene("still"), tmp_path_factory.mktemp("static") / "still"
    root.mkdir()
    for name in ("events.h5", "intrinsics.json"):
        shutil.copy(src / name, root / name)
    meta = json.loads((src / "meta.json").read_text()) | {"camera": "static"}
    (root / "meta.json").write_text(json.dumps(meta))
    return root


def test_static_camera_dataset_has_the_identity_pose_over_its_time_range(static_still):
    assert check_dataset(static_still) == []
    data = load_dataset(static_still)
    times = np.linspace(data.t_start_us, data.t_end_us, 11)
    np.testing.assert_allclose(data.trajectory.pose(times), np.broadcast_to(np.eye(4), (11, 4, 4)))


def test_static_camera_with_poses_or_another_camera_value_is_refused(static_still, tmp_path):
    both = tmp_path / "both"
    shutil.copytree(static_still, both)
    (both / "poses.txt").write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
    assert any("static" in p and "poses.txt" in p for p in check_dataset(both))
    odd = tmp_path / "odd"
    shutil.copytree(static_still, odd)
    meta = json.loads((odd / "meta.json").read_text()) | {"camera": "moving"}
    (odd / "meta.json").write_text(json.dumps(meta))
    problems = check_dataset(odd)
    assert any("'camera'" in p for p in problems)
    assert any("poses.txt: missing" in p and '"camera": "static"' in p for p in problems)


def test_convert_static_camera_writes_a_dataset_that_check_accepts(
    tiny_scene, tmp_path, capsys
) -> None:
    src = tiny_scene("still") / "events.h5"
    out = tmp_path / "data" / "events.h5"
    out.parent.mkdir()
    argv = ["convert", str(src), str(out), "--static-camera", "--fx", "80", "--cy", "40"]
    assert main(argv + ["--contrast", "0.25"]) == 0
    intr = json.loads((out.parent / "intrinsics.json").read_text())
    np.testing.assert_array_equal(intr["K"], [[80, 0, 48], [0, 80, 40], [0, 0, 1]])
    meta = json.loads((out.parent / "meta.json").read_text())
    t = read_events(src).t  # the events' own span
    assert (meta["t_start_us"], meta["t_end_us"]) == (int(t[0]), int(t[-1]))
    assert (meta["camera"], meta["c_pos"], meta["c_neg"]) == ("static", 0.25, 0.25)
    assert meta["bayer"] == "mono"
    capsys.readouterr()
    assert main(["check", str(out.parent)]) == 0
    assert "static camera" in capsys.readouterr().out
    # No focal length: guessed, and said so on stderr.
    again = tmp_path / "guess" / "events.h5"
    again.parent.mkdir()
    assert main(["convert", str(src), str(again), "--static-camera"]) == 0
    assert "GUESSED" in capsys.readouterr().err
    assert json.loads((again.parent / "intrinsics.json").read_text())["K"][0][0] > 0


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--fx", "-3"], "--fx"),
        (["--bayer", "XYZW"], "--bayer"),
        (["--contrast", "0"], "--contrast"),
    ],
)
def test_convert_static_camera_refuses_bad_values_before_writing(
    tiny_scene, tmp_path, capsys, extra, words
) -> None:
    out = tmp_path / "events.h5"
    argv = ["convert", str(tiny_scene("still") / "events.h5"), str(out), "--static-camera"]
    assert main(argv + extra) != 0
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_static_camera_output_must_be_named_events_h5(tiny_scene, tmp_path, capsys) -> None:
    src = tiny_scene("still") / "events.h5"
    assert main(["convert", str(src), str(tmp_path / "x.h5"), "--static-camera"]) != 0
    assert "DIR/events.h5" in capsys.readouterr().err


@pytest.fixture(scope="module")
def heldout_run(static_still, tmp_path_factory):
    """A short run on the static-camera folder with 4 held-out windows, every event it read
    recorded (``EventStore._stream`` is where every read of events' contents goes)."""
    cfg = preset("tiny")
    cfg.num_gaussians = 300
    cfg.schedule.iterations = 40  # warm-up to 4: the mover's seeding, L_ef and L_m after it
    cfg.schedule.checkpoint_every = 1000
    cfg.skips.early_stop_every = 8  # the early stop's windows are read too
    cfg.skips.static_start_fraction = 0.5  # and the static-scene evidence's
    cfg.holdout.windows, cfg.holdout.length = 4, 0.05
    read_times: list[np.ndarray] = []
    original = EventStore._stream

    def recording(self, i0, i1):
        ev = original(self, i0, i1)
        read_times.append(np.asarray(ev.t).copy())
        return ev

    run = tmp_path_factory.mktemp("runs") / "heldout"
    mp = pytest.MonkeyPatch()
    mp.setattr(EventStore, "_stream", recording)
    try:
        stats = train(static_still, run, config=cfg, progress=False)
    finally:
        mp.undo()
    return run, cfg, stats, np.concatenate(read_times)


def test_training_never_reads_an_event_of_the_held_out_windows(heldout_run, static_still):
    run, cfg, stats, times = heldout_run
    data = load_dataset(static_still)
    intervals = heldout_intervals(data.t_start_us, data.t_end_us, cfg.holdout, cfg.seed)
    assert len(intervals) == 4 and stats.skipped_nonfinite == 0
    assert stats.iterations == 40 and stats.skipped_empty < 40
    assert len(times) > 10_000  # training did read events
    for a, b in intervals:
        assert b - a == int(0.05 * (data.t_end_us - data.t_start_us))
        inside = (times >= a) & (times < b)
        assert not inside.any(), f"{inside.sum()} events of held-out [{a}, {b}) were read"
        # The windows hold events, so a read there would have shown.
        assert data.events.window(a, b)[1] > data.events.window(a, b)[0]
    assert RunState.load(run).heldout == intervals


def test_a_run_without_test_frames_is_scored_on_its_held_out_windows(heldout_run, static_still):
    run, cfg, _, _ = heldout_run
    result = evaluate_run(run, static_still, run / "eval")
    assert "frames" not in result
    events = result["event_prediction"]
    assert events["windows_source"].startswith("held out")
    assert [(w["t0_us"], w["t1_us"]) for w in events["windows"]] == RunState.load(run).heldout
    for w in events["windows"]:
        assert w["flat"]["correlation"] == 0.0
        assert -1.0 <= w["model"]["correlation"] <= 1.0
    assert json.loads((run / "eval" / "eval.json").read_text()) == result
    assert "corr model" in (run / "eval" / "eval.md").read_text()
