"""SE(3) cubic B-spline: exact on analytic motions, C2 smooth, velocities, range checks."""

import numpy as np
import pytest

from evsplat.data.trajectory import Trajectory
from evsplat.errors import EvsplatError


def hat(w, v):
    m = np.zeros((4, 4))
    m[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    m[:3, 3] = v
    return m


def expm(a):
    """Matrix exponential by scaling and squaring of a Taylor series (independent of Rust)."""
    k = max(0, int(np.ceil(np.log2(max(np.abs(a).max(), 1e-300)))) + 1)
    b = a / 2**k
    term, out = np.eye(4), np.eye(4)
    for i in range(1, 30):
        term = term @ b / i
        out = out + term
    for _ in range(k):
        out = out @ out
    return out


T0 = expm(hat([0.2, -0.4, 0.3], [1.0, -2.0, 0.5]))
W, V = np.array([0.9, -0.4, 1.3]), np.array([0.6, 1.2, -0.8])


def twist_motion(t_us):
    return T0 @ expm(hat(W, V) * (t_us * 1e-6))


def orbit(t_us, radius=2.5, omega=3.0):
    """Camera on a horizontal circle around (0, 0.3, 4) looking at its centre."""
    th = omega * t_us * 1e-6
    c, s = np.cos(th), np.sin(th)
    m = np.eye(4)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[:3, 3] = np.array([0, 0.3, 4.0]) + m[:3, :3] @ [0, 0, -radius]
    return m


@pytest.mark.parametrize("motion", [twist_motion, orbit], ids=["constant_twist", "circular_orbit"])
def test_spline_reproduces_analytic_trajectory_to_1e_9(motion):
    t = np.arange(0, 1_000_001, 10_000, dtype=np.int64) + 123_456
    traj = Trajectory.fit(t, np.stack([motion(x - t[0]) for x in t]))
    q = np.random.default_rng(0).uniform(t[0], t[-1], 500)
    got = traj.pose(q)
    want = np.stack([motion(x - t[0]) for x in q])
    assert np.abs(got - want).max() <= 1e-9


def test_non_uniform_samples_are_resampled_and_still_exact_for_constant_twist():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.integers(5_000, 15_000, 60)).astype(np.int64)
    traj = Trajectory.fit(t, np.stack([twist_motion(x) for x in t]))
    q = rng.uniform(t[0], t[-1], 200)
    assert np.abs(traj.pose(q) - np.stack([twist_motion(x) for x in q])).max() <= 1e-9
    assert traj.t_min_us == t[0] and traj.t_max_us == t[-1]


def random_trajectory(n=12, dt=10_000):
    rng = np.random.default_rng(2)
    t = np.arange(n, dtype=np.int64) * dt
    poses = [expm(hat(rng.normal(0, 0.3, 3), rng.normal(0, 0.5, 3))) for _ in range(n)]
    return t, np.stack(poses)


def test_spline_interpolates_the_samples_at_the_knots():
    t, m = random_trajectory()
    traj = Trajectory.fit(t, m)
    assert np.abs(traj.pose(t) - m).max() < 1e-9


def test_spline_is_c2_continuous_across_knots():
    t, m = random_trajectory()
    traj = Trajectory.fit(t, m)
    h = 20.0
    for k in t[2:-2]:
        left = traj.pose(np.array([k - 2 * h, k - h, k], dtype=float))
        right = traj.pose(np.array([k, k + h, k + 2 * h], dtype=float))
        d1_left, d1_right = (left[2] - left[1]) / h, (right[1] - right[0]) / h
        d2_left = (left[2] - 2 * left[1] + left[0]) / h**2
        d2_right = (right[2] - 2 * right[1] + right[0]) / h**2
        scale2 = np.abs(d2_left).max()
        # One-sided differences are O(h) accurate; a C1-only spline would jump by O(scale2).
        assert np.abs(d1_left - d1_right).max() < 3 * h * scale2 + 1e-12
        assert np.abs(d2_left - d2_right).max() < 0.05 * scale2


def test_body_velocity_matches_finite_differences():
    t, m = random_trajectory()
    traj = Trajectory.fit(t, m)
    q = np.linspace(t[0] + 1000, t[-1] - 1000, 37)
    w, v = traj.velocity(q)
    h = 0.5  # µs
    for i, x in enumerate(q):
        dT = (traj.pose(x + h) - traj.pose(x - h)) / (2 * h * 1e-6)
        xi = np.linalg.inv(traj.pose(x)) @ dT
        w_fd = np.array([xi[2, 1], xi[0, 2], xi[1, 0]])
        assert np.allclose(w[i], w_fd, rtol=1e-5, atol=1e-5)
        assert np.allclose(v[i], xi[:3, 3], rtol=1e-5, atol=1e-5)


def test_velocity_of_constant_twist_is_the_twist():
    t = np.arange(0, 500_001, 20_000, dtype=np.int64)
    traj = Trajectory.fit(t, np.stack([twist_motion(x) for x in t]))
    w, v = traj.velocity(np.array([12_345, 333_333]))
    assert np.allclose(w, W, atol=1e-9) and np.allclose(v, V, atol=1e-9)


def test_pose_accepts_scalars_int_and_float_arrays_of_any_shape():
    t, m = random_trajectory()
    traj = Trajectory.fit(t, m)
    assert traj.pose(5000).shape == (4, 4)
    assert traj.pose(np.zeros((2, 3), dtype=np.int64)).shape == (2, 3, 4, 4)
    assert np.allclose(traj.pose(5000), traj.pose(5000.0))
    w, v = traj.velocity(np.array([1000.0, 2000.0]))
    assert w.shape == v.shape == (2, 3)


def test_queries_outside_the_range_are_errors_not_extrapolation():
    t, m = random_trajectory()
    traj = Trajectory.fit(t, m)
    traj.pose(t[-1])
    with pytest.raises(EvsplatError, match="outside the trajectory's range"):
        traj.pose(t[-1] + 1)
    with pytest.raises(EvsplatError, match="outside"):
        traj.velocity(np.array([0, -5]))


def test_bad_pose_input_names_the_source_and_index():
    t, m = random_trajectory()
    t_bad = t.copy()
    t_bad[5] = t_bad[4]
    with pytest.raises(EvsplatError, match=r"cam\.txt: .*index 5"):
        Trajectory.fit(t_bad, m, source="cam.txt")
    m_bad = m.copy()
    m_bad[3, :3, :3] *= 1.1
    with pytest.raises(EvsplatError, match="pose 3 .*not orthonormal"):
        Trajectory.fit(t, m_bad)
    m_nan = m.copy()
    m_nan[7, 0, 3] = np.nan
    with pytest.raises(EvsplatError, match="pose 7 .*NaN"):
        Trajectory.fit(t, m_nan)
    with pytest.raises(EvsplatError, match="at least 2"):
        Trajectory.fit(t[:1], m[:1])
    with pytest.raises(EvsplatError, match="in microseconds"):
        Trajectory.fit(t, m, knot_interval_us=1e-6)


def test_huge_absolute_timestamps_lose_no_precision():
    origin = 2**40 + 17  # µs; float64 alone would still be exact here, float32 not at all
    t = origin + np.arange(0, 200_001, 10_000, dtype=np.int64)
    traj = Trajectory.fit(t, np.stack([twist_motion(x - origin) for x in t]))
    q = origin + np.array([1, 12_345, 199_999], dtype=np.int64)
    want = np.stack([twist_motion(x - origin) for x in q])
    assert np.abs(traj.pose(q) - want).max() <= 1e-9
