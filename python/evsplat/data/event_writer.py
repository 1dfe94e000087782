"""The project's HDF5 event file, written in one streaming pass.

Layout (DSEC's, docs/dataset.md): ``events/x``, ``events/y`` (uint16), ``events/t`` (int64 µs
relative to ``t_offset``), ``events/p`` (int8 ±1), chunked and compressed; the scalar
``t_offset`` (int64 µs: the first event's millisecond); ``ms_to_idx`` (uint64, see
:mod:`evsplat.data.event_index`); ``width``/``height`` attributes on the file, and
``recorded_us`` where the writer knows the span the sensor recorded (a quiet start has no
events, yet it was recorded); and, for a converted recording, a ``provenance`` group whose
attributes say where it came from.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path

import h5py
import hdf5plugin
import numpy as np

from evsplat.data.atomic import write_atomic
from evsplat.data.event_index import IndexBuilder, index_origin
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError

#: Events per HDF5 chunk: a 50 ms window of a dense recording spans a few chunks, and a
#: chunk (850 KB raw over the four columns) decompresses in about a millisecond.
CHUNK = 1 << 16
#: Blosc LZ4 with byte shuffle decodes ~4x faster than gzip and writes ~15x faster, at
#: 4.6 against 3.9 bytes per event (measured, docs/experiments/formats.md).
DEFAULT_CODEC = "blosc"


def codecs() -> dict[str, Mapping]:
    """h5py dataset options of every codec name the writers accept."""
    return {
        "blosc": hdf5plugin.Blosc(),
        "zstd": hdf5plugin.Zstd(),
        "gzip": {"compression": "gzip"},
        "lzf": {"compression": "lzf"},
        "none": {},
    }


#: Threads compressing one column's chunks: on the 2-core test machine a second one made the writes
#: alone faster only with a core to spare, and ``evsplat convert``, whose reader and checksum
#: threads take that core, no faster (docs/experiments/formats.md, "Blosc chunks compressed off the
#: GIL").
_BLOSC_THREADS = 1


class _BloscColumn:
    """One column written as the Blosc filter's LZ4 chunks made by ``_core.blosc_chunks`` (the
    layout, filter id and cd_values of ``hdf5plugin.Blosc()``'s filter, which stock h5py +
    hdf5plugin read) and handed to HDF5 whole with ``write_direct_chunk``: compressed without
    the GIL (h5py runs its filters on the calling thread, holding it), so the reader's and the
    checksum's threads run meanwhile. A chunk's tail waits for the next stream, so every chunk
    is compressed once."""

    def __init__(self, dset: h5py.Dataset, clevel: int, shuffle: bool) -> None:
        self.dset, self.clevel, self.shuffle = dset, clevel, shuffle
        self.chunk = dset.chunks[0]
        self.tail = np.zeros(0, dset.dtype)
        self.start = 0  # first event of the tail

    def add(self, values: np.ndarray) -> None:
        """Appends ``values`` (the dataset already resized to hold them); writes every whole
        chunk. Only the tail's chunk is joined with the head of ``values``, not the batch."""
        if len(self.tail):
            need = self.chunk - len(self.tail)
            first, values = np.concatenate([self.tail, values[:need]]), values[need:]
            if len(first) < self.chunk:
                self.tail = first
                return
            self._write(first)
            self.start += self.chunk
        whole = len(values) // self.chunk * self.chunk
        self._write(values[:whole])
        self.tail = values[whole:].copy()
        self.start += whole

    def close(self) -> None:
        """Writes the last, partial chunk (zero-padded, as HDF5 pads an edge chunk)."""
        self._write(self.tail)
        self.start += len(self.tail)
        self.tail = self.tail[:0]

    def _write(self, values: np.ndarray) -> None:
        if len(values) == 0:
            return
        from evsplat import _core

        raw = np.ascontiguousarray(values, self.dset.dtype).view(np.uint8)
        size = self.dset.dtype.itemsize
        chunks = _core.blosc_chunks(
            raw, size, self.chunk * size, self.clevel, self.shuffle, _BLOSC_THREADS
        )
        for i, (data, mask) in enumerate(chunks):
            self.dset.id.write_direct_chunk((self.start + i * self.chunk,), data, mask)


def _blosc_lz4(options: Mapping) -> tuple[int, bool] | None:
    """(clevel, shuffle) of an ``hdf5plugin.Blosc`` codec that ``_BloscColumn`` writes (LZ4,
    byte shuffle or none); None for any other codec."""
    if not isinstance(options, hdf5plugin.Blosc) or options.cname != "lz4":
        return None
    if options.shuffle not in (hdf5plugin.Blosc.NOSHUFFLE, hdf5plugin.Blosc.SHUFFLE):
        return None
    return options.clevel, options.shuffle == hdf5plugin.Blosc.SHUFFLE


