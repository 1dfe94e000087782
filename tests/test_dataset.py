"""`simulate` writes a valid dataset folder; `check`/`load_dataset` catch broken ones;
bad inputs are one-line errors and leave nothing half-written."""

import hashlib
import json
import shutil

import numpy as np
import pytest

from evsplat.cli import main
from evsplat.data.dataset import check_dataset, load_dataset
from evsplat.data.event_files import read_events
from evsplat.data.images import read_exr, read_png
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError


@pytest.fixture(scope="module")
def tiny_ball(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "ball"
    simulate_dataset("ball", out, tiny=True, seed=0, progress=False)
    return out


def folder_hashes(path):
    return {
        p.relative_to(path).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.rglob("*"))
        if p.is_file()
    }


def test_simulated_tiny_dataset_loads_and_is_consistent(tiny_ball):
    assert check_dataset(tiny_ball) == []
    ds = load_dataset(tiny_ball)
    assert (ds.width, ds.height, ds.bayer) == (96, 96, "RGGB")
    events = read_events(tiny_ball / "events.h5")
    assert ds.events.count == len(events) > 10_000
    assert (ds.events.t_first_us, ds.events.t_last_us) == (events.t[0], events.t[-1])
    assert events.t.min() >= ds.t_start_us and events.t.max() <= ds.t_end_us
    # RGGB: events on all four Bayer positions
    assert len(set(zip((events.y % 2).tolist(), (events.x % 2).tolist()))) == 4
    # measured (100 Hz) spline vs dense ground truth: close but not identical between knots
    q = np.linspace(ds.t_start_us, ds.t_end_us, 301)
    err = np.abs(ds.trajectory.pose(q) - ds.gt_trajectory.pose(q)).max()
    assert err < 1e-4
    assert len(ds.test_frames) == 6
    for f in ds.test_frames:
        assert f.time_us % 10_000 == 5_000  # halfway between training poses
        assert read_png(f.rgb_path).shape == (96, 96, 3)
        assert read_exr(f.depth_path).shape == (96, 96)
        assert np.allclose(f.c2w, ds.gt_trajectory.pose(f.time_us), atol=1e-6)
    assert read_png(ds.test_frames[0].mask_path).max() == 1.0


def test_same_seed_gives_identical_files_and_other_seed_different_events(tiny_ball, tmp_path):
    simulate_dataset("ball", tmp_path / "again", tiny=True, seed=0, progress=False)
    simulate_dataset("ball", tmp_path / "other", tiny=True, seed=1, progress=False)
    h0, h1, h2 = (
        folder_hashes(tiny_ball),
        folder_hashes(tmp_path / "again"),
        folder_hashes(tmp_path / "other"),
    )
    assert h0 == h1
    assert h0["events.h5"] != h2["events.h5"]


def test_mono_and_speed_factor(tmp_path):
    out = simulate_dataset("clock", tmp_path / "c", tiny=True, color=False, speed=4, progress=False)
    meta = json.loads((out / "meta.json").read_text())
    full = json.loads((out / "meta.json").read_text())
    assert meta["bayer"] == "mono" and meta["speed"] == 4
    assert meta["rendered_frames"] == pytest.approx(0.6 * 96 / 400 * 1000 / 4, abs=2)
    assert full["num_events"] > 0
    assert read_png(out / "test" / "rgb_00000.png").ndim == 2


def test_pixels_integrate_their_area_and_meta_says_how(tmp_path):
    """Oracle: a 3x3-sample test image is the mean of nine one-ray renders whose principal
    point moved by the sub-pixel offsets; the one-ray dataset's images are those renders'
    middle. The aliased dataset makes more events: its edges crawl as a staircase."""
    from evsplat.scenes import get_scene

    one = simulate_dataset("ball", tmp_path / "one", tiny=True, samples=1, progress=False)
    three = simulate_dataset("ball", tmp_path / "three", tiny=True, progress=False)
    metas = [json.loads((d / "meta.json").read_text()) for d in (one, three)]
    assert [m["pixel_samples"] for m in metas] == [1, 3]
    assert metas[0]["num_events"] > metas[1]["num_events"]
    frame = json.loads((three / "test" / "frames.json").read_text())[2]
    scene = get_scene("ball", tiny=True, samples=1)
    k0 = scene.K.copy()
    want = np.zeros((scene.height, scene.width, 3))
    for oy in (1 / 6, 1 / 2, 5 / 6):
        for ox in (1 / 6, 1 / 2, 5 / 6):
            scene.K = k0 + np.array([[0, 0, 0.5 - ox], [0, 0, 0.5 - oy], [0, 0, 0]])
            scene.__post_init__()
            want += scene.render(frame["time_us"])[0] / 9
    got = read_png(three / "test" / frame["rgb"])
    assert np.abs(got - want).max() < 2e-4  # 16-bit PNG quantisation
    plain = read_png(one / "test" / frame["rgb"])
    assert np.abs(got - plain).max() > 0.1  # edges mix colours, one ray does not


def leftovers(parent):
    return sorted(p.name for p in parent.iterdir())


def test_bad_simulate_inputs_fail_in_one_line_and_write_nothing(tmp_path, capsys):
    for argv, match in [
        (["--scene", "cat"], "unknown scene 'cat'"),
        (["--scene", "ball", "--speed", "0"], "--speed 0"),
        (["--scene", "ball", "--size", "2x2"], "--size 2x2"),
        (["--scene", "ball", "--samples", "2"], "--samples 2"),
        (["--scene", "ball", "--samples", "11"], "--samples 11"),
        (["--scene", "ball", "--samples", "-1"], "--samples -1"),
    ]:
        assert (
            main(["simulate", *argv, "--tiny", "--no-progress", "--out", str(tmp_path / "o")]) == 2
        )
        err = capsys.readouterr().err
        assert match in err and err.count("\n") == 1
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("keep")
    assert main(["simulate", "--scene", "ball", "--tiny", "--out", str(tmp_path / "full")]) == 2
    assert "not empty" in capsys.readouterr().err
    assert leftovers(tmp_path) == ["full"]


