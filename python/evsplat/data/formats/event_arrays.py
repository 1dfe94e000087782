"""The event arrays of ROS bags as numpy record views of their bytes (ROS 1 serialisation and
CDR), and rosbags reading a bag's events through them: `evsplat bench decode`'s reference
decoder (the path evsplat took before its Rust readers, crates/formats) and the tests'."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import numpy as np
from rosbags.highlevel import AnyReader

from evsplat.data.formats import Chunk

#: One event as ROS 1 serialises it (packed): x, y, ts.sec, ts.nsec, polarity.
ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])
#: The same in CDR (ROS 2): the first event is packed (13 bytes); each further one is
#: aligned (x, y, 2 padding bytes so that ts aligns to 4, ts, polarity) and read as a 16-byte
#: record that starts at the padding byte before it, so the last record ends with the message.
CDR_FIRST_EVENT = np.dtype(
    {
        "names": ["x", "y", "sec", "nsec", "p"],
        "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
        "offsets": [0, 2, 4, 8, 12],
        "itemsize": 13,
    }
)
CDR_EVENT = np.dtype(
    {
        "names": ["x", "y", "sec", "nsec", "p"],
        "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
        "offsets": [1, 3, 7, 11, 15],
        "itemsize": 16,
    }
)


def ros1_event_records(raw: bytes) -> np.ndarray | None:
    """The events of a ROS 1-serialised EventArray as a zero-copy record view, or None when
    the bytes do not have exactly that layout. ROS 1 serialisation is packed little-endian:
    Header (seq, stamp sec, nsec, frame_id length + bytes), height, width, event count, then
    13 bytes per event. The exact-length check guards against any other layout."""
    if len(raw) < 16:
        return None
    (id_len,) = struct.unpack_from("<I", raw, 12)
    start = 16 + id_len + 12
    if start > len(raw):
        return None
    (n,) = struct.unpack_from("<I", raw, start - 4)
    if start + ROS1_EVENT.itemsize * n != len(raw):
        return None
    return np.frombuffer(raw, ROS1_EVENT, n, start)


def cdr_event_records(raw: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """The events of a little-endian CDR (ROS 2) EventArray as (first event, the others)
    record views, or None for any other layout. After the 4-byte encapsulation header (origin
    of the alignment): Header (stamp sec, nanosec, frame_id length incl. NUL + bytes), padding
    to 4, height, width, event count; then the first event packed in 13 bytes and every further
    one in 16 (x, y, 2 padding bytes so that ts aligns to 4, ts, polarity, 1 padding byte)."""
    if len(raw) < 16 or raw[:2] != b"\x00\x01":
        return None
    body = memoryview(raw)[4:]
    (id_len,) = struct.unpack_from("<I", body, 8)
    start = (12 + id_len + 3) // 4 * 4 + 12
    if start > len(body):
        return None
    (n,) = struct.unpack_from("<I", body, start - 4)
    expected = start + (CDR_EVENT.itemsize * n - 3 if n else 0)
    # Serialisers may pad the message to a multiple of 4 bytes.
    if not expected <= len(body) <= expected + 3:
        return None
    if n == 0:
        return np.empty(0, CDR_FIRST_EVENT), np.empty(0, CDR_EVENT)
    first = np.frombuffer(body, CDR_FIRST_EVENT, 1, start)
    rest = np.frombuffer(body, CDR_EVENT, n - 1, start + CDR_FIRST_EVENT.itemsize)
    return first, rest


def event_chunks(reader: AnyReader, conns) -> Iterator[Chunk]:
    """The event chunks of a bag through rosbags: `evsplat bench decode`'s reference decoder
    (the path evsplat took before its Rust readers), with byte views of the event messages."""
    try:
        for conn, _, raw in reader.messages(connections=conns):
            # rosbags builds one Python object per event; a view of the bytes is ~100x faster.
            if reader.is2:
                parts = cdr_event_records(raw)
            else:
                rec = ros1_event_records(raw)
                parts = (rec,) if rec is not None else None
            if parts is not None:
                x, y, sec, nsec, p = (
                    np.concatenate([r[k] for r in parts]) for k in ("x", "y", "sec", "nsec", "p")
                )
                t = sec.astype(np.int64) * 1_000_000 + nsec.astype(np.int64) // 1000
                yield x, y, t, p.astype(np.int8)
                continue
            events = reader.deserialize(raw, conn.msgtype).events
            n = len(events)
            x = np.fromiter((e.x for e in events), np.uint16, n)
            y = np.fromiter((e.y for e in events), np.uint16, n)
            sec = np.fromiter((e.ts.sec for e in events), np.int64, n)
            nsec = np.fromiter((e.ts.nanosec for e in events), np.int64, n)
            p = np.fromiter((e.polarity for e in events), np.int8, n)
            yield x, y, sec * 1_000_000 + nsec // 1000, p
    finally:
        reader.close()
