"""iniVation AEDAT 4 (DV software, DAVIS/DVXplorer), decoded by the project's Rust reader
(crates/formats, ``aedat4``) in bounded chunks.

The header's XML description is parsed here for the streams (id, type, sensor size); the first
event stream's packets (uncompressed, LZ4 or Zstd) go to ``_core.Aedat4EventDecoder``. AEDAT 4
timestamps are already integer µs (since the Unix epoch). The reader was checked event by event
against the ``aedat`` package and dv-processing (tests/test_formats.py,
tests/test_formats_samples.py). A packet the file ends in is dropped and its bytes are counted;
a packet of the event stream that does not decode is skipped and counted."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from evsplat import _core
from evsplat.data.formats import BLOCK_BYTES, Dropped, EventSource, decoded_chunks
from evsplat.errors import EvsplatError

#: DV's stream type identifiers, named as the `aedat` package names them.
STREAM_TYPES = {"EVTS": "events", "FRME": "frame", "IMUS": "imus", "TRIG": "triggers"}


@dataclass(frozen=True)
class Stream:
    """One stream of the file's description."""

    id: int
    type: str
    width: int = 0
    height: int = 0


def _fail(path: Path, what: str) -> EvsplatError:
    what = " ".join(what.split())
    return EvsplatError(
        f"{path}: cannot decode AEDAT 4 ({what}); the file is truncated, corrupt or not AEDAT 4 "
        "(re-export it from DV)"
    )


def _attr(node: ET.Element, key: str) -> str | None:
    for child in node:
        if child.tag == "attr" and child.get("key") == key:
            return (child.text or "").strip()
    return None


def parse_description(path: Path, description: str) -> list[Stream]:
    """The streams of DV's XML: ``<dv><node name="outInfo"><node name="ID">`` with a
    ``typeIdentifier`` attribute and, for events and frames, ``<node name="info">`` with
    ``sizeX``/``sizeY``."""
    try:
        root = ET.fromstring(description)
    except ET.ParseError as e:
        raise _fail(path, f"the header's description is not XML: {e}") from None
    out = next((n for n in root if n.tag == "node" and n.get("name") == "outInfo"), None)
    if out is None:
        raise _fail(path, "the header's description has no outInfo node")
    streams = []
    for node in out:
        if node.tag != "node" or not (node.get("name") or "").isdigit():
            continue
        kind = _attr(node, "typeIdentifier") or "?"
        info = next((n for n in node if n.tag == "node" and n.get("name") == "info"), None)
        size = [_attr(info, k) if info is not None else None for k in ("sizeX", "sizeY")]
        w, h = (int(v) if v and v.isdigit() else 0 for v in size)
        streams.append(Stream(int(node.get("name", "0")), STREAM_TYPES.get(kind, kind), w, h))
    return streams


def open_aedat4(path: Path) -> EventSource:
    """Opens an .aedat4 file; raises EvsplatError when it has no event stream."""
    try:
        compression, data_table, description, data_start = _core.aedat4_header(path)
    except OSError as e:
        raise _fail(path, str(e)) from None
    if compression not in range(5):
        raise _fail(path, f"unknown compression {compression} in its header")
    streams = parse_description(path, description)
    events = [s for s in streams if s.type == "events"]
    if not events:
        kinds = ", ".join(sorted({s.type for s in streams})) or "none"
        raise EvsplatError(
            f"{path}: no event stream (streams: {kinds}); record with the event output enabled"
        )
    stream = min(events, key=lambda s: s.id)
    if not (stream.width > 0 and stream.height > 0):
        raise _fail(path, f"event stream {stream.id} has no sensor size (sizeX/sizeY)")
    block = max(1, min(BLOCK_BYTES, path.stat().st_size - data_start))
    decoder = _core.Aedat4EventDecoder(path, compression, stream.id, data_start, data_table, block)
    dropped = Dropped(words_are="event packets that could not be decoded")
    chunks = decoded_chunks(path, lambda: decoder, dropped)
    return EventSource(path, stream.width, stream.height, chunks, "aedat4", "evsplat", dropped)
