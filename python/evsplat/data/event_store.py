"""Time-window access to an HDF5 event file: the events of [t0, t1) read through the file's
millisecond index (:mod:`evsplat.data.event_index`), so a read costs what its window holds,
wherever it lies in the file, and memory stays bounded whatever the file's size.

Timestamps are integer µs on the recording's clock (``t_offset`` added back), as everywhere
in evsplat; a consumer subtracts a local origin before going to floating point.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from evsplat import _core
from evsplat.data.event_files import (
    READ_CHUNK,
    h5_events_group,
    h5_read_error,
    h5_sensor_size,
    h5_t_offset,
)
from evsplat.data.event_index import (
    MS,
    IndexBuilder,
    check_index,
    first_disagreement,
    index_origin,
    load_sidecar,
    save_sidecar,
    sidecar_path,
)
from evsplat.data.events import MAX_SIDE, EventStream
from evsplat.errors import EvsplatError, core_call

#: HDF5 chunk cache per column: a few decompressed chunks stay warm between nearby windows,
#: and a small file is read from disk once (4 columns: 64 MiB at most).
CHUNK_CACHE = 16 << 20


@dataclass
class Scan:
    """What one streaming pass over every event found (each chunk validated on the way)."""

    count: int
    origin: int  # of ms_to_idx
    ms_to_idx: np.ndarray
    max_x: int
    max_y: int


def _scan(group: h5py.Group, src: str, t_offset: int, size: dict, origin: int | None) -> Scan:
    """Validates every event in chunks of READ_CHUNK (sorted t across chunks too, coordinates
    inside the sensor when its size is known) and builds the index from the timestamps; an
    ``origin`` of None starts the index at the first event's millisecond."""
    n = len(group["t"])
    index, max_x, max_y = None, -1, -1
    w, h = size.get("width", MAX_SIDE), size.get("height", MAX_SIDE)
    last_t = None
    for s in range(0, n, READ_CHUNK):
        cut = slice(s, min(s + READ_CHUNK, n))
        where = src if s == 0 else f"{src} (events from index {s})"
        x, y, t, p = (group[k][cut] for k in "xytp")
        ev = EventStream.from_arrays(x, y, _absolute(t, t_offset, where), p, w, h, where)
        if last_t is not None and ev.t[0] < last_t:
            raise EvsplatError(
                f"{src}: timestamps not sorted at index {s} (t={ev.t[0]} < {last_t}); sort them"
            )
        index = index or IndexBuilder(index_origin(ev.t[0]) if origin is None else origin)
        index.add(ev.t)
        max_x, max_y = max(max_x, int(ev.x.max())), max(max_y, int(ev.y.max()))
        last_t = int(ev.t[-1])
    if index is None:
        return Scan(0, 0 if origin is None else origin, np.zeros(0, np.int64), -1, -1)
    return Scan(n, index.origin, index.result(), max_x, max_y)


def _absolute(t: np.ndarray, t_offset: int, src: str) -> np.ndarray:
    """Stored timestamps (any integer type, relative to t_offset) as int64 µs on the clock.
    Takes ownership of ``t`` (a fresh read): int64 input is shifted in place, no copy."""
    if t.dtype.kind not in "iu":
        raise EvsplatError(
            f"{src}: events/t holds {t.dtype} values; windowed reads need integer µs: convert "
            "the file with `evsplat convert IN OUT.h5`"
        )
    t = t.astype(np.int64, copy=False)
    t += t_offset
    return t


def _recorded(
    f: h5py.File, source: str, first: int | None, last: int | None
) -> tuple[int, int] | None:
    """The file's ``recorded_us`` attribute as (start, end) µs, None without one; an error
    where it is not two ordered integers holding every event."""
    if "recorded_us" not in f.attrs:
        return None
    span = np.asarray(f.attrs["recorded_us"])
    fix = "re-convert the file, or delete the attribute"
    if span.shape != (2,) or not np.issubdtype(span.dtype, np.integer) or span[0] > span[1]:
        raise EvsplatError(f"{source}: recorded_us {span.tolist()} is not [start, end] µs; {fix}")
    start, end = int(span[0]), int(span[1])
    if first is not None and last is not None and not start <= first <= last <= end:
        raise EvsplatError(
            f"{source}: recorded_us [{start}, {end}] does not hold the events at "
            f"[{first}, {last}] µs; {fix}"
        )
    return start, end


