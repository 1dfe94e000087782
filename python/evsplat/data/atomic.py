"""Atomic file writes: write a temporary sibling, then rename it over the target."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from evsplat.errors import EvsplatError


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Call `write(tmp)` on a temporary file next to `path`, then rename it to `path`.
    On any failure the temporary is removed and `path` is left untouched; an OSError (disk
    full, no permission) becomes an EvsplatError naming `path`."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as e:
        tmp.unlink(missing_ok=True)
        if isinstance(e, OSError):  # disk full, read-only folder, a directory in the way
            raise EvsplatError(
                f"{path}: cannot write ({e.strerror or e}); check the free space and the write "
                f"permission of {path.parent}, and that {path.name} is not a folder"
            ) from None
        raise
    return path


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically."""
    return write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
