"""An object's image track lifted to a world path, sampled on the motion model's knots.

Its depth is the static model's: after the warm-up the model draws a mover as a smear partly in
front of what it passes, and a near quantile of the rendered depth in the object's regions reads
its front surface (a median of the regions' depth lay up to 1.1 m behind the tiny ball and put it
behind the wall: docs/experiments/motion.md). The path's ends: an object first seen touching the
image border came in from outside, so before its first sighting it goes on at its first velocity
(out of view); likewise after its last sighting for one that leaves through the border. Any
other object is held where it was first or last seen (it was there, still: a still object makes
no events).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EDGE_SIGHTINGS = 3  # sightings whose mean velocity carries an object beyond its ends


@dataclass
class WorldPath:
    """One object's path: world centres at its sighting times, and whether it comes in and
    goes out through the image border."""

    times_us: np.ndarray  # [F] int64, sorted
    points: np.ndarray  # [F,3]
    enters: bool
    leaves: bool

    def at(self, t_us: np.ndarray) -> np.ndarray:
        """[T,3] centres at ``t_us``: linear between sightings, beyond them as the class says."""
        t = np.asarray(t_us, dtype=np.float64).reshape(-1)
        ts = self.times_us.astype(np.float64)
        out = np.stack([np.interp(t, ts, self.points[:, k]) for k in range(3)], 1)
        if len(ts) < 2:
            return out
        if self.enters:
            v = _velocity(ts[:EDGE_SIGHTINGS], self.points[:EDGE_SIGHTINGS])
            before = t < ts[0]
            out[before] = self.points[0] + np.outer(t[before] - ts[0], v)
        if self.leaves:
            v = _velocity(ts[-EDGE_SIGHTINGS:], self.points[-EDGE_SIGHTINGS:])
            after = t > ts[-1]
            out[after] = self.points[-1] + np.outer(t[after] - ts[-1], v)
        return out


def _velocity(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Least-squares velocity [3] (per µs) of points ``p`` [F,3] at times ``t`` [F]."""
    dt = t - t.mean()
    return (dt[:, None] * (p - p.mean(0))).sum(0) / max(float((dt * dt).sum()), 1e-12)


def lift(uv: np.ndarray, depth: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """World points [T,3] at camera ``depth`` [T] (z) along the rays of pixels ``uv`` [T,2]
    seen from ``c2w`` [T,4,4] (or one [4,4] for all)."""
    rays = np.stack(
        [(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))], 1
    )
    cam = rays * np.asarray(depth, dtype=np.float64).reshape(-1, 1)
    c2w = np.broadcast_to(c2w, (len(uv), 4, 4))
    return np.einsum("tij,tj->ti", c2w[:, :3, :3], cam) + c2w[:, :3, 3]


def turn_angles(
    times_us: np.ndarray, rates: np.ndarray, query_us: np.ndarray, t_ref_us: int
) -> np.ndarray:
    """In-plane turn angles [Q] (rad) from ``t_ref_us`` to ``query_us``, integrating the turn
    ``rates`` [F] (rad/s) measured at ``times_us`` [F]: linear between them, held beyond."""
    grid = np.union1d(np.asarray(query_us, dtype=np.float64), [float(t_ref_us)])
    rate = np.interp(grid, times_us.astype(np.float64), rates)
    steps = np.concatenate([[0.0], 0.5 * (rate[1:] + rate[:-1]) * np.diff(grid) * 1e-6])
    angle = np.cumsum(steps)
    angle -= angle[np.searchsorted(grid, float(t_ref_us))]
    return np.interp(np.asarray(query_us, dtype=np.float64), grid, angle)


def near_path(points: np.ndarray, path: np.ndarray, radius: float) -> np.ndarray:
    """Bool [N]: ``points`` [N,3] within ``radius`` of the polyline through ``path`` [T,3]
    (a single point when T = 1): the volume an object sweeps."""
    ends = np.concatenate([path[:1], path])
    a, b = ends[:-1], ends[1:]  # the first segment is the first point alone
    seg = b - a
    rel = points[:, None, :] - a[None]
    u = np.clip((rel * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-12), 0.0, 1.0)
    closest = a[None] + u[..., None] * seg[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=-1).min(axis=1) <= radius
