"""The millisecond index of an event file, DSEC's ``ms_to_idx``, and its cached copy.

Convention (the same as DSEC's): with ``origin`` the index's time origin in µs,
``ms_to_idx[k]`` is the index of the first event with ``t >= origin + 1000 k`` (the number of
events when there is none), for ``k = 0 .. (t_last - origin) // 1000``: one entry per
millisecond up to and including the one holding the last event. The events of any
millisecond ``k`` are ``[ms_to_idx[k], ms_to_idx[k + 1])``, the last one's run to the end.

In a file written by :mod:`evsplat.data.event_writer` the index is the root dataset
``ms_to_idx`` and its origin is ``t_offset`` (``events/t`` is stored relative to it, as in
DSEC). A file without one gets it built once by a streaming pass and cached beside it, in
``.<name>.ms_to_idx.npz`` (see :func:`sidecar_path`); the user's file is never rewritten.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evsplat.data.atomic import write_atomic
from evsplat.errors import EvsplatError

#: µs per index entry.
MS = 1000
#: Bumped when the cached index's layout changes; older caches are rebuilt.
SIDECAR_VERSION = 1


def index_origin(t_first_us: int) -> int:
    """The origin for a file whose first event is at ``t_first_us``: that millisecond's start
    (so index entries fall on whole milliseconds of the recording's clock)."""
    return (int(t_first_us) // MS) * MS


class IndexBuilder:
    """Builds ``ms_to_idx`` from sorted timestamps given chunk by chunk (bounded memory: the
    index itself, 8 bytes per millisecond, is all it keeps)."""

    def __init__(self, origin_us: int):
        self.origin = int(origin_us)
        self.count = 0
        self._parts: list[np.ndarray] = []
        self._next_ms = 0  # entries before this one are final

    def add(self, t_us: np.ndarray) -> None:
        """Appends the next events' timestamps (int64 µs, sorted, not before earlier chunks)."""
        if len(t_us) == 0:
            return
        last_ms = (int(t_us[-1]) - self.origin) // MS
        if last_ms >= self._next_ms:
            # Every millisecond started by this chunk's last event has its first event here.
            starts = self.origin + MS * np.arange(self._next_ms, last_ms + 1, dtype=np.int64)
            self._parts.append(self.count + np.searchsorted(t_us, starts, side="left"))
            self._next_ms = last_ms + 1
        self.count += len(t_us)

    def result(self) -> np.ndarray:
        """The index (int64), one entry per millisecond from the origin to the last event's."""
        return np.concatenate(self._parts) if self._parts else np.zeros(0, np.int64)


def check_index(
    ms_to_idx: np.ndarray, origin: int, count: int, t_last_us: int | None, source: str
) -> None:
    """Structure of an index against the file's event count and last timestamp, without
    reading the events: non-decreasing, inside [0, count], one entry per millisecond up to the
    last event's. Consistency with every timestamp is :func:`first_disagreement`'s job."""
    fix = "run `evsplat check` on it, then re-convert the file (or delete a cached index)"
    if ms_to_idx.ndim != 1:
        raise EvsplatError(f"{source}: ms_to_idx has shape {ms_to_idx.shape}; expected 1-D; {fix}")
    want = 0 if t_last_us is None else max(0, (t_last_us - origin) // MS + 1)
    if len(ms_to_idx) != want:
        raise EvsplatError(
            f"{source}: ms_to_idx has {len(ms_to_idx)} entries but the events span {want} ms "
            f"from its origin {origin} µs; {fix}"
        )
    if len(ms_to_idx) == 0:
        return
    bad = np.flatnonzero(np.diff(ms_to_idx) < 0)
    if len(bad):
        k = int(bad[0]) + 1
        raise EvsplatError(
            f"{source}: ms_to_idx decreases at ms {k} ({ms_to_idx[k]} < {ms_to_idx[k - 1]}); {fix}"
        )
    if ms_to_idx[0] < 0 or ms_to_idx[-1] > count:
        k = 0 if ms_to_idx[0] < 0 else len(ms_to_idx) - 1
        raise EvsplatError(
            f"{source}: ms_to_idx[{k}] = {ms_to_idx[k]} is outside the file's {count} events; {fix}"
        )


def first_disagreement(expected: np.ndarray, stored: np.ndarray) -> str | None:
    """Where a stored index differs from the one the timestamps give, as words; None if equal."""
    if len(expected) != len(stored):
        return f"{len(stored)} entries, the timestamps need {len(expected)}"
    diff = np.flatnonzero(expected != stored)
    if len(diff) == 0:
        return None
    k = int(diff[0])
    return (
        f"ms_to_idx[{k}] = {stored[k]} but the first event of that millisecond is {expected[k]} "
        f"({len(diff)} entries disagree)"
    )


def sidecar_path(path: str | os.PathLike) -> Path:
    """Where the index of a file without one is cached: ``.<name>.ms_to_idx.npz`` beside it."""
    path = Path(path)
    return path.with_name(f".{path.name}.ms_to_idx.npz")


def _identity(path: Path) -> np.ndarray:
    """Size and modification time: a cache made for another version of the file is stale."""
    st = path.stat()
    return np.array([st.st_size, st.st_mtime_ns], np.int64)


def load_sidecar(path: str | os.PathLike) -> tuple[int, np.ndarray, tuple[int, int]] | None:
    """The cached (origin, ms_to_idx, (largest x + 1, largest y + 1)) of ``path``; None when
    absent, unreadable or stale."""
    path = Path(path)
    cache = sidecar_path(path)
    try:
        with np.load(cache, allow_pickle=False) as z:
            fresh = int(z["version"]) == SIDECAR_VERSION and np.array_equal(
                z["identity"], _identity(path)
            )
            if not fresh:
                return None
            extent = (int(z["extent"][0]), int(z["extent"][1]))
            return int(z["origin"]), z["ms_to_idx"].astype(np.int64), extent
    except (OSError, ValueError, KeyError):
        return None


def save_sidecar(
    path: str | os.PathLike, origin: int, ms_to_idx: np.ndarray, extent: tuple[int, int]
) -> Path | None:
    """Caches the index of ``path`` and the extent of its coordinates (the sensor size of a
    file that names none) atomically; None (nothing cached) when the folder is not writable:
    the index then lives for this process only."""
    path = Path(path)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(
                f,
                version=np.int64(SIDECAR_VERSION),
                identity=_identity(path),
                origin=np.int64(origin),
                ms_to_idx=ms_to_idx,
                extent=np.array(extent, np.int64),
            )

    try:
        return write_atomic(sidecar_path(path), write)
    except EvsplatError:
        return None
