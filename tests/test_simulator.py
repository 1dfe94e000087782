"""ESIM-style simulator against analytic cases: ramps, sums of C·p, Bayer channels, seeds."""

import json
import shutil

import numpy as np
import pytest

from evsplat.data.simulator import sensor_log_image, simulate_events
from evsplat.errors import EvsplatError


def test_linear_log_ramp_gives_floor_dl_over_c_events_at_predicted_times():
    # Each pixel ramps L(t) = L0 + a t; crossings at t_k = k C / a. Frames every 1 ms.
    c = 0.15
    slopes = np.array([[3.1, -2.2, 0.7], [10.3, -7.9, 0.05]])  # per second
    l0 = np.array([[0.0, -1.0, 0.3], [-2.0, 0.5, 0.0]])
    times = np.arange(0, 200_001, 1000, dtype=np.int64)
    frames = l0 + slopes * (times[:, None, None] * 1e-6)
    ev = simulate_events((times, frames.astype(np.float32)), c, c, sigma_c=0.0, bayer="mono")
    for (i, j), a in np.ndenumerate(slopes):
        sel = (ev.y == i) & (ev.x == j)
        # float32 frames: the crossing levels are exact only to ~1e-7 in L
        n = int(np.floor(abs(a) * 0.2 / c + 1e-6))
        assert sel.sum() == n, (i, j)
        want = np.arange(1, n + 1) * c / abs(a) * 1e6
        assert np.abs(ev.t[sel] - want).max(initial=0) <= 1.0 + 1e-9
        assert np.all(ev.p[sel] == np.sign(a))


def smooth_video(rng, n=60, h=12, w=10):
    """Random smooth log-intensity video: a sum of drifting low-frequency sinusoids."""
    y, x = np.mgrid[0:h, 0:w]
    t = np.arange(n)[:, None, None] / n
    out = np.zeros((n, h, w))
    for _ in range(4):
        kx, ky, om = rng.uniform(-0.6, 0.6, 3) * [1, 1, 20]
        out += rng.uniform(0.3, 1.0) * np.sin(kx * x + ky * y + om * t + rng.uniform(0, 6))
    return out.astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sum_of_c_times_p_tracks_the_log_change_within_one_threshold(seed):
    rng = np.random.default_rng(seed)
    video = smooth_video(rng)
    times = np.cumsum(rng.integers(200, 3000, len(video))).astype(np.int64)
    c_pos, c_neg = 0.17, 0.23
    ev = simulate_events((times, video), c_pos, c_neg, sigma_c=0.0, bayer="mono")
    acc = np.zeros(video.shape[1:])
    np.add.at(acc, (ev.y, ev.x), np.where(ev.p > 0, c_pos, -c_neg))
    err = acc - (video[-1] - video[0])
    assert np.abs(err).max() <= max(c_pos, c_neg) + 1e-6
    assert len(ev) > 100 and np.all(np.diff(ev.t) >= 0)


@pytest.mark.parametrize(
    ("channel", "pixels"), [(0, [(0, 0)]), (1, [(0, 1), (1, 0)]), (2, [(1, 1)])], ids="RGB"
)
def test_bayer_rggb_events_land_only_on_that_channels_pixels(channel, pixels):
    h, w = 6, 8
    times = np.arange(0, 11_000, 1000, dtype=np.int64)
    rgb = np.full((len(times), h, w, 3), 0.2, dtype=np.float32)
    rgb[:, :, :, channel] = np.linspace(0.2, 0.8, len(times))[:, None, None]
    ev = simulate_events(
        (times, sensor_log_image(rgb, "RGGB")), 0.2, 0.2, sigma_c=0.0, bayer="RGGB"
    )
    got = set(zip((ev.y % 2).tolist(), (ev.x % 2).tolist()))
    assert got == set(pixels)
    # every pixel of that channel fires floor(log(0.801/0.201)/0.2) times
    n = int(np.floor((np.log(0.8 + 1e-3) - np.log(0.2 + 1e-3)) / 0.2))
    assert len(ev) == n * h * w * len(pixels) // 4


