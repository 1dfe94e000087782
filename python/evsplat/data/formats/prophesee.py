"""Prophesee recordings: RAW (EVT 2.0 through ``expelliarmus``, EVT 3.0 through ``evt3``) and
DAT (CD events, through ``expelliarmus``).

Both start with an ASCII header of ``% key value`` lines, parsed here for the encoding and the
sensor size; the binary event words are left to the decoders. (``expelliarmus`` also reads
EVT 3.0, but adds 4096 µs after each TIME_HIGH word that follows a larger TIME_LOW, which every
real stream has; ``evt3`` decodes the same words as OpenEB does.)"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import evt3
import expelliarmus
import numpy as np

from evsplat.data.formats import Chunk, EventSource
from evsplat.errors import EvsplatError

#: Events per chunk (EVT 2.0, DAT) and bytes per batch (EVT 3.0) when streaming.
CHUNK_EVENTS = 1 << 20
BATCH_BYTES = 8 << 20
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


def _decode_error(path: Path, e: BaseException) -> EvsplatError:
    what = " ".join(str(e).split())
    return EvsplatError(f"{path}: cannot decode events ({what}); the file is truncated or corrupt")


def open_raw(path: Path) -> EventSource:
    """Opens a Prophesee .raw file (EVT 2.0 or 3.0, named in its header)."""
    fields, start = read_header(path)
    version = _evt_version(path, fields)
    width, height = _geometry(path, fields)
    if version == "2.0":
        if (path.stat().st_size - start) % 4:
            raise EvsplatError(
                f"{path}: EVT 2.0 data is {path.stat().st_size - start} bytes, not whole 32-bit "
                "words; the file is truncated"
            )
        return EventSource(
            path, width, height, _expelliarmus_chunks(path, "evt2"), "evt2", "expelliarmus"
        )
    return EventSource(path, width, height, _evt3_chunks(path), "evt3", "evt3")


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
    return EventSource(
        path, width, height, _expelliarmus_chunks(path, "dat"), "dat", "expelliarmus"
    )


def _expelliarmus_chunks(path: Path, encoding: str) -> Iterator[Chunk]:
    try:
        wizard = expelliarmus.Wizard(encoding=encoding, fpath=path, chunk_size=CHUNK_EVENTS)
        for arr in wizard.read_chunk():
            yield (
                arr["x"].astype(np.uint16),
                arr["y"].astype(np.uint16),
                arr["t"].astype(np.int64, copy=False),
                arr["p"].astype(np.int8),
            )
    except (OSError, RuntimeError, ValueError) as e:
        raise _decode_error(path, e) from None


def _evt3_chunks(path: Path) -> Iterator[Chunk]:
    try:
        for ev in evt3.decode_file_batches(str(path), batch_bytes=BATCH_BYTES):
            yield ev.x, ev.y, ev.timestamp.astype(np.int64), ev.polarity.astype(np.int8)
    except (OSError, RuntimeError, ValueError) as e:
        raise _decode_error(path, e) from None
