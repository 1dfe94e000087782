"""Prophesee recordings: RAW (EVT 2.0, EVT 3.0) and DAT (CD events), decoded by the
project's Rust decoders (crates/formats) in bounded chunks.

Both start with an ASCII header of ``% key value`` lines, parsed here for the encoding and the
sensor size; the binary event words after it go to ``_core.EventFileDecoder``. The decoders
were checked event by event against the field's: ``evt3`` for EVT 3.0 (it decodes as OpenEB
does; ``expelliarmus`` adds 4096 µs after each TIME_HIGH word that follows a larger TIME_LOW,
which every real stream has) and ``expelliarmus`` for EVT 2.0 and DAT (tests/test_formats.py,
``evsplat bench decode``). A truncated file keeps its events up to the last complete word and
says how many bytes were dropped."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

from evsplat import _core
from evsplat.data.formats import BLOCK_BYTES, Chunk, Dropped, EventSource, decoded_chunks
from evsplat.errors import EvsplatError

#: DAT event-type byte for CD events and their size in bytes (Prophesee file format docs).
DAT_CD_TYPE, DAT_CD_SIZE = 0x0C, 8
#: A header longer than this is not a header (a binary file that happens to start with '%').
MAX_HEADER = 1 << 16


def read_header(path: Path) -> tuple[dict[str, str], int]:
    """The ``% key value`` lines at the start of ``path`` (keys lower-cased) and the byte
    offset where the binary data starts."""
    fields: dict[str, str] = {}
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER)
    pos = 0
    while pos < len(head) and head[pos : pos + 1] == b"%":
        end = head.find(b"\n", pos)
        if end < 0:
            raise EvsplatError(
                f"{path}: corrupt header (a '%' line without its newline in the first "
                f"{MAX_HEADER} bytes); the file is not a Prophesee recording or is damaged"
            )
        line = head[pos + 1 : end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if line == "end":
            break
        key, _, value = line.partition(" ")
        if key:
            fields[key.lower()] = value.strip()
    return fields, pos


def _geometry(path: Path, fields: dict[str, str]) -> tuple[int, int]:
    """Sensor size from ``% geometry WxH``, ``% format ...;width=W;height=H`` or
    ``% width W`` / ``% height H`` (DAT)."""
    fmt = dict(kv.split("=", 1) for kv in fields.get("format", "").split(";") if "=" in kv)
    candidates = [
        re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", fields.get("geometry", "")),
        (fmt.get("width"), fmt.get("height")),
        (fields.get("width"), fields.get("height")),
    ]
    for c in candidates:
        w, h = (c.group(1), c.group(2)) if isinstance(c, re.Match) else c or (None, None)
        if w and h and w.strip().isdigit() and h.strip().isdigit() and int(w) > 0 and int(h) > 0:
            return int(w), int(h)
    raise EvsplatError(
        f"{path}: corrupt header: no sensor size ('% geometry WxH' or '% format "
        "...;width=W;height=H'); the header was damaged: restore it from the recording software"
    )


def _evt_version(path: Path, fields: dict[str, str]) -> str:
    version = fields.get("evt") or fields.get("format", "").split(";")[0].upper().replace("EVT", "")
    version = {"2": "2.0", "3": "3.0", "2.0": "2.0", "3.0": "3.0"}.get(version.strip())
    if version is None:
        found = fields.get("evt") or fields.get("format") or "no '% evt' or '% format' line"
        raise EvsplatError(
            f"{path}: corrupt header: encoding {found!r} is not EVT 2.0 or EVT 3.0; only those "
            "RAW encodings are supported (convert others with metavision_file_to_hdf5)"
        )
    return version


def open_raw(path: Path) -> EventSource:
    """Opens a Prophesee .raw file (EVT 2.0 or 3.0, named in its header)."""
    fields, start = read_header(path)
    version = _evt_version(path, fields)
    width, height = _geometry(path, fields)
    encoding = {"2.0": "evt2", "3.0": "evt3"}[version]
    return _source(path, width, height, encoding, start)


def open_dat(path: Path) -> EventSource:
    """Opens a Prophesee .dat file of CD events."""
    fields, start = read_header(path)
    width, height = _geometry(path, fields)
    with open(path, "rb") as f:
        f.seek(start)
        kind = f.read(2)
    if len(kind) < 2 or kind[0] != DAT_CD_TYPE or kind[1] != DAT_CD_SIZE:
        raise EvsplatError(
            f"{path}: corrupt header: event type/size bytes {kind.hex() or 'missing'}; a CD "
            f"event file has type {DAT_CD_TYPE:#04x} and size {DAT_CD_SIZE}"
        )
    return _source(path, width, height, "dat", start + len(kind))


def _source(path: Path, width: int, height: int, encoding: str, start: int) -> EventSource:
    dropped = Dropped()
    chunks = _chunks(path, encoding, start, dropped)
    return EventSource(path, width, height, chunks, encoding, "evsplat", dropped)


def _chunks(path: Path, encoding: str, start: int, dropped: Dropped) -> Iterator[Chunk]:
    """The events after byte ``start``; ``dropped`` is filled in once they are exhausted."""
    block = max(1, min(BLOCK_BYTES, path.stat().st_size - start))
    return decoded_chunks(
        path, lambda: _core.EventFileDecoder(path, encoding, start, block), dropped
    )
