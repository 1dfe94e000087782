"""Readers for recordings from real sensors, each on the field's maintained decoder:

==============  ==========================  ==================================================
suffix          format                      decoder (PyPI)
==============  ==========================  ==================================================
``.aedat4``     iniVation AEDAT 4 (DV)      evsplat's own (crates/formats, Rust)
``.raw``        Prophesee RAW, EVT 2.0      evsplat's own (crates/formats, Rust)
``.raw``        Prophesee RAW, EVT 3.0      evsplat's own (crates/formats, Rust)
``.dat``        Prophesee DAT (CD events)   evsplat's own (crates/formats, Rust)
``.bag``        ROS 1 bag                   evsplat's own (crates/formats, Rust)
``.mcap``       ROS 2 bag, one MCAP file    evsplat's own (crates/formats, Rust)
``.db3``        ROS 2 bag (or its folder)   evsplat's own (crates/formats, Rust, SQLite)
==============  ==========================  ==================================================

Every reader opens a file into an :class:`EventSource`: the sensor size plus an iterator of
chunks ``(x, y, t, p)`` (t in integer µs, p in {0, 1} or {-1, +1}), so conversion streams
without holding the recording in memory. :func:`read_source` gathers the chunks into one
validated :class:`EventStream` for ``evsplat.data.event_files.read_events``. What a decoder
read but could not turn into events (a truncated file's last bytes) is counted in the
source's :class:`Dropped`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError

#: One chunk of events: x, y, t (µs), p.
Chunk = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: Suffixes of the sensor formats handled here (a ROS 2 bag may also be its folder).
SUFFIXES = (".aedat4", ".raw", ".dat", ".bag", ".mcap", ".db3")
#: A ROS 2 storage file that rosbag2 compressed whole (its compression_mode "file").
PACKED_SUFFIXES = (".mcap.zstd", ".db3.zstd")
#: Every recording name this package opens, for the messages that list them.
KNOWN_SUFFIXES = SUFFIXES + PACKED_SUFFIXES


@dataclass
class Dropped:
    """What a decoder read but did not turn into events; complete once the chunks are
    exhausted."""

    #: CD events before the stream's first time word: they have no timestamp.
    events: int = 0
    #: Words of a type the format does not define, skipped.
    words: int = 0
    #: Bytes after the last complete word or record: the file is truncated.
    bytes: int = 0
    #: What ``words`` counts, in the warning.
    words_are: str = "words of undefined types"

    def warning(self, path: Path) -> str | None:
        """One line saying what was dropped, or None when nothing was."""
        parts = [
            f"an incomplete record of {self.bytes} B at the end (the file is truncated)"
            if self.bytes
            else "",
            f"{self.events} events come before the first time word (no timestamp)"
            if self.events
            else "",
            f"{self.words} {self.words_are} were skipped" if self.words else "",
        ]
        said = "; ".join(p for p in parts if p)
        return f"{path}: {said}; all other events were kept" if said else None


#: Events per chunk of the Rust readers (every chunk but the last is full: convert's batches are
#: whole chunks), and bytes per read: the memory a recording streams through.
CHUNK_EVENTS = 1 << 20
BLOCK_BYTES = 4 << 20


CHECK_FILE = "check the file"  # the fix a reader's I/O error names when it has none better


def decoded_chunks(
    path: Path, open_decoder: Callable, dropped: Dropped, fix: str = CHECK_FILE
) -> Iterator[Chunk]:
    """The chunks of the Rust reader that ``open_decoder()`` makes, until it is exhausted;
    ``dropped`` is filled in then. An I/O error, opening or reading, is one line naming the
    file and ``fix``."""
    try:
        decoder = open_decoder()
        while len((chunk := decoder.next_chunk(CHUNK_EVENTS))[0]):
            yield chunk
    except OSError as e:
        what = " ".join(str(e).split())
        raise EvsplatError(f"{path}: cannot read events ({what}); {fix}") from None
    dropped.events, dropped.words, dropped.bytes = decoder.dropped()


@dataclass
class EventSource:
    """An opened recording: where it came from, its sensor size, its event chunks, the
    decoder (a PyPI package, or "evsplat" for the project's own; recorded in a converted
    file's provenance) and what it dropped."""

    path: Path
    width: int
    height: int
    chunks: Iterator[Chunk]
    format: str
    decoder: str
    dropped: Dropped = field(default_factory=Dropped)


def is_sensor_format(path: str | os.PathLike) -> bool:
    """True for a file with one of :data:`SUFFIXES`, a ROS 2 storage file packed whole
    (``NAME.mcap.zstd``) or a ROS 2 bag folder (metadata.yaml)."""
    path = Path(path)
    return path.suffix.lower() in SUFFIXES or is_ros2_bag(path)


def is_ros2_bag(path: Path) -> bool:
    """A ROS 2 bag given by its folder (metadata.yaml) or by a storage file packed whole."""
    return packed_storage(path) is not None or (path / "metadata.yaml").is_file()


def packed_storage(path: Path) -> str | None:
    """The storage suffix (``.mcap``, ``.db3``) of a ROS 2 file rosbag2 compressed whole
    (``NAME.mcap.zstd``: compression_mode "file"), else None."""
    name = path.name.lower()
    return next((s.removesuffix(".zstd") for s in PACKED_SUFFIXES if name.endswith(s)), None)


def open_source(path: str | os.PathLike, *, topic: str | None = None) -> EventSource:
    """Opens a sensor recording chosen by suffix; ``topic`` picks the event topic of a bag
    (default: the only event-array topic). Errors are one-line EvsplatErrors."""
    from evsplat.data.formats import aedat4, prophesee, rosbag

    path = Path(path)
    if not path.exists():
        raise EvsplatError(f"{path}: no such file; check the path")
    suffix = path.suffix.lower()
    if topic is not None and not rosbag.is_bag(path):
        raise EvsplatError(f"{path}: --topic applies to ROS bags only; drop it for {suffix} files")
    if rosbag.is_bag(path):
        return rosbag.open_bag(path, topic=topic)
    if path.stat().st_size == 0:
        raise EvsplatError(f"{path}: file is empty; expected a recording")
    if suffix == ".aedat4":
        return aedat4.open_aedat4(path)
    if suffix == ".raw":
        return prophesee.open_raw(path)
    if suffix == ".dat":
        return prophesee.open_dat(path)
    known = ", ".join(KNOWN_SUFFIXES)
    raise EvsplatError(f"{path}: unknown recording type '{suffix}'; use {known}")


def read_source(source: EventSource) -> EventStream:
    """Gathers every chunk of ``source`` into one validated stream."""
    parts = [c for c in source.chunks if len(c[0])]
    if (warning := source.dropped.warning(source.path)) is not None:
        warnings.warn(warning, stacklevel=2)
    if not parts:
        raise EvsplatError(f"{source.path}: the recording holds no events")
    x, y, t, p = (np.concatenate([c[i] for c in parts]) for i in range(4))
    return EventStream.from_arrays(
        x, y, t.astype(np.int64, copy=False), p, source.width, source.height, str(source.path)
    )
