"""Lens distortion in ``intrinsics.json`` and the undistortion of event coordinates.

``"distortion"`` is ``null`` (an ideal pinhole) or one of the two models people calibrate with
(Kalibr, OpenCV), coefficients in OpenCV order, acting on normalised coordinates (x/z, y/z)::

    {"model": "radtan",      "coeffs": [k1, k2, p1, p2]}   (or [k1, k2, p1, p2, k3])
    {"model": "equidistant", "coeffs": [k1, k2, k3, k4]}   (OpenCV's cv::fisheye)

The dataset loader undistorts events once: the rectification map (computed in Rust, Newton's
method per pixel) gives each sensor pixel's centre on the ideal pinhole image with the same K;
an event moves to the pixel containing that point, and events whose point leaves the image or
where the lens cannot be inverted are dropped. Training, rendering and evaluation then work on
that undistorted grid (test frames must be undistorted images too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evsplat import _core
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError, core_call

#: Coefficient counts per model.
MODELS = {"radtan": (4, 5), "equidistant": (4,)}


@dataclass(frozen=True)
class LensDistortion:
    """A lens model and its OpenCV-ordered coefficients."""

    model: str
    coeffs: tuple[float, ...]

    @classmethod
    def from_json(cls, doc: object, source: str) -> LensDistortion | None:
        """Parses the ``"distortion"`` value of ``source`` (None for null); one-line errors."""
        if doc is None:
            return None
        example = '{"model": "radtan", "coeffs": [k1, k2, p1, p2]}'
        if not isinstance(doc, dict) or set(doc) != {"model", "coeffs"}:
            raise EvsplatError(f"{source}: 'distortion' must be null or {example}, got {doc!r}")
        model, coeffs = doc["model"], doc["coeffs"]
        if model not in MODELS:
            raise EvsplatError(
                f"{source}: distortion model {model!r} is unknown; use 'radtan' (k1, k2, p1, p2"
                "[, k3]) or 'equidistant' (k1, k2, k3, k4)"
            )
        ok_type = isinstance(coeffs, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in coeffs
        )
        if not ok_type or len(coeffs) not in MODELS[model]:
            counts = " or ".join(map(str, MODELS[model]))
            raise EvsplatError(
                f"{source}: distortion model {model} needs a list of {counts} numbers, "
                f"got {coeffs!r}"
            )
        bad = [i for i, v in enumerate(coeffs) if not math.isfinite(v)]
        if bad:
            raise EvsplatError(
                f"{source}: distortion coefficient {bad[0]} is {coeffs[bad[0]]}; every "
                "coefficient must be a finite number (re-export the calibration)"
            )
        return cls(model, tuple(float(v) for v in coeffs))

    def to_json(self) -> dict:
        return {"model": self.model, "coeffs": list(self.coeffs)}


def _fxfycxcy(K: np.ndarray, source: str) -> list[float]:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or K[0, 1] != 0.0:
        raise EvsplatError(f"{source}: distortion needs a 3x3 K without skew (K[0][1] = 0)")
    return [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])]


def undistort_points(
    dist: LensDistortion, K: np.ndarray, points: np.ndarray, source: str = "<points>"
) -> np.ndarray:
    """Pixel points [N,2] (x, y) of the distorted image -> the ideal pinhole image with the
    same K; NaN rows where the lens cannot be inverted."""
    pts = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 2))
    return core_call(
        source, _core.undistort_points, dist.model, list(dist.coeffs), _fxfycxcy(K, source), pts
    )


def rectification_map(
    dist: LensDistortion, K: np.ndarray, width: int, height: int, source: str = "<camera>"
) -> np.ndarray:
    """[height, width, 2]: the undistorted position of each pixel centre (j + 0.5, i + 0.5)."""
    return core_call(
        source,
        _core.rectification_map,
        dist.model,
        list(dist.coeffs),
        _fxfycxcy(K, source),
        int(width),
        int(height),
    )


class Rectifier:
    """Moves events to the ideal pinhole grid of ``K``: each event goes to the undistorted pixel
    containing its pixel centre's undistorted point; events that leave the image or where the
    lens cannot be inverted are dropped. Order and timestamps are kept, so rectifying a window
    gives the window of the rectified stream. The pixel map is computed once."""

    def __init__(
        self, dist: LensDistortion, K: np.ndarray, width: int, height: int, source: str
    ) -> None:
        m = rectification_map(dist, K, width, height, source)
        # Pixel (row i, column j) covers [j, j+1) x [i, i+1) in K's coordinates.
        with np.errstate(invalid="ignore"):
            col = np.floor(m[..., 0])
            row = np.floor(m[..., 1])
            inside = (
                np.isfinite(col)
                & np.isfinite(row)
                & (col >= 0)
                & (col < width)
                & (row >= 0)
                & (row < height)
            )
        self.target = np.where(inside, row * width + col, -1).astype(np.int64).ravel()
        self.width, self.height, self.source = width, height, source

    def __call__(self, events: EventStream) -> EventStream:
        w = self.width
        dest = self.target[events.y.astype(np.int64) * w + events.x]
        keep = dest >= 0
        dest = dest[keep]
        return EventStream.from_arrays(
            (dest % w).astype(np.uint16),
            (dest // w).astype(np.uint16),
            events.t[keep],
            events.p[keep],
            w,
            self.height,
            self.source,
        )


def rectify_events(
    events: EventStream, dist: LensDistortion, K: np.ndarray, source: str | None = None
) -> EventStream:
    """``events`` on the ideal pinhole grid (see :class:`Rectifier`)."""
    source = source or events.source
    return Rectifier(dist, K, events.width, events.height, source)(events)