def test_same_seed_gives_identical_events_and_another_seed_different_noise():
    rng = np.random.default_rng(5)
    video = smooth_video(rng)
    times = np.arange(len(video), dtype=np.int64) * 2000
    kw = dict(c_pos=0.2, c_neg=0.2, sigma_c=0.05, noise_rate_hz=20.0, hot_pixels=2, bayer="mono")
    a = simulate_events((times, video), seed=7, **kw)
    b = simulate_events((times, video), seed=7, **kw)
    c = simulate_events((times, video), seed=8, **kw)
    for f in ("x", "y", "t", "p"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert len(a) != len(c) or not np.array_equal(a.t, c.t)


def test_background_noise_rate_matches_the_requested_rate():
    times = np.arange(0, 1_000_001, 10_000, dtype=np.int64)
    flat = np.zeros((len(times), 20, 25), np.float32)
    ev = simulate_events((times, flat), noise_rate_hz=5.0, bayer="mono", seed=3)
    expected = 5.0 * 1.0 * 500
    assert abs(len(ev) - expected) < 4 * np.sqrt(expected)
    assert 0.4 < np.mean(ev.p > 0) < 0.6


def test_refractory_period_separates_events_of_a_pixel():
    times = np.arange(0, 10_001, 1000, dtype=np.int64)
    video = (np.linspace(0, 5, len(times))[:, None, None] * np.ones((1, 2, 2))).astype(np.float32)
    ev = simulate_events((times, video), 0.1, 0.1, sigma_c=0.0, refractory_us=500, bayer="mono")
    for px in range(4):
        sel = (ev.y * 2 + ev.x) == px
        assert np.all(np.diff(ev.t[sel]) >= 500)


def test_frames_from_an_iterator_equal_frames_from_arrays():
    rng = np.random.default_rng(9)
    video = smooth_video(rng, n=20)
    times = np.arange(20, dtype=np.int64) * 1500
    a = simulate_events((times, video), sigma_c=0.0, bayer="mono")
    b = simulate_events(iter(zip(times, video)), sigma_c=0.0, bayer="mono")
    assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x)


def test_bad_simulator_inputs_are_one_line_errors():
    times = np.array([0, 1000], dtype=np.int64)
    with pytest.raises(EvsplatError, match="bayer pattern 'RGBW'"):
        simulate_events((times, np.zeros((2, 4, 4, 3), np.float32)), bayer="RGBW")
    with pytest.raises(EvsplatError, match=r"needs \[H,W,3\]"):
        simulate_events((times, np.zeros((2, 4, 4), np.float32)), bayer="RGGB")
    with pytest.raises(EvsplatError, match="not after the previous"):
        simulate_events((np.array([0, 0]), np.zeros((2, 4, 4), np.float32)), bayer="mono")
    with pytest.raises(EvsplatError, match="non-finite"):
        simulate_events((times, np.full((2, 4, 4), np.nan, np.float32)), bayer="mono")
    with pytest.raises(EvsplatError, match="thresholds must be positive"):
        simulate_events((times, np.zeros((2, 4, 4), np.float32)), c_pos=0.0, bayer="mono")


# ----------------------------------------------------------------- tracked-object ground truth


@pytest.fixture(scope="module")
def tiny_ball_with_track(tmp_path_factory):
    from evsplat.data.simulator import simulate_dataset

    out = tmp_path_factory.mktemp("track") / "ball"
    return simulate_dataset("ball", out, tiny=True, seed=0, progress=False)


def ball_centre(t_s: float) -> np.ndarray:
    """The ball scene's ball centre, written out from its description (independent of Scene)."""
    radius, floor_y = 0.38, 1.0
    height = 1.1 * abs(np.sin(np.pi * 2.5 * t_s))
    return np.array([0.9 * np.sin(2 * np.pi * 0.6 * t_s), floor_y - radius - height, 3.0])


def test_test_frames_carry_the_ball_centre_which_projects_onto_its_mask(tiny_ball_with_track):
    from evsplat.data.images import read_exr, read_png

    root = tiny_ball_with_track
    intr = json.loads((root / "intrinsics.json").read_text())
    K = np.array(intr["K"])
    seen = 0
    for f in json.loads((root / "test" / "frames.json").read_text()):
        centre = np.array(f["object_centre"])
        np.testing.assert_allclose(centre, ball_centre(f["time_us"] * 1e-6), atol=1e-12)
        c2w = np.array(f["c2w"])
        cam = c2w[:3, :3].T @ (centre - c2w[:3, 3])
        u, v = (K @ cam)[:2] / cam[2]
        row, col = int(v), int(u)
        if not (0 <= row < intr["height"] and 0 <= col < intr["width"]):
            continue  # the zoomed-in tiny view loses the ball at some test times
        seen += 1
        assert read_png(root / "test" / f["mask"])[row, col] > 0.5
        # The ray through the centre's pixel hits the sphere's front, one radius nearer.
        depth = read_exr(root / "test" / f["depth"])[row, col]
        assert cam[2] - 0.38 - 0.02 < depth < cam[2] - 0.38 + 0.05
    assert seen >= 3


