"""Lens undistortion against OpenCV as the oracle (cv2.undistortPoints and
cv2.fisheye.undistortPoints with tight criteria; cv2.projectPoints for the forward model),
the event rectification map, and distortion in intrinsics.json."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from evsplat.data.dataset import check_dataset, load_dataset
from evsplat.data.distortion import (
    LensDistortion,
    rectification_map,
    rectify_events,
    undistort_points,
)
from evsplat.data.event_files import read_events
from evsplat.data.events import EventStream
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError

cv2 = pytest.importorskip("cv2")

W, H = 640, 480
K = np.array([[420.0, 0.0, 322.5], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]])
RADTAN = [-0.28, 0.07, 1.2e-3, -8e-4, 0.01]
FISHEYE = [-0.013, 0.021, -0.006, 0.0012]
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)


def _grid(step: int = 20) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(0, W + 1, step, float), np.arange(0, H + 1, step, float))
    return np.stack([xs.ravel(), ys.ravel()], 1)


@pytest.mark.parametrize("coeffs", [RADTAN, RADTAN[:4]])
def test_radtan_undistortion_matches_opencv_on_a_grid(coeffs):
    pts = _grid()
    ours = undistort_points(LensDistortion("radtan", tuple(coeffs)), K, pts)
    ref = cv2.undistortPoints(
        pts.reshape(-1, 1, 2), K, np.array(coeffs), R=None, P=K, criteria=CRIT
    ).reshape(-1, 2)
    assert np.isfinite(ours).all()
    err = np.abs(ours - ref).max()
    assert err <= 1e-3, err
    # Forward check: OpenCV's projection of our ideal points lands on the distorted input.
    norm = np.c_[(ours - K[:2, 2]) / np.diag(K)[:2], np.ones(len(ours))]
    back, _ = cv2.projectPoints(norm, np.zeros(3), np.zeros(3), K, np.array(coeffs))
    assert np.abs(back.reshape(-1, 2) - pts).max() <= 1e-6


def test_fisheye_undistortion_matches_opencv_on_a_grid():
    pts = _grid()
    ours = undistort_points(LensDistortion("equidistant", tuple(FISHEYE)), K, pts)
    ref = cv2.fisheye.undistortPoints(
        pts.reshape(-1, 1, 2), K, np.array(FISHEYE), R=np.eye(3), P=K, criteria=CRIT
    ).reshape(-1, 2)
    assert np.isfinite(ours).all()
    err = np.abs(ours - ref).max()
    assert err <= 1e-3, err
    norm = np.c_[(ours - K[:2, 2]) / np.diag(K)[:2], np.ones(len(ours))][:, None, :]
    back, _ = cv2.fisheye.projectPoints(norm, np.zeros(3), np.zeros(3), K, np.array(FISHEYE))
    assert np.abs(back.reshape(-1, 2) - pts).max() <= 1e-6


def test_rectified_events_land_on_the_pixel_opencv_undistorts_their_centre_to():
    w, h = 64, 48
    k = np.array([[50.0, 0, 32.0], [0, 50.0, 24.0], [0, 0, 1]])
    dist = LensDistortion("radtan", (-0.3, 0.08, 0.0, 0.0))
    rng = np.random.default_rng(0)
    n = 5000
    ev = EventStream.from_arrays(
        rng.integers(0, w, n), rng.integers(0, h, n), np.arange(n), rng.integers(0, 2, n), w, h
    )
    centres = np.stack([ev.x + 0.5, ev.y + 0.5], 1).astype(np.float64)
    ref = cv2.undistortPoints(
        centres.reshape(-1, 1, 2), k, np.array(dist.coeffs), R=None, P=k, criteria=CRIT
    ).reshape(-1, 2)
    col, row = np.floor(ref[:, 0]), np.floor(ref[:, 1])
    keep = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = rectify_events(ev, dist, k)
    assert 0 < keep.sum() < n  # barrel distortion pushes the corners out
    np.testing.assert_array_equal(out.x, col[keep])
    np.testing.assert_array_equal(out.y, row[keep])
    np.testing.assert_array_equal(out.t, ev.t[keep])
    np.testing.assert_array_equal(out.p, ev.p[keep])
    m = rectification_map(dist, k, w, h)
    assert m.shape == (h, w, 2)


@pytest.fixture(scope="module")
def tiny_ball(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "ball"
    simulate_dataset("ball", out, tiny=True, seed=0, progress=False)
    return out


def _with_distortion(src, dst, value, raw: str | None = None):
    shutil.copytree(src, dst)
    path = dst / "intrinsics.json"
    doc = json.loads(path.read_text())
    doc["distortion"] = value
    path.write_text(raw if raw is not None else json.dumps(doc))
    return dst


def test_dataset_with_distortion_loads_undistorted_events(tiny_ball, tmp_path):
    plain = load_dataset(tiny_ball)
    dist = {"model": "equidistant", "coeffs": FISHEYE}
    data = load_dataset(_with_distortion(tiny_ball, tmp_path / "d", dist))
    assert data.distortion == LensDistortion("equidistant", tuple(FISHEYE))
    whole = read_events(tiny_ball / "events.h5")
    expected = rectify_events(whole, data.distortion, plain.K)
    # Rectified window by window as read: the windows of the whole rectified stream.
    for t0, t1 in [(whole.t[0], whole.t[-1] + 1), (100_000, 130_000), (599_000, 700_000)]:
        got = data.events.read(t0, t1)
        keep = (expected.t >= t0) & (expected.t < t1)
        np.testing.assert_array_equal(got.x, expected.x[keep])
        np.testing.assert_array_equal(got.y, expected.y[keep])
        np.testing.assert_array_equal(got.t, expected.t[keep])


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ({"model": "radtan", "coeffs": [0.1, float("nan"), 0, 0]}, "coefficient 1 is nan"),
        ({"model": "kannala", "coeffs": [0.1, 0, 0, 0]}, "model 'kannala' is unknown"),
        ({"model": "equidistant", "coeffs": [0.1, 0.2]}, "needs a list of 4 numbers"),
        ([0.1, 0.2, 0, 0], "must be null or"),
    ],
)
def test_bad_distortion_is_one_line_naming_intrinsics(tiny_ball, tmp_path, value, match):
    raw = None
    if (
        value
        and isinstance(value, dict)
        and any(isinstance(v, float) and np.isnan(v) for v in value["coeffs"])
    ):
        raw = (
            '{"K": %s, "width": %d, "height": %d, "distortion": {"model": "radtan", '
            '"coeffs": [0.1, NaN, 0, 0]}}'
        )
        k = json.loads((tiny_ball / "intrinsics.json").read_text())
        raw = raw % (json.dumps(k["K"]), k["width"], k["height"])
    folder = _with_distortion(tiny_ball, tmp_path / "bad", value, raw)
    problems = check_dataset(folder)
    assert len(problems) == 1 and match in problems[0] and "intrinsics.json" in problems[0]
    with pytest.raises(EvsplatError, match=match):
        load_dataset(folder)