def test_interrupted_simulation_leaves_nothing_half_written(tmp_path, monkeypatch):
    import evsplat.scenes as scenes

    calls = {"n": 0}
    real = scenes.Scene.render

    def render(self, t):
        calls["n"] += 1
        if calls["n"] == 20:
            raise KeyboardInterrupt
        return real(self, t)

    monkeypatch.setattr(scenes.Scene, "render", render)
    with pytest.raises(KeyboardInterrupt):
        simulate_dataset("ball", tmp_path / "out", tiny=True, progress=False)
    assert leftovers(tmp_path) == []


def break_copy(src, dst, edit):
    shutil.copytree(src, dst)
    edit(dst)
    return dst


def _set_json(name, **changes):
    def edit(d):
        doc = json.loads((d / name).read_text())
        doc.update(changes)
        (d / name).write_text(json.dumps(doc))

    return edit


def _edit_poses(d, fn):
    lines = (d / "poses.txt").read_text().splitlines()
    (d / "poses.txt").write_text("\n".join(fn(lines)) + "\n")


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: (d / "events.h5").unlink(), "events.h5: missing"),
        (_set_json("meta.json", width=97), "sensor size 97x96 differs from intrinsics.json"),
        (
            lambda d: (
                _set_json("meta.json", width=64)(d),
                _set_json("intrinsics.json", width=64)(d),
            ),
            "events.h5: sensor size 96x96 differs from meta.json 64x96",
        ),
        (
            lambda d: _edit_poses(d, lambda ls: [ls[0], ls[2], ls[1], *ls[3:]]),
            "not strictly increasing at index 1",
        ),
        (
            lambda d: _edit_poses(d, lambda ls: [ls[0], ls[1].rsplit(" ", 1)[0] + " nan", *ls[2:]]),
            "poses.txt:2: NaN",
        ),
        (lambda d: _edit_poses(d, lambda ls: ls[:-10]), "poses cover"),
        (_set_json("meta.json", bayer="XYZ"), "'bayer' must be one of"),
        (_set_json("intrinsics.json", distortion=[0.1, 0, 0, 0]), "'distortion' must be null or"),
        (lambda d: (d / "test" / "depth_00002.exr").unlink(), "depth_00002.exr: missing"),
        (lambda d: (d / "meta.json").write_text("{oops"), "meta.json: not valid JSON"),
    ],
    ids=[
        "missing_events",
        "meta_vs_intrinsics",
        "events_vs_meta",
        "non_monotonic_poses",
        "nan_quaternion",
        "poses_too_short",
        "bad_bayer",
        "distortion",
        "missing_test_file",
        "broken_json",
    ],
)
def test_check_reports_each_broken_dataset_in_one_line(tiny_ball, tmp_path, capsys, edit, match):
    d = break_copy(tiny_ball, tmp_path / "d", edit)
    problems = check_dataset(d)
    assert any(match in p for p in problems), problems
    assert all("\n" not in p for p in problems)
    with pytest.raises(EvsplatError, match="^.*$"):
        load_dataset(d)
    assert main(["check", str(d)]) == 2
    assert match in capsys.readouterr().err


def test_check_cli_accepts_a_good_folder_and_rejects_a_missing_one(tiny_ball, tmp_path, capsys):
    assert main(["check", str(tiny_ball)]) == 0
    assert main(["check", str(tmp_path / "nothing")]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_events_integrate_to_the_ground_truth_log_change(tiny_ball):
    # Σ C·p over the events between two ground-truth renders ≈ the change of each pixel's
    # Bayer-channel log intensity (thresholds vary per pixel by σ_C, hence a statistical check).
    from evsplat.data.simulator import LOG_EPS
    from evsplat.scenes import get_scene

    ds = load_dataset(tiny_ball)
    scene = get_scene("ball", tiny=True)
    ta, tb = 200_000, 230_000
    ev = ds.events.read(ta + 1, tb + 1)  # (ta, tb]: the events after the render at ta
    acc = np.zeros((ds.height, ds.width))
    np.add.at(acc, (ev.y, ev.x), np.where(ev.p > 0, ds.c_pos, -ds.c_neg))
    y, x = np.mgrid[0 : ds.height, 0 : ds.width]
    channel = np.array([[0, 1], [1, 2]])[y % 2, x % 2]  # RGGB
    la, lb = (np.log(scene.render(t)[0][y, x, channel] + LOG_EPS) for t in (ta, tb))
    err = np.abs(acc - (lb - la))
    changed = np.abs(lb - la) > 0.5
    assert changed.mean() > 0.05
    # The reference level carries up to one threshold from before ta: allow ±2C per pixel. A
    # pixel's own threshold is off by ~σ_C, which scales the count of a large change: a change
    # ΔL integrates to ΔL·C/C', off by up to ~2σ_C/C·|ΔL| at two standard deviations.
    c = max(ds.c_pos, ds.c_neg)
    c2 = 2 * c + 2 * ds.meta["sigma_c"] / c * np.abs(lb - la) + 0.1
    assert np.mean(err < c2) > 0.95 and np.mean(err[changed] < c2[changed]) > 0.8
    assert np.corrcoef(acc[changed], (lb - la)[changed])[0, 1] > 0.9