def test_track_json_samples_the_centre_at_1khz_over_the_sequence(tiny_ball_with_track):
    from evsplat.data.dataset import load_dataset

    data = load_dataset(tiny_ball_with_track)
    track = data.track
    assert track.radius == 0.38
    np.testing.assert_array_equal(track.times_us, np.arange(0, 600_001, 1000))
    want = np.stack([ball_centre(t * 1e-6) for t in track.times_us])
    np.testing.assert_allclose(track.centres, want, atol=1e-12)
    for f in data.test_frames:
        np.testing.assert_allclose(f.object_centre, ball_centre(f.time_us * 1e-6), atol=1e-12)


def test_a_dataset_from_before_per_object_ground_truth_is_one_object(
    tiny_ball_with_track, tmp_path
):
    from evsplat.data.dataset import load_dataset

    old = tmp_path / "v3"
    shutil.copytree(tiny_ball_with_track, old)
    frames = json.loads((old / "test" / "frames.json").read_text())
    for f in frames:
        del f["objects"]
    (old / "test" / "frames.json").write_text(json.dumps(frames))
    track = json.loads((old / "test" / "track.json").read_text())
    del track["objects"]
    (old / "test" / "track.json").write_text(json.dumps(track))
    data = load_dataset(old)
    assert [t.name for t in data.tracks] == ["object"] and data.tracks[0].radius == 0.38
    for f in data.test_frames:
        (obj,) = f.objects
        assert obj.name == "object" and obj.mask_path == f.mask_path
        np.testing.assert_array_equal(obj.centre, f.object_centre)


def test_a_static_scene_has_no_tracked_object(tmp_path):
    from evsplat.data.dataset import load_dataset
    from evsplat.data.simulator import simulate_dataset

    root = simulate_dataset("still", tmp_path / "still", tiny=True, progress=False)
    assert not (root / "test" / "track.json").exists()
    data = load_dataset(root)
    assert data.track is None and all(f.object_centre is None for f in data.test_frames)


def test_the_ducks_parts_are_one_object_bounded_by_its_farthest_part():
    from evsplat.scenes import get_scene

    scene = get_scene("duck", tiny=True)
    assert [o.name for o in scene.objects] == ["duck"] and len(scene.objects[0].parts) == 5
    body = scene.primitives[scene.objects[0].parts[0]]
    np.testing.assert_allclose(scene.object_centre(250_000), body.pose(0.25)[:3, 3])
    # The beak, 0.6 m right and 0.46 m up of the body's centre, a box of half extents
    # (0.14, 0.045, 0.09), reaches farthest (library.duck, written out).
    beak = np.hypot(0.6, 0.46) + np.linalg.norm([0.14, 0.045, 0.09])
    assert scene.object_radius() == pytest.approx(beak, rel=1e-9)
    assert scene.object_centre(0, 1) is None and scene.object_radius(1) is None


def test_datasets_without_tracking_load_and_a_broken_track_is_reported(
    tiny_ball_with_track, tmp_path
):
    from evsplat.data.dataset import check_dataset, load_dataset

    old = tmp_path / "old"
    shutil.copytree(tiny_ball_with_track, old)
    (old / "test" / "track.json").unlink()
    frames = json.loads((old / "test" / "frames.json").read_text())
    for f in frames:
        del f["object_centre"], f["objects"]
    (old / "test" / "frames.json").write_text(json.dumps(frames))
    data = load_dataset(old)
    assert data.track is None and data.test_frames[0].object_centre is None
    assert data.tracks == [] and data.test_frames[0].objects == []

    (old / "test" / "track.json").write_text('{"times_us": [0, 0], "centres": [[0, 0, 1]]}')
    frames[0]["object_centre"] = [0, "x", 1]
    (old / "test" / "frames.json").write_text(json.dumps(frames))
    problems = check_dataset(old)
    assert any("track.json: needs increasing" in p for p in problems)
    assert any("frame 0 object_centre must be [x, y, z]" in p for p in problems)
