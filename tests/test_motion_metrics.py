"""Tracking metrics against scenes whose answer is known by construction: Gaussians that move
exactly with the object (error 0, path ratio 1), the same with a minority of static Gaussians
left on the object (still 0), and a time-local 'smear' of static Gaussians, one cluster per test
time (error = the object's own displacement, ratio 0)."""

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from evsplat.motion_metrics import (
    OPACITY_MIN,
    TrackView,
    mean_pose,
    object_gaussians,
    object_set,
    track_object,
)

W = H = 96
F = 100.0
RADIUS = 0.3
WALL_Z = 5.0
TIMES = [0, 100_000, 200_000, 300_000, 400_000]


def centre(t_us: int) -> np.ndarray:
    s = t_us / 400_000
    return np.array([-0.6 + 1.2 * s, 0.2 * np.sin(3.0 * s), 3.0 + 0.3 * s])


def camera(t_us: int) -> np.ndarray:
    """Translating camera, fixed orientation (so the mean camera is the mean position)."""
    m = np.eye(4)
    m[:3, 3] = [0.1 * t_us / 400_000, -0.05 * t_us / 400_000, 0.0]
    return m


def pixel(point: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Pinhole projection written out: camera frame x = R^T (p - t), u = f x/z + c."""
    x, y, z = c2w[:3, :3].T @ (point - c2w[:3, 3])
    return np.array([F * x / z + W / 2, F * y / z + H / 2])


def view(t_us: int) -> TrackView:
    """Ground truth of a sphere of RADIUS at centre(t) before a wall at WALL_Z: mask is the disc
    of the sphere's projected radius, depth the sphere's front there and the wall elsewhere."""
    c2w = camera(t_us)
    g = centre(t_us)
    z = (c2w[:3, :3].T @ (g - c2w[:3, 3]))[2]
    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    u, v = pixel(g, c2w)
    mask = np.hypot(cols - u, rows - v) < F * RADIUS / z
    depth = np.where(mask, z - RADIUS, WALL_Z)
    return TrackView(t_us, c2w, mask, depth.astype(np.float32), g)


def front_cap(n: int, seed: int) -> np.ndarray:
    """Offsets on the sphere's camera-facing cap only (a surface-only set, biased towards the
    camera), away from the rim so every one projects inside the object's mask."""
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = -np.abs(d[:, 2]) - 1.0
    return RADIUS * d / np.linalg.norm(d, axis=1, keepdims=True)


def wall_points() -> np.ndarray:
    """Static background Gaussians on the wall, many of them seen through the object's mask."""
    xs, ys = np.meshgrid(np.linspace(-2, 2, 40), np.linspace(-2, 2, 40))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, WALL_Z)], axis=1)


def deeper(surface: np.ndarray, t: int) -> np.ndarray:
    """The object's ``surface`` offsets at time ``t``, pushed along their rays to 4.2 m deep."""
    eye = camera(t)[:3, 3]
    points = centre(t) + surface
    z = points[:, 2] - eye[2]  # the camera looks along +z, unrotated
    return eye + (points - eye) * (4.2 / z)[:, None]


class StubModel:
    """Opacity per Gaussian: a peak value and a table of time-local values at the test times."""

    def __init__(self, peak: np.ndarray, at_time: dict[float, np.ndarray]):
        self.peak, self.at_time = peak, at_time

    def opacities(self, t: float | None = None) -> torch.Tensor:
        return torch.from_numpy(self.peak if t is None else self.at_time[t])


@dataclass
class StubRenderer:
    """What tracking reads from a Renderer: K, deformed means, opacities, normalised time."""

    model: StubModel
    means_at: dict[int, np.ndarray]
    K: torch.Tensor = torch.tensor([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])

    def time(self, t_us: float) -> float:
        return t_us / 400_000

    def gaussians_at(self, t_us: float) -> tuple[torch.Tensor]:
        return (torch.from_numpy(self.means_at[t_us]),)

    def opacities(self, t_us: float) -> torch.Tensor:
        """As ``Renderer.opacities``: the model's at the time (no objects here)."""
        return self.model.opacities(self.time(t_us))


def tracked(renderer: StubRenderer, views: list[TrackView]) -> dict:
    """``track_object`` of the sets the eval chooses with the object's true radius."""
    return track_object(renderer, views, object_gaussians(renderer, views, RADIUS))


