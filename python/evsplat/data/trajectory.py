"""Continuous camera trajectory: a cumulative cubic B-spline on SE(3) fitted to timestamped poses.

The spline (Rust, f64) uses uniform knots. Uniformly sampled poses are interpolated exactly (the
curve passes through every sample); non-uniform input is first resampled geodesically at uniform
knots. Times are int64 microseconds; queries outside [t_min_us, t_max_us] are errors.
"""

from __future__ import annotations

import numpy as np

from evsplat import _core
from evsplat.errors import EvsplatError, core_call

# Tolerance on R^T R = I for input poses: looser than float32 round-off of a stored matrix.
ORTHONORMAL_TOL = 1e-5


def validate_poses(
    times_us: np.ndarray, c2w: np.ndarray, source: str
) -> tuple[np.ndarray, np.ndarray]:
    """Check shapes, finiteness, strictly increasing times and proper rotations; return copies
    as (int64[N], float64[N,4,4]). Raises EvsplatError naming `source` and the first bad index."""
    t = np.asarray(times_us)
    m = np.asarray(c2w, dtype=np.float64)
    if t.ndim != 1 or m.shape != (t.shape[0], 4, 4):
        raise EvsplatError(
            f"{source}: expected times [N] and poses [N,4,4], got {t.shape} and {m.shape}"
        )
    if not np.issubdtype(t.dtype, np.integer):
        if not np.all(np.isfinite(t)):
            raise EvsplatError(f"{source}: non-finite timestamp; timestamps are integer µs")
        t = np.round(t)
    t = t.astype(np.int64)
    if len(t) < 2:
        raise EvsplatError(f"{source}: need at least 2 poses to fit a trajectory, got {len(t)}")
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if len(bad):
        i = int(bad[0]) + 1
        raise EvsplatError(
            f"{source}: pose times not strictly increasing at index {i} "
            f"(t={t[i]} µs <= {t[i - 1]} µs); sort the poses and drop duplicates"
        )
    finite = np.all(np.isfinite(m.reshape(len(m), -1)), axis=1)
    if not finite.all():
        i = int(np.argmin(finite))
        raise EvsplatError(f"{source}: pose {i} (t={t[i]} µs) has NaN/inf values")
    r = m[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(r)
    bad = np.nonzero((err > ORTHONORMAL_TOL) | (det <= 0))[0]
    if len(bad):
        i = int(bad[0])
        raise EvsplatError(
            f"{source}: pose {i} (t={t[i]} µs) rotation is not orthonormal "
            f"(|R^T R - I| = {err[i]:.2e}, det = {det[i]:.3f}); store camera-to-world rigid poses"
        )
    if np.abs(m[:, 3, :] - [0, 0, 0, 1]).max() > 1e-9:
        raise EvsplatError(f"{source}: last row of every pose must be [0, 0, 0, 1]")
    return t, m


class Trajectory:
    """Camera-to-world pose as a smooth function of time (int64 µs)."""

    def __init__(self, spline: _core.SplineTrajectory, origin_us: int, source: str) -> None:
        self._spline = spline
        self._origin = int(origin_us)
        self.source = source
        # The last knot may sit a fraction of a µs before the last sample after resampling.
        self.t_min_us = self._origin
        self.t_max_us = self._origin + int(np.floor(spline.t_max + 1e-6))

    @classmethod
    def fit(
        cls,
        times_us: np.ndarray,
        c2w: np.ndarray,
        knot_interval_us: int | None = None,
        source: str = "<poses>",
    ) -> Trajectory:
        """Fit to poses `c2w` [N,4,4] at strictly increasing `times_us` [N] (int64 µs).

        Uniform samples without `knot_interval_us` are interpolated exactly; otherwise poses are
        resampled at knots `knot_interval_us` apart (default: the median sample spacing)."""
        t, m = validate_poses(times_us, c2w, source)
        if knot_interval_us is not None and not knot_interval_us > 0:
            raise EvsplatError(f"{source}: knot interval {knot_interval_us} µs must be positive")
        rel = (t - t[0]).astype(np.float64)
        knot = None if knot_interval_us is None else float(knot_interval_us)
        spline = core_call(source, _core.SplineTrajectory, rel, np.ascontiguousarray(m), knot)
        return cls(spline, int(t[0]), source)

    @property
    def knot_interval_us(self) -> float:
        return float(self._spline.knot_interval)

    def _relative(self, times_us: np.ndarray | float | int) -> tuple[np.ndarray, tuple[int, ...]]:
        t = np.asarray(times_us)
        if np.issubdtype(t.dtype, np.integer):
            rel = (t.astype(np.int64) - self._origin).astype(np.float64)
        else:
            rel = t.astype(np.float64) - float(self._origin)
        flat = np.ascontiguousarray(rel.reshape(-1))
        bad = ~((flat >= 0) & (flat <= self.t_max_us - self._origin))
        if bad.any():
            v = t.reshape(-1)[int(np.argmax(bad))]
            raise EvsplatError(
                f"{self.source}: time {v} µs is outside the trajectory's range "
                f"[{self.t_min_us}, {self.t_max_us}] µs; poses are not extrapolated"
            )
        # Within range by the check above; clamp the sub-µs slack of a resampled last knot.
        np.minimum(flat, self._spline.t_max, out=flat)
        return flat, t.shape

    def pose(self, times_us: np.ndarray | float | int) -> np.ndarray:
        """Camera-to-world poses float64[..., 4, 4] at `times_us` (int64 or float64 µs)."""
        flat, shape = self._relative(times_us)
        return self._spline.pose(flat).reshape(*shape, 4, 4)

    def velocity(self, times_us: np.ndarray | float | int) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame angular (rad/s) and linear (m/s) velocity, float64[..., 3] each:
        T^-1 dT/dt = [[ω^, v], [0, 0]], so v is the camera centre's velocity in camera axes."""
        flat, shape = self._relative(times_us)
        w, v = self._spline.velocity(flat)
        return w.reshape(*shape, 3), v.reshape(*shape, 3)
