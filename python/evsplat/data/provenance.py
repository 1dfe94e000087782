"""Where a converted event file came from: the source's path, size and SHA-256, the decoder
and its version, and how many events were dropped on the way. Stored as the attributes of the
file's ``provenance`` group (evsplat.data.event_writer); `evsplat check` prints them."""

from __future__ import annotations

import hashlib
import os
from importlib import metadata
from pathlib import Path

from evsplat import __version__

#: Bytes per read while hashing: large enough that hashlib runs without the GIL.
HASH_BLOCK = 1 << 20


def source_digest(path: str | os.PathLike) -> tuple[int, str]:
    """(bytes, SHA-256 hex) of a file, streamed; a folder (a ROS 2 bag) is hashed as its files'
    relative paths and contents in sorted order."""
    path = Path(path)
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    digest, size = hashlib.sha256(), 0
    for p in files:
        if path.is_dir():
            digest.update(p.relative_to(path).as_posix().encode() + b"\0")
        with open(p, "rb") as f:
            while block := f.read(HASH_BLOCK):
                digest.update(block)
                size += len(block)
    return size, digest.hexdigest()


def package_version(name: str) -> str:
    """The installed version of a PyPI package, or "unknown"."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "unknown"


def provenance(
    source: str | os.PathLike,
    size: int,
    sha256: str,
    fmt: str,
    decoder: str,
    events: int,
    dropped: int,
    *,
    bytes_dropped: int = 0,
    words_skipped: int = 0,
) -> dict[str, object]:
    """The provenance attributes of a file converted from ``source`` by ``decoder`` (a PyPI
    package name, or "evsplat" for the project's own readers): ``dropped`` events without a
    timestamp, the ``bytes_dropped`` of a truncated last record, the ``words_skipped`` of
    undefined types."""
    version = __version__ if decoder == "evsplat" else package_version(decoder)
    return {
        "source": str(Path(source).resolve()),
        "source_bytes": int(size),
        "source_sha256": sha256,
        "format": fmt,
        "decoder": f"{decoder} {version}",
        "converter": f"evsplat {__version__} convert",
        "events": int(events),
        "events_dropped": int(dropped),
        "bytes_dropped": int(bytes_dropped),
        "words_skipped": int(words_skipped),
    }
