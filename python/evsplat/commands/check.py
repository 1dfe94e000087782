"""`evsplat check DATA`: validate a dataset folder (or one HDF5 event file), one line per
problem: every event, and the millisecond index against the timestamps, in one streaming
pass. Also prints what the event file holds and where it came from (its provenance)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from evsplat.data.event_store import EventStore

HELP = (
    "validate a dataset folder (events and their index, poses, intrinsics, meta, test frames) "
    "or an event .h5; exit 2 on problems"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="dataset folder (see docs/dataset.md) or an event .h5 file")


def describe(store: EventStore) -> list[str]:
    """What an event file holds, its index, and its provenance, one line each."""
    if store.count:
        span = (store.t_last_us - store.t_first_us) / 1e6
        when = f"from {store.t_first_us} to {store.t_last_us} µs ({span:.3f} s)"
    else:
        when = "(empty)"
    lines = [
        f"{store.path}: {store.count:,} events {when}, sensor {store.width}x{store.height}",
        f"  ms index: {len(store.ms_to_idx):,} entries from {store.origin} µs, "
        f"{store.index_source}",
    ]
    prov = store.provenance
    if not prov:
        lines.append("  provenance: none recorded (written by `evsplat simulate` or another tool)")
        return lines
    lines.append(
        f"  provenance: converted from {prov.get('source')} ({prov.get('source_bytes'):,} bytes, "
        f"sha256 {prov.get('source_sha256')})"
    )
    cut = prov.get("bytes_dropped", 0)
    lines.append(
        f"  by {prov.get('converter')} with {prov.get('decoder')} (format {prov.get('format')}): "
        f"{prov.get('events'):,} events written, {prov.get('events_dropped'):,} dropped"
        + (f", the last {cut} B (a truncated record) dropped" if cut else "")
    )
    return lines


def hot_pixel_line(store: EventStore, listed: int = 8) -> str:
    """One line on the event file's hot pixels (``data.hot_pixels``): how many, and where."""
    from evsplat.data.hot_pixels import hot_pixel_map

    ys, xs = hot_pixel_map(store, [(store.t_first_us, store.t_last_us + 1)]).nonzero()
    if not len(xs):
        return "  hot pixels: none"
    at = ", ".join(f"({x}, {y})" for x, y in zip(xs[:listed].tolist(), ys[:listed].tolist()))
    more = f" and {len(xs) - listed} more" if len(xs) > listed else ""
    return f"  hot pixels: {len(xs)} at (x, y) {at}{more}; training leaves their events out"


def run(args: argparse.Namespace) -> int:
    from evsplat.data.dataset import verify_dataset
    from evsplat.data.event_store import verify_store
    from evsplat.data.poses import is_static_camera

    path = Path(args.path)
    data = None
    if path.is_file() and path.suffix.lower() in (".h5", ".hdf5"):
        problems, store = verify_store(path)
    else:
        problems, data = verify_dataset(path)
        store = data.events if data else None
    if store is not None:
        print("\n".join(describe(store)))
        if not problems and store.count:
            print(hot_pixel_line(store))
    if data is not None and is_static_camera(data.meta):
        print(
            f"  static camera: identity pose over [{data.t_start_us}, {data.t_end_us}] µs "
            "(meta.json; no poses.txt)"
        )
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        print(f"{args.path}: {len(problems)} problem(s)", file=sys.stderr)
        return 2
    print(f"{args.path}: ok")
    return 0
