"""Event streams: validated (x, y, t, p) arrays of one sensor, and the operations on windows of
them (ESI, counts, masks, Bayer split, patches, voxel grids). The loops run in Rust
(``evsplat._core``) on the numpy arrays without copying them; this module checks and names
the inputs and turns core errors into one-line ``EvsplatError``s.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, TypeVar, Union

import numpy as np

from evsplat import _core
from evsplat.errors import EvsplatError, core_call

#: A contrast threshold: one value for the sensor, or an (H, W) map with one value per pixel.
Contrast = Union[float, np.ndarray]

#: Largest sensor side: coordinates are uint16.
MAX_SIDE = 65536

R = TypeVar("R")


def _one_dim(values: object, name: str, source: str) -> np.ndarray:
    a = np.asarray(values)
    if a.ndim != 1:
        raise EvsplatError(
            f"{source}: {name} has shape {a.shape}; give a one-dimensional array, one value "
            "per event"
        )
    return a


def _as_int64(a: np.ndarray, name: str, source: str) -> np.ndarray:
    """Integers (any width) or whole-numbered floats as int64; anything lossy is an error."""
    if a.dtype.kind == "f":
        return core_call(source, _core.float_to_int64, np.ascontiguousarray(a, np.float64), name)
    if a.dtype.kind in "iub":
        if a.dtype == np.uint64 and a.size and int(a.max()) > np.iinfo(np.int64).max:
            i = int(np.argmax(a > np.iinfo(np.int64).max))
            raise EvsplatError(
                f"{source}: {name} out of range at index {i} ({name}={a[i]}); "
                "it does not fit a 64-bit integer"
            )
        return np.ascontiguousarray(a, np.int64)
    raise EvsplatError(
        f"{source}: {name} has dtype {a.dtype}; give integers or whole-numbered floats"
    )


def coords_uint16(values: object, axis: str, limit: int, source: str) -> np.ndarray:
    """Pixel coordinates as contiguous uint16, checked to lie in [0, limit) when they need a
    cast (uint8/uint16 input is checked later, by the stream validation, without a copy)."""
    a = _one_dim(values, axis, source)
    if a.dtype.kind == "u" and a.dtype.itemsize <= 2:
        return np.ascontiguousarray(a, np.uint16)
    return core_call(source, _core.coords_to_uint16, _as_int64(a, axis, source), axis, limit)


def _polarity_int8(values: object, source: str) -> np.ndarray:
    a = _one_dim(values, "p", source)
    if a.dtype == np.int8:
        return np.ascontiguousarray(a)
    return core_call(source, _core.polarity_from_int64, _as_int64(a, "p", source))


def _side(value: object, name: str, source: str) -> int:
    try:
        side = int(value)  # type: ignore[call-overload]
    except (TypeError, ValueError):
        side = -1
    if side != value or not 1 <= side <= MAX_SIDE:
        raise EvsplatError(
            f"{source}: sensor {name} {value!r} is invalid; give an integer 1..{MAX_SIDE}"
        )
    return side


@dataclass(frozen=True)
class EventStream:
    """Events of one sensor: x (column) and y (row) as uint16, t in integer microseconds
    (int64, sorted non-decreasing), p as int8 ±1. Build it with :meth:`from_arrays`, which
    validates; the plain constructor only checks dtypes (used for already-valid views).

    Index windows ``(i0, i1)`` are half-open event ranges, as returned by :meth:`window`.
    """

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray
    width: int
    height: int
    source: str = field(default="<arrays>", compare=False)

    def __post_init__(self) -> None:
        want = {"x": np.uint16, "y": np.uint16, "t": np.int64, "p": np.int8}
        for name, dtype in want.items():
            a = getattr(self, name)
            ok = isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == 1
            if not ok or not a.flags.c_contiguous:
                raise EvsplatError(
                    f"{self.source}: EventStream.{name} must be a contiguous 1-D "
                    f"{np.dtype(dtype)} array; "
                    "build streams with EventStream.from_arrays, which converts and validates"
                )

    @classmethod
    def from_arrays(
        cls,
        x: object,
        y: object,
        t: object,
        p: object,
        width: int,
        height: int,
        source: str = "<arrays>",
    ) -> EventStream:
        """Converts and validates: equal lengths, sorted t, 0 <= x < width, 0 <= y < height,
        polarity in {-1, +1} or {0, 1} (0 becomes -1). Casts only without loss (no NaN, no
        fractions). Any failure is an EvsplatError naming ``source``, the first bad index and
        its value. Inputs already in the canonical dtypes are used without copying."""
        width, height = _side(width, "width", source), _side(height, "height", source)
        xs = coords_uint16(x, "x", width, source)
        ys = coords_uint16(y, "y", height, source)
        ta = _one_dim(t, "t", source)
        ts = np.ascontiguousarray(ta) if ta.dtype == np.int64 else _as_int64(ta, "t", source)
        ps = _polarity_int8(p, source)
        stream = cls(xs, ys, ts, ps, width, height, source)
        mapped = core_call(source, _core.validate_events, stream)
        return stream if mapped is None else replace(stream, p=mapped)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def shape(self) -> tuple[int, int]:
        """Sensor shape (height, width), the shape of every per-pixel image."""
        return (self.height, self.width)

    def _call(self, fn: Callable[..., R], *args: object) -> R:
        return core_call(self.source, fn, *args)

    def _contrast(self, c: Contrast, name: str) -> float | np.ndarray:
        """A scalar as float, a map as a flat contiguous float32 array (checked to be H×W)."""
        if np.ndim(c) == 0:
            return float(c)
        a = np.asarray(c)
        if a.shape != self.shape:
            raise EvsplatError(
                f"{self.source}: {name} map has shape {a.shape}; give a scalar or an array of "
                f"the sensor shape {self.shape}"
            )
        return np.ascontiguousarray(a, np.float32).reshape(-1)

    def window(self, t0_us: int, t1_us: int) -> tuple[int, int]:
        """Index range of the events with t0 <= t < t1 (binary search; empty if t1 <= t0)."""
        return self._call(_core.window_by_time, self.t, int(t0_us), int(t1_us))

    def window_by_count(self, start: int, count: int) -> tuple[int, int]:
        """Index range of ``count`` events from index ``start``, clipped to the stream."""
        return self._call(_core.window_by_count, len(self), int(start), int(count))

    def split_equal_count(self, i0: int, i1: int, m: int) -> np.ndarray:
        """int64[m+1] boundaries splitting [i0, i1) into m sub-windows whose event counts
        differ by at most one."""
        return self._call(_core.split_equal_count, len(self), int(i0), int(i1), int(m))

    def _accumulate(
        self, i0: int, i1: int, c_pos: Contrast, c_neg: Contrast, want: list[str]
    ) -> list[np.ndarray]:
        """The images named in ``want`` ("esi", "count", "mask") from one counting pass."""
        return self._call(
            _core.accumulate,
            self,
            int(i0),
            int(i1),
            self._contrast(c_pos, "c_pos"),
            self._contrast(c_neg, "c_neg"),
            want,
        )

    def esi(self, i0: int, i1: int, c_pos: Contrast, c_neg: Contrast) -> np.ndarray:
        """Event single integral float32[H, W] of events [i0, i1): per pixel, C+ for each
        positive event minus C- for each negative one (C scalar or per-pixel map)."""
        return self._accumulate(i0, i1, c_pos, c_neg, ["esi"])[0]

    def esi_and_mask(
        self, i0: int, i1: int, c_pos: Contrast, c_neg: Contrast
    ) -> tuple[np.ndarray, np.ndarray]:
        """ESI and event mask of [i0, i1) from one pass over the events."""
        esi, mask = self._accumulate(i0, i1, c_pos, c_neg, ["esi", "mask"])
        return esi, mask

    def event_count(self, i0: int, i1: int) -> np.ndarray:
        """Events per pixel in [i0, i1), uint32[H, W]."""
        return self._accumulate(i0, i1, 0.0, 0.0, ["count"])[0]

    def event_mask(self, i0: int, i1: int) -> np.ndarray:
        """bool[H, W]: True where at least one event fired in [i0, i1)."""
        return self._call(_core.event_mask, self, int(i0), int(i1))

    def esi_by_channel(
        self, i0: int, i1: int, c_pos: Contrast, c_neg: Contrast, pattern: str
    ) -> np.ndarray:
        """ESI split by colour-filter channel, float32[C, H, W]: C = 3 (R, G, B) for the
        Bayer patterns RGGB/BGGR/GRBG/GBRG, where a pixel adds only to its own channel, and
        C = 1 for "mono"."""
        return self._call(
            _core.esi_by_channel,
            self,
            int(i0),
            int(i1),
            self._contrast(c_pos, "c_pos"),
            self._contrast(c_neg, "c_neg"),
            pattern,
        )

    def patches(
        self,
        centres: np.ndarray,
        bounds: np.ndarray,
        side: int,
        c_pos: Contrast,
        c_neg: Contrast,
        mode: str = "bilinear",
    ) -> tuple[np.ndarray, np.ndarray]:
        """ESI patches around ``centres`` for each sub-window of ``bounds``.

        centres: float32 (n, 2) pixel coordinates (x, y), the centre of pixel (i, j) being
        (j + 0.5, i + 0.5); or (n, m, 2) for centres that move between sub-windows.
        bounds: int64[m+1] event-index boundaries (see :meth:`split_equal_count`).
        Returns (float32[n, m, side, side], bool[n, m, side, side] valid). Sample (a, b) lies
        at centre + (b - (side-1)/2, a - (side-1)/2); its value is the sub-window's ESI there,
        bilinear between pixel centres (edge pixels repeat past the border) or nearest.
        Samples outside the sensor are 0 and not valid.
        """
        b = _one_dim(bounds, "bounds", self.source)
        b = np.ascontiguousarray(_as_int64(b, "bounds", self.source))
        m = len(b) - 1
        c = np.asarray(centres)
        if not (c.ndim == 2 and c.shape[1] == 2) and not (c.ndim == 3 and c.shape[1:] == (m, 2)):
            raise EvsplatError(
                f"{self.source}: centres have shape {c.shape}; give (n, 2) or (n, {m}, 2) pixel "
                "coordinates (x, y)"
            )
        values, valid = self._call(
            _core.patches,
            self,
            b,
            np.ascontiguousarray(c, np.float32).reshape(-1),
            c.ndim == 3,
            int(side),
            self._contrast(c_pos, "c_pos"),
            self._contrast(c_neg, "c_neg"),
            mode,
        )
        return values.reshape(len(c), m, int(side), int(side)), valid.reshape(
            len(c), m, int(side), int(side)
        )

    def voxel_grid(self, i0: int, i1: int, bins: int) -> np.ndarray:
        """float32[bins, H, W]: each event adds p·max(0, 1 − |tn − b|) to bin b, with
        tn = (bins − 1)(t − t_first)/(t_last − t_first) over the window (0 if all t equal).
        Time is made window-relative in integers first, so absolute offsets do not matter."""
        return self._call(_core.voxel_grid, self, int(i0), int(i1), int(bins))

    def slice(self, i0: int, i1: int) -> EventStream:
        """Events [i0, i1) as a new stream sharing this one's memory (no copy, no re-check)."""
        n = len(self)
        if not 0 <= i0 <= i1 <= n:
            raise EvsplatError(
                f"{self.source}: slice [{i0}, {i1}) is outside the stream of {n} events; "
                f"use 0 <= i0 <= i1 <= {n}"
            )
        s = slice(int(i0), int(i1))
        return EventStream(
            self.x[s], self.y[s], self.t[s], self.p[s], self.width, self.height, self.source
        )


def bayer_channel_map(pattern: str, width: int, height: int) -> np.ndarray:
    """uint8[H, W] channel index of every pixel (0=R, 1=G, 2=B) for a Bayer pattern
    (RGGB/BGGR/GRBG/GBRG, tile origin at pixel (0, 0)); zeros for "mono"."""
    return core_call("pattern", _core.bayer_channel_map, pattern, int(width), int(height))
