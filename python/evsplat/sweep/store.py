"""The sweep's output folder, shared by the driver and every worker:

    OUT/cells/KEY/                 a finished cell: cell.json, run/ (the run folder), result.json
    OUT/cells/.tmp-KEY@HOST-PID/   an attempt in progress (renamed to KEY/ when complete)
    OUT/logs/KEY.log               every attempt's output, appended
    OUT/summary.json               the last sweep's rows, failures and where the cells ran

A cell folder appears by one rename of a complete attempt whose result.json was written last,
so a folder named KEY is always finished, and a killed attempt leaves only a .tmp- folder.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import socket
from pathlib import Path

from evsplat.data.atomic import write_atomic

TMP_PREFIX = ".tmp-"


def cells_dir(out: Path) -> Path:
    return out / "cells"


def log_path(out: Path, key: str) -> Path:
    return out / "logs" / f"{key}.log"


def finished(out: Path, key: str) -> dict | None:
    """The result row of a finished cell, or None."""
    try:
        return json.loads((cells_dir(out) / key / "result.json").read_text())
    except (OSError, ValueError):
        return None


def attempt_dir(out: Path, key: str) -> Path:
    """A fresh folder for this process's attempt at ``key``."""
    tmp = cells_dir(out) / f"{TMP_PREFIX}{key}@{socket.gethostname()}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    return tmp


def publish(tmp: Path, out: Path, key: str) -> None:
    """Rename a complete attempt to its key. If another attempt finished first, keep that one
    and drop this one; a folder named KEY without result.json (copied in by hand, say) is not
    a result and is replaced."""
    final = cells_dir(out) / key
    if final.exists() and finished(out, key) is None:
        shutil.rmtree(final)
    try:
        os.rename(tmp, final)
    except OSError:
        if finished(out, key) is None:
            raise
        shutil.rmtree(tmp, ignore_errors=True)


def running(out: Path, keys: set[str]) -> int:
    """How many of ``keys`` have an attempt folder (in progress, or left by a killed worker and
    waiting for its retry)."""
    try:
        names = os.listdir(cells_dir(out))
    except OSError:
        return 0
    started = {_attempt_key(n) for n in names if n.startswith(TMP_PREFIX)}
    return len(started & keys)


def _attempt_key(name: str) -> str:
    return name[len(TMP_PREFIX) :].split("@", 1)[0]  # keys never hold '@' (Cell.key)


def remove_attempts(out: Path, keys: set[str] | None = None) -> int:
    """Delete the attempt folders of ``keys`` (all when None): left by killed workers, or by
    an attempt that lost the race to a retry. Returns how many were removed."""
    root = cells_dir(out)
    if not root.is_dir():
        return 0
    stale = [
        p
        for p in root.iterdir()
        if p.name.startswith(TMP_PREFIX) and (keys is None or _attempt_key(p.name) in keys)
    ]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def write_table(out: Path, rows: list[dict], meta: dict) -> list[Path]:
    """results.json ({**meta, "rows": rows}) and results.csv (one line per row), atomically."""

    def write_csv(tmp: Path) -> None:
        fields = list(dict.fromkeys(k for r in rows for k in r))
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)

    paths = [out / "results.json", out / "results.csv"]
    write_atomic(paths[0], lambda tmp: tmp.write_text(json.dumps({**meta, "rows": rows}, indent=2)))
    write_atomic(paths[1], write_csv)
    return paths
