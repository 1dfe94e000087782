"""The project's HDF5 event file, written in one streaming pass.

Layout (DSEC's, docs/dataset.md): ``events/x``, ``events/y`` (uint16), ``events/t`` (int64 µs
relative to ``t_offset``), ``events/p`` (int8 ±1), chunked and compressed; the scalar
``t_offset`` (int64 µs: the first event's millisecond); ``ms_to_idx`` (uint64, see
:mod:`evsplat.data.event_index`); ``width``/``height`` attributes on the file; and, for a
converted recording, a ``provenance`` group whose attributes say where it came from.
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
#: 4.6 against 3.9 bytes per event (measured, docs/results.md "Issue 24").
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


def write_events(
    path: str | os.PathLike,
    width: int,
    height: int,
    streams: Iterable[EventStream],
    *,
    compression: str = DEFAULT_CODEC,
    chunk: int = CHUNK,
    provenance: Mapping[str, object] | None = None,
) -> int:
    """Writes the validated ``streams`` (in time order) to ``path`` as one event file with its
    millisecond index; returns the number of events. Atomic: an error (also one raised by
    ``streams``) leaves ``path`` as it was. ``provenance`` is read after the last stream, so
    a caller may fill it in while streaming."""
    path = Path(path)
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
                dsets["x"][written:], dsets["y"][written:] = ev.x, ev.y
                dsets["t"][written:] = ev.t - index.origin
                dsets["p"][written:] = ev.p
                written, last_t = n, int(ev.t[-1])
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
    )
