"""`evsplat bench large`: a recording far larger than memory, end to end with bounded memory
(issue 24): written by the project's own EVT 3.0 writer (``prophesee_writer``), converted by
`evsplat convert`, checked by `evsplat check`, trained on by `evsplat train --iters N`, each in
a fresh process whose peak resident memory (``ru_maxrss``) is measured; then 50 ms windows
read through the millisecond index at the recording's start, middle and end.

Everything is written to a scratch folder (``--dir``, default the system's temp dir) and
deleted at the end (unless ``--keep``). The sensor is small (64x64 by default) so that the
50 iterations are quick: the point is memory and IO with a huge event file, not the model.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from evsplat.bench.decode import drop_cache, read_all, synthetic_chunks, timed

HELP = "a 500 M-event recording: peak RSS of convert/check/train, window reads at start/middle/end"

#: Pose rate of the dataset folder's poses.txt (as `simulate`'s measured poses).
POSE_RATE_HZ = 100
#: Regions of the recording where windows are read, and the share of its span before each.
REGIONS = {"start": 0.0, "middle": 0.5, "end": 1.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--events", type=int, default=500_000_000, help="events to generate")
    parser.add_argument("--rate", type=float, default=5e6, help="events per second of sensor")
    parser.add_argument("--size", type=int, default=64, help="sensor side in pixels (square)")
    parser.add_argument(
        "--dir", type=Path, default=None, help="scratch folder (default: the system's temp dir)"
    )
    parser.add_argument("--iters", type=int, default=50, help="training iterations")
    parser.add_argument("--preset", default="tiny", help="training preset")
    parser.add_argument("--window-ms", type=float, default=50.0, help="window read length")
    parser.add_argument("--windows", type=int, default=9, help="windows read per region")
    parser.add_argument("--no-check", action="store_true", help="skip `evsplat check`")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")


@dataclass
class Child:
    """One CLI command run in a fresh process."""

    command: str
    wall_s: float
    peak_rss_mb: float  # the child's ru_maxrss (its largest resident set), MiB
    stdout: str


def run_child(argv: list[str], log: Path) -> Child:
    """`evsplat ARGV` in a fresh process (this interpreter), output to ``log``; its peak RSS
    from ``wait4``'s resource usage, which is the child's own (not this process's)."""
    cmd = [sys.executable, "-m", "evsplat.cli", *argv]
    env = {**os.environ, "EVSPLAT_QUIET": "1"}
    with open(log, "w") as out:
        w0 = time.perf_counter()
        child = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - w0
    child.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    text = log.read_text(errors="replace")
    if child.returncode != 0:
        tail = text.strip().splitlines()[-1:] or ["(no output)"]
        raise RuntimeError(f"evsplat {' '.join(argv)} exited {child.returncode}: {tail[0]}")
    return Child(f"evsplat {' '.join(argv)}", wall, usage.ru_maxrss / 1024, text)


def write_dataset_files(folder: Path, width: int, height: int, t0_us: int, t1_us: int) -> None:
    """poses.txt (a slow sideways sway at POSE_RATE_HZ covering [t0, t1]), intrinsics.json and
    meta.json beside the folder's events.h5: a dataset folder (docs/dataset.md)."""
    from evsplat.data.atomic import write_text_atomic
    from evsplat.data.poses import write_tum

    step = 1_000_000 // POSE_RATE_HZ
    times = np.arange(t0_us // step * step, t1_us + 2 * step, step, dtype=np.int64)
    c2w = np.tile(np.eye(4), (len(times), 1, 1))
    c2w[:, 0, 3] = 0.05 * np.sin(times / 1e6)
    write_tum(folder / "poses.txt", times, c2w)
    f = float(width)
    K = [[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]]
    intrinsics = {"K": K, "width": width, "height": height, "distortion": None}
    meta = {
        "width": width,
        "height": height,
        "c_pos": 0.2,
        "c_neg": 0.2,
        "bayer": "mono",
        "t_start_us": int(t0_us),
        "t_end_us": int(t1_us),
        "description": "evsplat bench large: synthetic row runs, not a scene",
    }
    for name, doc in (("intrinsics.json", intrinsics), ("meta.json", meta)):
        write_text_atomic(folder / name, json.dumps(doc, indent=1) + "\n")


def window_starts(t_first: int, t_last: int, length: int, count: int) -> dict[str, list[int]]:
    """``count`` window starts per region, spread so that no two windows share an HDF5 chunk
    (each read decompresses its own), all inside [t_first, t_last]."""
    room = t_last - t_first - length
    stride = max(length, min(1_000_000, room // (4 * count)))
    block = stride * (count - 1)
    starts = {}
    for name, share in REGIONS.items():
        base = t_first + int(share * max(room - block, 0))
        starts[name] = [base + j * stride for j in range(count)]
    return starts


def time_windows(path: Path, length_us: int, count: int, cold: bool) -> dict[str, dict]:
    """Per region: median ms of a window read, events in a window, events the file gave per
    read (the index's cost: the window plus its two end milliseconds). ``cold``: the file's
    pages dropped from the page cache before each read."""
    from evsplat.data.event_store import open_store

    rows = {}
    with open_store(path) as store:
        starts = window_starts(store.t_first_us, store.t_last_us, length_us, count)
        for name, region in starts.items():
            ms, events, cost = [], [], []
            for t0 in region:
                if cold:
                    drop_cache(path)
                before = store.events_read
                w0 = time.perf_counter()
                ev = store.read(t0, t0 + length_us)
                ms.append((time.perf_counter() - w0) * 1e3)
                events.append(len(ev))
                cost.append(store.events_read - before)
            rows[name] = {
                "at_s": (region[0] - store.t_first_us) / 1e6,
                "median_ms": float(np.median(ms)),
                "min_ms": float(np.min(ms)),
                "max_ms": float(np.max(ms)),
                "events": int(np.median(events)),
                "events_read": int(np.median(cost)),
            }
    return rows


def measure(args: argparse.Namespace, tmp: Path) -> dict:
    from evsplat.data.event_store import open_store
    from evsplat.data.formats import prophesee_writer

    raw, data, run = tmp / "large.raw", tmp / "data", tmp / "run"
    data.mkdir()
    side = args.size
    chunks = synthetic_chunks(args.events, args.rate, args.seed, width=side, height=side)
    w0 = time.perf_counter()
    raw_bytes = prophesee_writer.write_recording(raw, "evt3", side, side, chunks)
    result: dict = {"events": args.events, "raw_bytes": raw_bytes, "sensor": side}
    result["generate_s"] = time.perf_counter() - w0
    result["disk_read_direct_s"] = timed(lambda: read_all(raw, direct=True))[0]
    events_h5 = data / "events.h5"
    convert = run_child(["convert", str(raw), str(events_h5)], tmp / "convert.log")
    said = re.search(r"in ([\d.]+) s", convert.stdout)
    result["convert_own_s"] = float(said.group(1)) if said else float("nan")
    result["h5_bytes"] = events_h5.stat().st_size
    raw.unlink()  # the recording's disk space, before training needs none of it
    with open_store(events_h5) as store:
        t_first, t_last = store.t_first_us, store.t_last_us
    write_dataset_files(data, side, side, t_first, t_last + 1)
    result["span_s"] = (t_last + 1 - t_first) / 1e6
    children = [convert]
    if not args.no_check:
        children.append(run_child(["check", str(data)], tmp / "check.log"))
    train = ["train", str(data), "--out", str(run), "--preset", args.preset]
    train += ["--iters", str(args.iters), "--depth-prior", "none", "--no-progress"]
    children.append(run_child(train, tmp / "train.log"))
    result["children"] = [asdict(c) | {"stdout": c.stdout[-400:]} for c in children]
    length = round(args.window_ms * 1000)
    result["windows_warm"] = time_windows(events_h5, length, args.windows, cold=False)
    result["windows_cold"] = time_windows(events_h5, length, args.windows, cold=True)
    return result


def run(args: argparse.Namespace) -> int:
    if args.dir is not None:
        args.dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=args.dir, prefix="evsplat-bench-large-"))
    try:
        result = measure(args, tmp)
    finally:
        if args.keep:
            print(f"kept {tmp}", file=sys.stderr)
        else:
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    result["load_average"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(result))
    else:
        print(report(result, args))
    return 0


def report(r: dict, args: argparse.Namespace) -> str:
    """The results as the tables docs/benchmarks.md shows."""
    n, mb = r["events"], 1e6
    disk = r["raw_bytes"] / r["disk_read_direct_s"] / mb
    lines = [
        f"evsplat bench large: {n:,} events ({r['span_s']:.1f} s at {args.rate / 1e6:g} M ev/s, "
        f"{r['sensor']}x{r['sensor']} sensor); EVT 3.0 file {r['raw_bytes'] / mb:,.0f} MB, "
        f"events.h5 {r['h5_bytes'] / mb:,.0f} MB; load average {r['load_average']:.1f} on "
        f"{os.cpu_count()} CPUs",
        f"generate + write (numpy): {r['generate_s']:.1f} s "
        f"({n / r['generate_s'] / mb:.1f} M ev/s)",
        f"disk read of the EVT 3.0 file, O_DIRECT: {r['disk_read_direct_s']:.1f} s "
        f"({disk:,.0f} MB/s)",
        f"convert (its own time): {r['convert_own_s']:.1f} s, "
        f"{n / r['convert_own_s'] / mb:.1f} M ev/s, "
        f"{r['raw_bytes'] / r['convert_own_s'] / mb:,.0f} MB/s of input "
        f"({r['raw_bytes'] / r['convert_own_s'] / mb / disk:.2f}x disk)",
        "",
        f"{'command':<60} {'wall s':>8} {'peak RSS MiB':>13}",
    ]
    for c in r["children"]:
        command = re.sub(r"/\S*/", "", c["command"])[:60]
        lines.append(f"{command:<60} {c['wall_s']:>8.1f} {c['peak_rss_mb']:>13,.0f}")
    for kind in ("warm", "cold"):
        rows = r[f"windows_{kind}"]
        medians = [v["median_ms"] for v in rows.values()]
        lines += [
            "",
            f"{args.window_ms:g} ms window reads, page cache {kind} "
            f"({args.windows} windows per region, median; max/min of the medians "
            f"{max(medians) / max(min(medians), 1e-9):.2f})",
            f"{'region':<8} {'from s':>8} {'median ms':>10} {'min':>8} {'max':>8} "
            f"{'events':>9} {'read':>9}",
        ]
        for name, v in rows.items():
            lines.append(
                f"{name:<8} {v['at_s']:>8.1f} {v['median_ms']:>10.2f} {v['min_ms']:>8.2f} "
                f"{v['max_ms']:>8.2f} {v['events']:>9,} {v['events_read']:>9,}"
            )
    lines.append(
        "'read': events the file gave per window read (the window, plus its two end "
        "milliseconds read to locate it); peak RSS: each child's ru_maxrss."
    )
    return "\n".join(lines)
