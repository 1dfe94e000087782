"""Prophesee recordings written from the public format docs (EVT 2.0, EVT 3.0, DAT CD
events), vectorised and streaming: the test files of the readers and the benchmark's
recordings. EVT 3.0 is written as single events (no vectors)."""

from __future__ import annotations

import os
from collections.abc import Iterable

import numpy as np

from evsplat.data.formats import Chunk

#: Byte pairs after a DAT header: CD event type and record size (prophesee.DAT_CD_TYPE/SIZE).
DAT_KIND = bytes([0x0C, 8])


def header(encoding: str, width: int, height: int) -> bytes:
    """The header a reader needs: the encoding and the sensor size."""
    if encoding == "dat":
        lines = ["Data file containing CD events.", "Version 2", f"Width {width}"]
        return "".join(f"% {s}\n" for s in [*lines, f"Height {height}"]).encode() + DAT_KIND
    version = {"evt2": "2.0", "evt3": "3.0"}[encoding]
    fmt = f"{encoding.upper()};height={height};width={width}"
    return f"% evt {version}\n% format {fmt}\n% geometry {width}x{height}\n% end\n".encode()


def _interleave(flags: list[np.ndarray], values: list[np.ndarray], last: np.ndarray) -> np.ndarray:
    """Per event: the words ``values[i]`` where ``flags[i]`` (in order), then ``last``."""
    count = 1 + sum(f.astype(np.int64) for f in flags)
    end = np.cumsum(count)
    out = np.empty(int(end[-1]) if len(end) else 0, last.dtype)
    out[end - 1] = last
    pos = end - 1
    for f, v in zip(reversed(flags), reversed(values)):
        pos = pos - f
        out[pos[f]] = v[f]
    return out


class Encoder:
    """Encodes chunks of sorted events (x, y, t µs, p in {0, 1}) into a format's words, keeping
    the time base and row from one chunk to the next."""

    def __init__(self, encoding: str) -> None:
        if encoding not in ("evt2", "evt3", "dat"):
            raise ValueError(f"encoding {encoding!r} is not evt2, evt3 or dat")
        self.encoding = encoding
        self._prev: tuple[int, int] | None = None  # the last event's (t, y)

    def encode(self, x, y, t, p) -> bytes:
        x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
        t, p = np.asarray(t, np.int64), (np.asarray(p) > 0).astype(np.int64)
        if not len(t):
            return b""
        t_prev = np.concatenate([[-1 if self._prev is None else self._prev[0]], t[:-1]])
        y_prev = np.concatenate([[-1 if self._prev is None else self._prev[1]], y[:-1]])
        self._prev = (int(t[-1]), int(y[-1]))
        if self.encoding == "dat":
            rec = np.empty(len(t), [("t", "<u4"), ("d", "<u4")])
            rec["t"] = t & 0xFFFF_FFFF
            rec["d"] = x | (y << 14) | (p << 28)
            return rec.tobytes()
        if self.encoding == "evt2":
            # CD: t[5:0] in 27..22, x in 21..11, y in 10..0; TIME_HIGH (0x8): t[33:6].
            high = t >> 6
            new_high = high != (t_prev >> 6)
            cd = (p << 28) | ((t & 0x3F) << 22) | (x << 11) | y
            th = (0x8 << 28) | (high & 0x0FFF_FFFF)
            return _interleave([new_high], [th], cd).astype("<u4").tobytes()
        # EVT 3.0: TIME_HIGH (0x8, t[23:12]) resets the low bits, so TIME_LOW (0x6, t[11:0])
        # follows it; ADDR_Y (0x0) on a new row; ADDR_X (0x2, polarity in bit 11) = one event.
        new_high = (t >> 12) != (t_prev >> 12)
        new_low = new_high | (t != t_prev)
        new_row = new_high | (y != y_prev)
        words = [(0x8 << 12) | ((t >> 12) & 0xFFF), (0x6 << 12) | (t & 0xFFF), y]
        ev = (0x2 << 12) | (p << 11) | x
        return _interleave([new_high, new_low, new_row], words, ev).astype("<u2").tobytes()


def encode(
    encoding: str, x, y, t, p, width: int, height: int, *, head: bytes | None = None
) -> bytes:
    """A whole recording in memory: ``head`` (default :func:`header`) and the events."""
    head = header(encoding, width, height) if head is None else head
    return head + Encoder(encoding).encode(x, y, t, p)


def write_recording(
    path: str | os.PathLike, encoding: str, width: int, height: int, chunks: Iterable[Chunk]
) -> int:
    """Streams ``chunks`` into a recording at ``path``; returns its size in bytes."""
    enc = Encoder(encoding)
    with open(path, "wb") as f:
        size = f.write(header(encoding, width, height))
        for x, y, t, p in chunks:
            size += f.write(enc.encode(x, y, t, p))
    return size