class EventStore:
    """An open HDF5 event file, read by time window. Use :func:`open_store`.

    Attributes: ``path``, ``count`` (events), ``t_first_us``/``t_last_us`` (None when empty),
    ``recorded_us`` (the [start, end] µs the file says the sensor recorded, None when it does
    not say), ``width``/``height``, ``provenance`` (the file's provenance attributes, empty
    when none) and ``index_source`` (where the index came from, in words)."""

    def __init__(
        self,
        f: h5py.File,
        path: Path,
        size: tuple[int, int],
        index: tuple[int, np.ndarray],
        index_source: str,
        transform: Callable[[EventStream], EventStream] | None,
    ):
        self._file = f
        self.path = path
        self.source = str(path)
        group = h5_events_group(f, self.source)
        self._columns = tuple(group[k] for k in "xytp")
        self._t_offset = h5_t_offset(f)
        self.width, self.height = size
        self.origin, self.ms_to_idx = index
        self.index_source = index_source
        self._transform = transform
        self.count = len(self._columns[2])
        # Events the file gave (their timestamps read), in all and in the largest single slice:
        # what a read cost and what memory held (the large-file tests' oracle).
        self.events_read = self.largest_read = 0
        ends = self._t(0, 1), self._t(self.count - 1, self.count)
        self.t_first_us = int(ends[0][0]) if self.count else None
        self.t_last_us = int(ends[1][0]) if self.count else None
        prov = f.get("provenance")
        self.provenance = dict(prov.attrs) if isinstance(prov, h5py.Group) else {}
        check_index(self.ms_to_idx, self.origin, self.count, self.t_last_us, self.source)
        self.recorded_us = _recorded(f, self.source, self.t_first_us, self.t_last_us)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> EventStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _t(self, i0: int, i1: int) -> np.ndarray:
        """Timestamps of events [i0, i1); every read goes through here, so it counts them."""
        t = self._columns[2][max(i0, 0) : i1]
        self.events_read += len(t)
        self.largest_read = max(self.largest_read, len(t))
        return _absolute(t, self._t_offset, self.source)

    @property
    def transforms(self) -> bool:
        """Whether reads apply a transform (which may move and drop events)."""
        return self._transform is not None

    def events(self, i0: int, i1: int) -> EventStream:
        """Events [i0, i1) by index as a validated stream (transformed, if the store does)."""
        return self._stream(int(i0), int(i1))

    def _stream(self, i0: int, i1: int) -> EventStream:
        """Events [i0, i1) as a validated stream, with the store's transform applied."""
        x, y, p = (self._columns[k][i0:i1] for k in (0, 1, 3))
        t = self._t(i0, i1)
        ev = EventStream.from_arrays(x, y, t, p, self.width, self.height, self.source)
        return self._transform(ev) if self._transform else ev

    def read(self, t0_us: int, t1_us: int, most: int | None = None) -> EventStream:
        """The events with t0 <= t < t1 (empty when t1 <= t0 or outside the recording), read
        from the slice the index points to: the window plus at most its two end milliseconds
        (read twice: to locate the window, then from HDF5's chunk cache). A window of more
        than ``most`` events is thinned to every k-th event (k the smallest that keeps at most
        ``most``), streamed in slices: memory holds one slice and the result."""
        i0, i1 = self.window(t0_us, t1_us)
        if most is None or i1 - i0 <= most:
            return self._stream(i0, i1)
        step = -(-(i1 - i0) // max(int(most), 1))
        size = max(READ_CHUNK // step, 1) * step  # slices start on a kept event
        kept = []
        for s in range(i0, i1, size):
            ev = self._stream(s, min(s + size, i1))
            kept.append([getattr(ev, k)[::step].copy() for k in "xytp"])  # the slice is freed
        x, y, t, p = (np.concatenate(column) for column in zip(*kept))
        return EventStream(x, y, t, p, self.width, self.height, self.source)

    def window(self, t0_us: int, t1_us: int) -> tuple[int, int]:
        """Index range [i0, i1) of the events with t0 <= t < t1, found from the slices of its two
        end milliseconds (what lies between is not read)."""
        t0_us, t1_us = int(t0_us), int(t1_us)
        if t1_us <= t0_us or self.count == 0:
            return 0, 0
        i0 = self._first_at(t0_us)
        return i0, max(self._first_at(t1_us), i0)

    def time_at(self, i: int) -> int:
        """The timestamp of event ``i`` (µs)."""
        return int(self._t(i, i + 1)[0])

    def split_equal_count(self, i0: int, i1: int, m: int) -> np.ndarray:
        """int64[m+1] boundaries splitting events [i0, i1) into m sub-windows whose counts
        differ by at most one (as :meth:`EventStream.split_equal_count`)."""
        return core_call(self.source, _core.split_equal_count, self.count, int(i0), int(i1), int(m))

    def accumulate(
        self, i0: int, i1: int, c_pos: float, c_neg: float
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """ESI, event mask (see :meth:`EventStream.esi_and_mask`) and event count of events
        [i0, i1), read in slices of at most READ_CHUNK events: a window of any length (a
        fraction of a long recording) holds 13 bytes per event of one slice in memory, never
        the whole window's."""
        esi = np.zeros((self.height, self.width), np.float32)
        mask = np.zeros((self.height, self.width), bool)
        count = 0
        for ev in self._slices(i0, i1):
            part, hit = ev.esi_and_mask(0, len(ev), c_pos, c_neg)
            esi += part
            mask |= hit
            count += len(ev)
        return esi, mask, count

    def event_count(self, i0: int, i1: int) -> np.ndarray:
        """Events per pixel of events [i0, i1), uint32[H,W], read in slices as ``accumulate``."""
        counts = np.zeros((self.height, self.width), np.uint32)
        for ev in self._slices(i0, i1):
            counts += ev.event_count(0, len(ev))
        return counts

    def _slices(self, i0: int, i1: int) -> Iterator[EventStream]:
        """Events [i0, i1) as streams of at most ``READ_CHUNK`` events each."""
        for s in range(i0, i1, READ_CHUNK):
            yield self._stream(s, min(s + READ_CHUNK, i1))

    def _bucket(self, t_us: int) -> tuple[int, int, list[tuple[int, int]]]:
        """[a, b]: where the first event at or after ``t_us`` lies, and the (ms, entry) pairs
        of the index that say so (checked against the timestamps by the caller)."""
        idx, n = self.ms_to_idx, len(self.ms_to_idx)
        k = (t_us - self.origin) // MS
        if n == 0:
            return 0, self.count, []
        if k < 0:
            return 0, int(idx[0]), [(0, int(idx[0]))]
        if k >= n:
            return self.count, self.count, []
        b = int(idx[k + 1]) if k + 1 < n else self.count
        used = [(k, int(idx[k]))] + ([(k + 1, b)] if k + 1 < n else [])
        return int(idx[k]), b, used

    def _check_entries(self, used: list[tuple[int, int]], t: np.ndarray, lo: int) -> None:
        """Each (ms, entry) used against the timestamps ``t`` of events [lo, ...): the entry's
        event is the first at or after the millisecond's start."""
        for k, j in used:
            start = self.origin + k * MS
            if (j < self.count and t[j - lo] < start) or (j > 0 and t[j - 1 - lo] >= start):
                raise EvsplatError(
                    f"{self.source}: ms_to_idx[{k}] = {j} disagrees with the timestamps (the "
                    f"first event at or after {start} µs is elsewhere); run `evsplat check` on "
                    f"it and re-convert the file{self._cache_hint()}"
                )

    def _first_at(self, t_us: int) -> int:
        """Index of the first event at or after ``t_us``, from its millisecond's slice only."""
        a, b, used = self._bucket(t_us)
        lo = max(a - 1, 0)
        t = self._t(lo, min(b + 1, self.count))  # a neighbour each side checks the entries
        self._check_entries(used, t, lo)
        return a + int(np.searchsorted(t[a - lo : b - lo], t_us, side="left"))

    def _cache_hint(self) -> str:
        cached = "cached" in self.index_source
        return f" (or delete its cached index {sidecar_path(self.path)})" if cached else ""

    def verify(self) -> list[str]:
        """Problems found by one streaming pass over every event: invalid events, unsorted
        timestamps, an index that disagrees with them. Empty when the file is sound."""
        if self.index_source.startswith("built"):
            return []  # the pass that built the index validated every event
        try:
            scan = _scan(
                h5_events_group(self._file, self.source),
                self.source,
                self._t_offset,
                {"width": self.width, "height": self.height},
                self.origin,
            )
        except EvsplatError as e:
            return [str(e)]
        wrong = first_disagreement(scan.ms_to_idx, self.ms_to_idx)
        if wrong is None:
            return []
        return [
            f"{self.source}: the ms index ({self.index_source}) disagrees with the timestamps: "
            f"{wrong}; re-convert the file{self._cache_hint()}"
        ]


def open_store(
    path: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    transform: Callable[[EventStream], EventStream] | None = None,
    *,
    cache_index: bool = True,
) -> EventStore:
    """Opens an HDF5 event file for windowed reads. The sensor size is the file's attributes,
    else ``width``/``height``. A file without ``ms_to_idx`` gets one from a validating
    streaming pass, cached beside it (``cache_index``; see event_index.sidecar_path) for the
    next open. ``transform`` is applied to every window read (e.g. lens rectification)."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        what = "is a folder, not a file" if path.exists() else "no such file; check the path"
        raise EvsplatError(f"{src}: {what}")
    if path.stat().st_size == 0:
        raise EvsplatError(f"{src}: file is empty; expected events (x, y, t, p)")
    try:
        f = h5py.File(path, "r", rdcc_nbytes=CHUNK_CACHE, rdcc_nslots=10007)
    except OSError as e:
        raise h5_read_error(src, e) from None
    try:
        group = h5_events_group(f, src)
        lengths = {len(group[k]) for k in "xytp"}
        if len(lengths) > 1 or any(group[k].ndim != 1 for k in "xytp"):
            shapes = ", ".join(f"{k} {group[k].shape}" for k in "xytp")
            raise EvsplatError(f"{src}: event datasets differ in shape ({shapes}); re-export it")
        size = h5_sensor_size(f, group)
        given = {"width": width, "height": height}
        size = {k: size.get(k, given[k]) for k in given}
        index, source = _index(f, group, path, size, cache_index)
        if None in size.values():
            raise EvsplatError(
                f"{src}: no width/height attributes; pass the sensor size (meta.json in a "
                "dataset folder)"
            )
        return EventStore(f, path, (size["width"], size["height"]), index, source, transform)
    except OSError as e:
        f.close()
        raise h5_read_error(src, e) from None
    except BaseException:
        f.close()
        raise


def _index(
    f: h5py.File, group: h5py.Group, path: Path, size: dict, cache: bool
) -> tuple[tuple[int, np.ndarray], str]:
    """The file's (origin, ms_to_idx) and where it came from: the file, a fresh cache, or a
    streaming pass now (cached when ``cache`` and the folder is writable)."""
    if "ms_to_idx" in f:
        return (h5_t_offset(f), np.asarray(f["ms_to_idx"][()]).astype(np.int64)), "in the file"
    cached = load_sidecar(path)
    if cached is not None:
        origin, ms_to_idx, extent = cached
        source = f"cached in {sidecar_path(path)}"
    else:
        known = {k: v for k, v in size.items() if v is not None}
        scan = _scan(group, str(path), h5_t_offset(f), known, None)
        origin, ms_to_idx, extent = scan.origin, scan.ms_to_idx, (scan.max_x + 1, scan.max_y + 1)
        saved = save_sidecar(path, origin, ms_to_idx, extent) if cache else None
        source = f"built by a streaming pass, {f'cached in {saved}' if saved else 'not cached'}"
    for k, side in zip(("width", "height"), extent):
        if size[k] is None and side > 0:
            size[k] = side  # the smallest sensor holding every event, as read_events
    return (origin, ms_to_idx), source


def verify_store(
    path: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    transform: Callable[[EventStream], EventStream] | None = None,
) -> tuple[list[str], EventStore | None]:
    """Problems with the event file (every event and the index checked; nothing written) and
    the opened store, None when it does not open (its error is then the one problem)."""
    try:
        store = open_store(path, width=width, height=height, transform=transform, cache_index=False)
    except EvsplatError as e:
        return [str(e)], None
    return store.verify(), store