def test_gaussians_moving_with_the_object_track_it_exactly():
    surface = front_cap(200, seed=0)
    wall = wall_points()
    n_obj = len(surface)
    rng = np.random.default_rng(1)
    peak = np.concatenate([rng.uniform(0.3, 1.0, n_obj), np.full(len(wall), 0.9)])
    # Time-local opacities that change between times (but stay drawn): weighting by them
    # instead of the peak would move the set's centroid and show as an error.
    at_time = {t / 400_000: peak * rng.uniform(0.2, 1.0, peak.size) for t in TIMES}
    means = {t: np.concatenate([centre(t) + surface, wall]) for t in TIMES}
    result = tracked(StubRenderer(StubModel(peak, at_time), means), [view(t) for t in TIMES])

    assert [p["n"] for p in result["paths"]] == [n_obj] * len(TIMES)
    assert result["error_px_median"] < 1e-6 and result["error_px_mean"] < 1e-6
    assert all(p["error_px"] < 1e-6 for p in result["per_time"])
    assert result["path_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert result["dx_px"]["object"]["p50"] > 10.0
    assert result["dx_px"]["other"]["p99"] == pytest.approx(0.0, abs=1e-9)
    # The wall seen through the mask is too deep to be taken for the object.
    assert result["dx_px"]["other"]["n"] == len(wall)


def test_a_time_local_smear_of_static_gaussians_scores_the_objects_own_displacement():
    clusters = [centre(t) + front_cap(100, seed=k) for k, t in enumerate(TIMES)]
    wall = wall_points()
    points = np.concatenate([*clusters, wall])
    owner = np.concatenate([np.full(100, k) for k in range(len(TIMES))] + [np.full(len(wall), -1)])
    peak = np.full(len(points), 0.8)
    # Cluster k is drawn only around t_k (as time-local opacity does); the wall always.
    at_time = {
        t / 400_000: np.where((owner == k) | (owner < 0), 0.8, 0.5 * OPACITY_MIN)
        for k, t in enumerate(TIMES)
    }
    means = {t: points for t in TIMES}
    views = [view(t) for t in TIMES]
    result = tracked(StubRenderer(StubModel(peak, at_time), means), views)

    # Reference k follows cluster k, which stays at g(t_k): the error at t_j is how far the
    # object moved, in frame j's pixels.
    err = np.full((len(TIMES), len(TIMES)), np.nan)
    for k, tk in enumerate(TIMES):
        for j, tj in enumerate(TIMES):
            if j != k:
                err[k, j] = np.linalg.norm(
                    pixel(centre(tk), camera(tj)) - pixel(centre(tj), camera(tj))
                )
    assert [p["n"] for p in result["paths"]] == [100] * len(TIMES)
    for j, p in enumerate(result["per_time"]):
        assert p["error_px"] == pytest.approx(np.nanmedian(err[:, j]), rel=1e-9)
    assert result["error_px_median"] == pytest.approx(np.nanmedian(err), rel=1e-9)
    assert result["error_px_mean"] == pytest.approx(np.nanmean(err), rel=1e-9)
    assert result["path_ratio"] == 0.0
    # The true path through the test times, seen from the mean camera (mean position here).
    mean_cam = np.mean([camera(t) for t in TIMES], axis=0)
    gt_px = np.array([pixel(centre(t), mean_cam) for t in TIMES])
    assert result["gt_path_px"] == pytest.approx(
        np.linalg.norm(np.diff(gt_px, axis=0), axis=1).sum()
    )
    assert result["dx_px"]["object"]["p99"] == pytest.approx(0.0, abs=1e-9)


def test_a_minority_of_static_gaussians_left_on_the_object_does_not_drag_its_centre():
    # 40 Gaussians move rigidly with the object (one tight spot on its front); 30 static ones
    # stay where the object was at the first test time, with 3/7 of the set's weight there.
    spot = np.array([0.0, 0.0, -0.2])
    strays = centre(TIMES[0]) + front_cap(30, seed=3)
    means = {t: np.concatenate([np.tile(centre(t) + spot, (40, 1)), strays]) for t in TIMES}
    peak = np.full(70, 0.6)
    at_time = {t / 400_000: peak for t in TIMES}
    result = tracked(StubRenderer(StubModel(peak, at_time), means), [view(t) for t in TIMES])
    # The weighted median of each coordinate is the spot's as long as it holds over half the
    # weight, so the error is 0 exactly; the mean would sit 3/7 of the way back to the start.
    assert result["paths"][0]["n"] == 70
    assert result["error_px_median"] < 1e-6 and result["error_px_mean"] < 1e-6
    assert result["path_ratio"] == pytest.approx(1.0, abs=1e-9)
    last = means[TIMES[-1]]
    dragged = last.mean(0) - (means[TIMES[0]].mean(0) - centre(TIMES[0]))
    offset = pixel(dragged, camera(TIMES[-1])) - pixel(centre(TIMES[-1]), camera(TIMES[-1]))
    assert np.linalg.norm(offset) > 10.0


def test_a_set_the_model_draws_from_the_wrong_depth_is_the_objects():
    """Gaussians on the object's pixels at every time but 4.2 m deep (the object at 3.0-3.3,
    the wall at 5): one camera cannot see a moving object's depth, and a model may misjudge it.
    Against the GT depth alone they are not the object's; where the model's rendered depth says
    it draws them there, they are, and the wall seen through the mask still is not. Their world
    path is 1.4 times the object's, and the following metrics, which carry their 3-D offset from
    the object over, say so (path ratio 1.4)."""
    surface, wall = front_cap(100, seed=4), wall_points()
    means = {t: np.concatenate([deeper(surface, t), wall]) for t in TIMES}
    peak = np.full(len(surface) + len(wall), 0.8)
    renderer = StubRenderer(StubModel(peak, {t / 400_000: peak for t in TIMES}), means)
    views = [view(t) for t in TIMES]
    alone = tracked(renderer, views)
    assert [p["n"] for p in alone["paths"]] == [0] * len(TIMES)
    for v in views:
        v.drawn_depth = np.where(v.mask, 4.2, WALL_Z).astype(np.float32)
    drawn = tracked(renderer, views)
    assert [p["n"] for p in drawn["paths"]] == [len(surface)] * len(TIMES)
    assert 1.3 < drawn["path_ratio"] < 1.5
    assert drawn["dx_px"]["other"]["n"] == len(wall)


def test_the_wall_seen_where_the_object_is_not_drawn_is_not_the_objects():
    """The object drawn 4.2 m deep as above, but not at the first test time: there the model's
    drawn depth is the wall's, and the wall's Gaussians seen through the mask pass its test.
    They hold still and are drawn off the object at the other times: the background it passed,
    in no set (before, the region's union took them as the object at every time). Gaussians
    left at the object's own depth still count (the tests above and tests/test_eval.py)."""
    surface, wall = front_cap(100, seed=4), wall_points()
    means = {t: np.concatenate([deeper(surface, t), wall]) for t in TIMES}
    peak = np.full(len(surface) + len(wall), 0.8)
    hidden = np.where(np.arange(len(peak)) < len(surface), 0.5 * OPACITY_MIN, 0.8)
    at_time = {t / 400_000: peak if t != TIMES[0] else hidden for t in TIMES}
    views = [view(t) for t in TIMES]
    for v in views:
        v.drawn_depth = np.where(v.mask, 4.2, WALL_Z).astype(np.float32)
    views[0].drawn_depth = np.full_like(views[0].drawn_depth, WALL_Z)
    seen = object_set(means[TIMES[0]], hidden, views[0], np.asarray(StubRenderer.K), RADIUS)[0]
    assert seen.sum() > 30  # the wall through the mask, which the first test admits
    result = tracked(StubRenderer(StubModel(peak, at_time), means), views)
    assert [p["n"] for p in result["paths"]] == [0] + [len(surface)] * (len(TIMES) - 1)
    assert result["dx_px"]["object"]["n"] == len(surface)
    assert result["dx_px"]["other"]["n"] == len(wall)


def test_a_reference_without_the_object_in_view_takes_no_part():
    surface = front_cap(50, seed=2)
    means = {t: centre(t) + surface for t in TIMES}
    peak = np.full(len(surface), 0.5)
    at_time = {t / 400_000: peak for t in TIMES}
    views = [view(t) for t in TIMES]
    views[0].mask[:] = False  # the object is out of the picture at the first test time
    result = tracked(StubRenderer(StubModel(peak, at_time), means), views)
    assert result["paths"][0] == {"reference_us": 0, "n": 0, "centres": None}
    assert result["error_px_median"] < 1e-6 and result["per_time"][0]["error_px"] < 1e-6


def test_mean_pose_is_the_mean_position_and_the_rotation_halfway():
    def yaw(angle: float, x: float) -> np.ndarray:
        c, s = np.cos(angle), np.sin(angle)
        m = np.eye(4)
        m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        m[:3, 3] = [x, 0, 0]
        return m

    np.testing.assert_allclose(
        mean_pose([yaw(0.3, 1.0), yaw(-0.3, 3.0)]), yaw(0.0, 2.0), atol=1e-12
    )
    np.testing.assert_allclose(mean_pose([yaw(0.1, 0.0), yaw(0.5, 0.0)]), yaw(0.3, 0.0), atol=1e-12)


def test_a_spinning_object_is_tracked_by_its_rigid_motion():
    """Gaussians on the camera-facing cap of a sphere that moves with the object and turns
    about its centre by 1.5 rad over the test times: the rigid error is 0; the set's median
    (which assumes translation) drifts with the turn."""
    cap = front_cap(200, seed=4)
    peak = np.random.default_rng(5).uniform(0.3, 1.0, len(cap))

    def turned(t_us: int) -> np.ndarray:
        a = 1.5 * t_us / 400_000
        c, s = np.cos(a), np.sin(a)
        return cap @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]).T

    means = {t: centre(t) + turned(t) for t in TIMES}
    at_time = {t / 400_000: peak for t in TIMES}
    views = [view(t) for t in TIMES]
    result = tracked(StubRenderer(StubModel(peak, at_time), means), views)
    assert result["paths"][0]["n"] > 100  # the reference at t = 0 sees the cap
    assert result["rigid_error_px_median"] < 1e-6
    assert result["error_px_median"] > 3.0
