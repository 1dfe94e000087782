"""An object's image track lifted to a world path at the static model's depth, sampled on the
motion model's knots (docs/motion.md, step 5). Beyond its first and last sightings an object is
held where it was seen (a still object makes no events); one that came in or went out through
the image border is hidden there instead (``seed.span``).
"""

from __future__ import annotations

import numpy as np


def hold_path(times_us: np.ndarray, points: np.ndarray, query_us: np.ndarray) -> np.ndarray:
    """[Q,3] centres at ``query_us``: linear between the sightings ``points`` [F,3] at
    ``times_us`` [F], held beyond them (an object out of view is hidden by its span instead,
    ``ObjectMotion.visibility``)."""
    q = np.asarray(query_us, dtype=np.float64).reshape(-1)
    t = times_us.astype(np.float64)
    return np.stack([np.interp(q, t, points[:, k]) for k in range(3)], 1)


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
