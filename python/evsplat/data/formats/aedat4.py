"""iniVation AEDAT 4 (DV software, DAVIS/DVXplorer) through the ``aedat`` decoder (Rust).

The first event stream of the file is read; its packets become chunks. AEDAT 4 timestamps
are already integer µs (since the Unix epoch)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import aedat
import numpy as np

from evsplat.data.formats import Chunk, EventSource
from evsplat.errors import EvsplatError


def _fail(path: Path, e: BaseException) -> EvsplatError:
    what = " ".join(str(e).split())
    return EvsplatError(
        f"{path}: cannot decode AEDAT 4 ({what}); the file is truncated, corrupt or not AEDAT 4 "
        "(re-export it from DV)"
    )


def open_aedat4(path: Path) -> EventSource:
    """Opens an .aedat4 file; raises EvsplatError when it has no event stream."""
    try:
        decoder = aedat.Decoder(str(path))
        streams = decoder.id_to_stream()
    except (OSError, RuntimeError, ValueError) as e:
        raise _fail(path, e) from None
    events = {i: s for i, s in streams.items() if s.get("type") == "events"}
    if not events:
        kinds = ", ".join(sorted({str(s.get("type")) for s in streams.values()})) or "none"
        raise EvsplatError(
            f"{path}: no event stream (streams: {kinds}); record with the event output enabled"
        )
    sid = min(events)
    return EventSource(
        path,
        int(events[sid]["width"]),
        int(events[sid]["height"]),
        _chunks(path, decoder, sid),
        "aedat4",
        "aedat",
    )


def _chunks(path: Path, decoder: aedat.Decoder, sid: int) -> Iterator[Chunk]:
    it = iter(decoder)
    while True:
        try:
            packet = next(it)
        except StopIteration:
            return
        except (OSError, RuntimeError, ValueError) as e:
            raise _fail(path, e) from None
        if packet["stream_id"] == sid and "events" in packet:
            ev = packet["events"]
            yield ev["x"], ev["y"], ev["t"].astype(np.int64), ev["p"].astype(np.int8)
