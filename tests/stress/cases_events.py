"""Stress cases of the event core and the camera trajectory (SE(3) B-spline)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from tests.stress.harness import Arrays, Case

# ---- event operations ----------------------------------------------------------------------------


def _event_arrays(rng: np.random.Generator, kind: str) -> tuple[dict, float, float]:
    """Random events of one edge-case ``kind``: (arrays for EventStream.from_arrays, C+, C-)."""
    w, h = int(rng.integers(1, 48)), int(rng.integers(1, 48))
    n = int(rng.integers(0, 3000))
    offset = 0
    c_pos, c_neg = float(np.exp(rng.uniform(np.log(1e-4), np.log(10)))), 0.0
    c_neg = float(np.exp(rng.uniform(np.log(1e-4), np.log(10))))
    if kind == "flood":  # every event in one pixel
        n = int(rng.integers(1, 50_000))
        x = np.full(n, rng.integers(0, w))
        y = np.full(n, rng.integers(0, h))
    else:
        x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    if kind == "offset_2^40":
        offset = 1 << 40
    if kind == "single":
        n = 1
        x, y = x[:1] if len(x) else np.zeros(1, int), y[:1] if len(y) else np.zeros(1, int)
    if kind == "empty":
        n = 0
        x, y = x[:0], y[:0]
    if kind == "contrast_extreme":
        c_pos, c_neg = (float(v) for v in rng.choice([1e-4, 10.0, 1.0], 2))
    if kind == "same_time":  # a burst: every event at one timestamp
        t = np.full(n, offset + int(rng.integers(0, 1 << 20)), np.int64)
    else:
        t = offset + np.sort(rng.integers(0, 1 << 20, n)).astype(np.int64)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return dict(x=x, y=y, t=t, p=p, width=w, height=h), c_pos, c_neg


def _event_ops(arrays: dict, c_pos: float, c_neg: float, rng: np.random.Generator) -> Arrays:
    """Every event operation on one stream, with numpy oracles for counts and ESI."""
    from evsplat.data.events import EventStream

    ev = EventStream.from_arrays(**arrays, source="<stress>")
    n = len(ev)
    i0 = int(rng.integers(0, n + 1))
    i1 = int(rng.integers(i0, n + 1))
    esi, mask = ev.esi_and_mask(i0, i1, c_pos, c_neg)
    count = ev.event_count(i0, i1)
    ref = np.zeros(ev.shape, np.float64)
    c = np.where(ev.p[i0:i1] > 0, c_pos, -c_neg)
    np.add.at(ref, (ev.y[i0:i1].astype(int), ev.x[i0:i1].astype(int)), c)
    assert int(count.sum()) == i1 - i0, "event count lost events"
    assert np.array_equal(mask, count > 0), "mask differs from count > 0"
    tol = 1e-5 * (np.abs(c).sum() + 1.0)
    assert np.abs(esi - ref).max(initial=0.0) <= tol, "ESI differs from the numpy reference"
    t_lo, t_hi = (int(ev.t[0]), int(ev.t[-1]) + 1) if n else (0, 1)
    a, b = ev.window(t_lo, t_hi)
    assert (a, b) == (0, n), "time window over the whole stream misses events"
    m = int(rng.integers(1, 6))
    bounds = ev.split_equal_count(i0, i1, m)
    assert bounds[0] == i0 and bounds[-1] == i1 and np.all(np.diff(bounds) >= 0)
    centres = rng.uniform(-5, max(ev.width, ev.height) + 5, (3, 2)).astype(np.float32)
    patches, _ = ev.patches(centres, bounds, int(rng.integers(1, 6)), c_pos, c_neg)
    vox = ev.voxel_grid(i0, i1, int(rng.integers(1, 6)))
    by_channel = ev.esi_by_channel(i0, i1, c_pos, c_neg, "RGGB")
    assert abs(float(by_channel.sum()) - float(esi.sum())) <= tol, "Bayer split lost events"
    return [esi, patches, vox, by_channel]


def event_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Event core: floods, 2^40 µs offsets, empty/single windows, extreme contrasts, bursts;
    plus invalid streams (unsorted, outside the sensor, NaN times, NaN contrast)."""
    from evsplat.data.events import EventStream

    kinds = ["flood", "offset_2^40", "empty", "single", "contrast_extreme", "same_time", "random"]
    bad = ["unsorted", "outside", "nan_time", "nan_contrast"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 8 == 7:
            kind = bad[(i // 8) % len(bad)]
            arrays, c_pos, c_neg = _event_arrays(r, "random")
            arrays["x"], arrays["y"] = np.append(arrays["x"], 0), np.append(arrays["y"], 0)
            arrays["p"], arrays["t"] = np.append(arrays["p"], 1), np.append(arrays["t"], 1 << 21)
            if kind == "unsorted":
                arrays["t"][-1] = -1
            elif kind == "outside":
                arrays["x"][-1] = arrays["width"]
            elif kind == "nan_time":
                arrays["t"] = arrays["t"].astype(np.float64)
                arrays["t"][-1] = np.nan

            def run(arrays=arrays, kind=kind, c_pos=c_pos) -> Arrays:
                ev = EventStream.from_arrays(**arrays, source="<stress>")
                if kind == "nan_contrast":
                    return [ev.esi(0, len(ev), c_pos, float("nan"))]
                return []

            yield Case("events", kind, run, expect="error")
            continue
        kind = kinds[i % len(kinds)]
        arrays, c_pos, c_neg = _event_arrays(r, kind)
        yield Case(
            "events", kind, lambda a=arrays, cp=c_pos, cn=c_neg, r=r: _event_ops(a, cp, cn, r)
        )


# ---- camera trajectory (SE(3) B-spline) ----------------------------------------------------------


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _spline_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.data.trajectory import Trajectory

    n = int(r.integers(2, 12))
    step = int(r.integers(1, 100_000))
    t = np.arange(n, dtype=np.int64) * step
    if kind == "long_gap":  # a gap of up to 10^3 sample spacings: resampled to uniform knots
        t[n // 2 :] += step * int(r.integers(10, 1000))
    if kind == "offset_2^40":
        t += 1 << 40
    c2w = np.tile(np.eye(4), (n, 1, 1))
    axis = r.normal(size=3)
    if kind == "near_identical":
        omega = float(r.uniform(1e-12, 1e-7))  # rad per sample
    elif kind == "rot_180":  # consecutive poses half a turn apart (antipodal quaternions)
        omega = math.pi - float(r.choice([0.0, 1e-9, 1e-6]))
    else:
        omega = float(r.uniform(-1.0, 1.0))
    for i in range(n):
        c2w[i, :3, :3] = _rot(axis, i * omega)
    # A smooth path (constant velocity plus small jitter) at a random scale.
    scale = float(r.choice([1e-6, 1.0, 1e3]))
    velocity = r.normal(size=3)
    c2w[:, :3, 3] = scale * (np.arange(n)[:, None] * velocity + 0.1 * r.normal(size=(n, 3)))
    knot = None if kind != "knot" else int(r.integers(1, 4 * step))
    traj = Trajectory.fit(t, c2w, knot_interval_us=knot, source="<stress>")
    q = np.sort(r.integers(traj.t_min_us, traj.t_max_us + 1, 16))
    poses = traj.pose(q)
    w, v = traj.velocity(q)
    rot = poses[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max()
    assert err < 1e-6, f"spline rotation not orthonormal (|R^T R - I| = {err:.1e})"
    return [poses, w, v]


def _bad_spline(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.data.trajectory import Trajectory

    n = int(r.integers(3, 8))
    t = np.arange(n, dtype=np.int64) * 1000
    c2w = np.tile(np.eye(4), (n, 1, 1))
    j = int(r.integers(1, n))
    if kind == "repeated_time":
        t[j] = t[j - 1]
    elif kind == "nan_pose":
        c2w[j, int(r.integers(0, 3)), int(r.integers(0, 4))] = float(r.choice([np.nan, np.inf]))
    elif kind == "not_a_rotation":
        c2w[j, :3, :3] *= 2.0
    elif kind == "one_pose":
        t, c2w = t[:1], c2w[:1]
    Trajectory.fit(t, c2w, source="<stress>")
    return []


def spline_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """B-spline: near-identical and 180° rotations, long gaps, 2^40 µs times, explicit knots;
    repeated timestamps, NaN poses, non-rotations and single poses must be refused."""
    kinds = ["near_identical", "rot_180", "long_gap", "offset_2^40", "knot", "random"]
    bad = ["repeated_time", "nan_pose", "not_a_rotation", "one_pose"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 5 == 4:
            kind = bad[(i // 5) % len(bad)]
            yield Case("spline", kind, lambda r=r, k=kind: _bad_spline(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            expect = "either" if kind == "rot_180" else "finite"
            yield Case("spline", kind, lambda r=r, k=kind: _spline_case(r, k), expect=expect)