def write_events(
    path: str | os.PathLike,
    width: int,
    height: int,
    streams: Iterable[EventStream],
    *,
    compression: str = DEFAULT_CODEC,
    chunk: int = CHUNK,
    provenance: Mapping[str, object] | None = None,
    recorded_us: tuple[int, int] | None = None,
) -> int:
    """Writes the validated ``streams`` (in time order) to ``path`` as one event file with its
    millisecond index; returns the number of events. Atomic: an error (also one raised by
    ``streams``) leaves ``path`` as it was. ``provenance`` is read after the last stream, so
    a caller may fill it in while streaming. ``recorded_us``: the [start, end] µs the sensor
    recorded, which must hold every event."""
    path = Path(path)
    if recorded_us is not None and not recorded_us[0] <= recorded_us[1]:
        raise EvsplatError(f"{path}: recorded span {recorded_us} must have start <= end")
    options = codecs()
    if compression not in options:
        raise EvsplatError(
            f"{path}: compression {compression!r} is unknown; use {', '.join(sorted(options))}"
        )
    if chunk < 1:
        raise EvsplatError(f"{path}: chunk {chunk} must be at least 1 event")
    written = 0

    def write(tmp: Path) -> None:
        nonlocal written
        with h5py.File(tmp, "w") as f:
            f.attrs["width"], f.attrs["height"] = width, height
            if recorded_us is not None:
                f.attrs["recorded_us"] = np.array(recorded_us, dtype=np.int64)
            group = f.create_group("events")
            dtypes = {"x": np.uint16, "y": np.uint16, "t": np.int64, "p": np.int8}
            dsets = {
                k: group.create_dataset(
                    k,
                    shape=(0,),
                    dtype=dt,
                    maxshape=(None,),
                    chunks=(chunk,),
                    **options[compression],
                )
                for k, dt in dtypes.items()
            }
            blosc = _blosc_lz4(options[compression])
            direct = {k: _BloscColumn(d, *blosc) for k, d in dsets.items()} if blosc else {}
            index: IndexBuilder | None = None
            last_t = None
            for ev in streams:
                if len(ev) == 0:
                    continue
                if last_t is not None and ev.t[0] < last_t:
                    raise EvsplatError(
                        f"{ev.source}: events go back in time at event {written} ({ev.t[0]} µs "
                        f"after {last_t} µs); sort them (the recording's packets are out of order)"
                    )
                index = index or IndexBuilder(index_origin(ev.t[0]))
                index.add(ev.t)
                n = written + len(ev)
                for k in "xytp":
                    dsets[k].resize((n,))
                columns = {"x": ev.x, "y": ev.y, "t": ev.t - index.origin, "p": ev.p}
                for k, values in columns.items():
                    if direct:
                        direct[k].add(values)
                    else:
                        dsets[k][written:] = values
                written, last_t = n, int(ev.t[-1])
                if recorded_us is not None and not (
                    recorded_us[0] <= int(ev.t[0]) and last_t <= recorded_us[1]
                ):
                    raise EvsplatError(
                        f"{ev.source}: events at {int(ev.t[0])}-{last_t} µs lie outside the "
                        f"recorded span {list(recorded_us)} µs; widen the span or drop them"
                    )
            for column in direct.values():
                column.close()
            f["t_offset"] = np.int64(index.origin if index else 0)
            ms_to_idx = index.result() if index else np.zeros(0, np.int64)
            f.create_dataset("ms_to_idx", data=ms_to_idx.astype(np.uint64))
            if provenance is not None:
                f.create_group("provenance").attrs.update(provenance)

    write_atomic(path, write)
    return written


def write_events_h5(
    path: str | os.PathLike,
    events: EventStream,
    *,
    compression: str = DEFAULT_CODEC,
    chunk: int = CHUNK,
    provenance: Mapping[str, object] | None = None,
    recorded_us: tuple[int, int] | None = None,
) -> None:
    """Writes one stream as an event file (see :func:`write_events`); chunks never longer
    than the stream, so a small file stays small even uncompressed."""
    chunk = min(chunk, max(len(events), 1)) if chunk >= 1 else chunk
    write_events(
        path,
        events.width,
        events.height,
        [events],
        compression=compression,
        chunk=chunk,
        provenance=provenance,
        recorded_us=recorded_us,
    )
