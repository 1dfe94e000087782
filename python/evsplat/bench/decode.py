"""`evsplat bench decode`: the recording decoders (Prophesee EVT 2.0, EVT 3.0, DAT; ROS 1 bags,
uncompressed and LZ4; ROS 2 MCAP, uncompressed, Zstd chunks, split over two files and zstd per
message or per file; ROS 2 SQLite bags, uncompressed and zstd per message or per file; AEDAT 4,
LZ4) against the disk and the reference decoders, on a recording generated for the run (deleted
after it).

Per format, all in one run on the same file: the disk's sequential read speed (once with the
file's pages dropped from the page cache by ``posix_fadvise(DONTNEED)`` after an ``fsync``:
"cold", though a VM's host may still cache it; once warm), the project's Rust decoder
(``_core.EventFileDecoder``, ``_core.BagEventDecoder``, ``_core.McapEventDecoder``,
``_core.Db3EventDecoder``, ``_core.Aedat4EventDecoder``; warm and cold, its opening included)
and the reference decoder (``evt3`` for EVT 3.0, ``expelliarmus`` for EVT 2.0 and DAT,
``aedat`` for AEDAT 4, for bags ``rosbags``' reader with the byte views evsplat used before its
Rust readers: rosbags' deserialiser, one Python object per event, is far too slow for these
sizes), warm; with ``--convert``, ``evsplat convert`` end to end with and without compression
and the SHA-256 of the file it computes alongside. Each decoder's events are summed (count, x,
y, t, p) and compared with the generator's.
"""

from __future__ import annotations

import argparse
import json
import mmap
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from evsplat.data.formats import Chunk, prophesee_writer
from evsplat.data.formats.recording_writers import write_aedat4, write_bag, write_ros2

HELP = (
    "recording decoders (EVT 2.0/3.0, DAT, ROS 1 bags, ROS 2 MCAP and .db3, AEDAT 4): Rust vs "
    "the field's decoders vs the disk's read speed"
)

FORMATS = (
    "evt3", "evt2", "dat", "bag", "bag-lz4", "mcap", "mcap-zstd", "mcap-split", "mcap-message",
    "mcap-file", "db3", "db3-message", "db3-file", "aedat4",
)  # fmt: skip
#: The field's decoder each format is compared with.
REFERENCES = {
    "evt3": "evt3",
    "evt2": "expelliarmus",
    "dat": "expelliarmus",
    "bag": "rosbags",
    "bag-lz4": "rosbags",
    "mcap": "rosbags",
    "mcap-zstd": "rosbags",
    "mcap-split": "rosbags",
    "mcap-message": "rosbags",
    "mcap-file": "rosbags",
    "db3": "rosbags",
    "db3-message": "rosbags",
    "db3-file": "rosbags",
    "aedat4": "aedat",
}
#: Bytes per read when timing the disk.
READ_BLOCK = 8 << 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--events", type=int, default=50_000_000, help="events per recording")
    parser.add_argument(
        "--formats", default=",".join(FORMATS), help=f"comma-separated: {', '.join(FORMATS)}"
    )
    parser.add_argument(
        "--dir", type=Path, default=None, help="where the recordings go (default: a temp dir)"
    )
    parser.add_argument("--rate", type=float, default=10e6, help="events per second of sensor")
    parser.add_argument("--convert", action="store_true", help="also time `evsplat convert`")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per row (best kept)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")


def synthetic_chunks(
    n: int, rate: float, seed: int, size: int = 1 << 20, width: int = 1280, height: int = 720
) -> Iterator[Chunk]:
    """``n`` events on a ``width`` x ``height`` sensor at ``rate`` events/s, in row runs (an
    edge crossing a row fires a few neighbouring pixels at once, mean run 4 px, cut at the
    sensor's edge) sorted by time."""
    rng = np.random.default_rng(seed)
    margin = min(64, width // 4)
    t0 = 0
    done = 0
    while done < n:
        runs = rng.geometric(0.25, size // 4)
        count = int(min(runs.sum(), n - done))
        first = np.repeat(np.cumsum(runs) - runs, runs)[:count]
        run_id = np.repeat(np.arange(len(runs)), runs)[:count]
        span = count / rate * 1e6
        t_run = t0 + np.sort(rng.integers(0, max(1, int(span)), len(runs)))
        y_run = rng.integers(0, height, len(runs))
        x_run = rng.integers(0, width - margin, len(runs))
        x = np.minimum(x_run[run_id] + np.arange(count) - first, width - 1).astype(np.uint16)
        p = rng.integers(0, 2, count).astype(np.int8)
        yield x, y_run[run_id].astype(np.uint16), t_run[run_id], p
        t0, done = int(t_run[-1]) + 1, done + count


class Sums:
    """Count and column sums of a decoded stream, to compare decoders without storing events."""

    def __init__(self) -> None:
        self.values = np.zeros(5, np.int64)

    def add(self, x, y, t, p) -> None:
        cols = (x, y, t, np.asarray(p) > 0)
        self.values += [len(t), *(int(np.sum(c, dtype=np.int64)) for c in cols)]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sums) and bool(np.array_equal(self.values, other.values))


def drop_cache(path: Path) -> None:
    """Asks the kernel to forget the file's cached pages (clean ones only: fsync first)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def read_all(path: Path, direct: bool = False) -> None:
    """Reads the file through; ``direct``: with O_DIRECT, past the page cache (the device's
    own speed)."""
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECT if direct else 0))
    buf = mmap.mmap(-1, READ_BLOCK)  # page-aligned, as O_DIRECT needs
    try:
        while os.readv(fd, [buf]) == READ_BLOCK:
            pass
    finally:
        os.close(fd)
        buf.close()


def drain(chunks: Callable[[], Iterator[Chunk]], sums: Sums) -> tuple[float, float]:
    """Opens the reader (``chunks()``: a .db3 reader reads up to its first chunk there, and
    unpacks a compressed file) and sums every chunk; returns the wall and CPU seconds spent
    opening and producing them (the sums, the check, not counted)."""
    w0, c0 = time.perf_counter(), time.process_time()
    it = chunks()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    while True:
        w0, c0 = time.perf_counter(), time.process_time()
        chunk = next(it, None)
        wall, cpu = wall + time.perf_counter() - w0, cpu + time.process_time() - c0
        if chunk is None:
            return wall, cpu
        sums.add(*chunk)


def rust_chunks(path: Path) -> Iterator[Chunk]:
    """The project's decoder, through the reader `convert` uses."""
    from evsplat.data.formats import open_source

    return open_source(path).chunks


def reference_chunks(path: Path, encoding: str) -> Iterator[Chunk]:
    """The field's decoder (ImportError when it is not installed)."""
    if encoding == "aedat4":
        import aedat

        decoder = aedat.Decoder(str(path))
        for packet in decoder:
            if packet["stream_id"] == 0 and "events" in packet:
                ev = packet["events"]
                yield ev["x"], ev["y"], ev["t"], ev["on"]
    elif encoding.startswith(("bag", "mcap", "db3")):
        from evsplat.data.formats import event_arrays, rosbag

        reader = rosbag._open(path)
        conns = [c for c in reader.connections if c.msgtype in rosbag.EVENT_TYPES]
        yield from event_arrays.event_chunks(reader, conns)
    elif encoding == "evt3":
        import evt3

        for ev in evt3.decode_file_batches(str(path), batch_bytes=8 << 20):
            yield ev.x, ev.y, ev.timestamp, ev.polarity
    else:
        import expelliarmus

        wizard = expelliarmus.Wizard(encoding=encoding, fpath=path, chunk_size=1 << 20)
        for a in wizard.read_chunk():
            yield a["x"], a["y"], a["t"], a["p"]


def timed(
    fn: Callable[[], object], repeat: int = 1, before: Callable[[], object] | None = None
) -> tuple[float, float]:
    """Best wall s and best CPU s (this process) over ``repeat`` calls, each after ``before``."""
    wall, cpu = [], []
    for _ in range(max(1, repeat)):
        if before is not None:
            before()
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def timed_decode(
    chunks: Callable[[], Iterator[Chunk]], repeat: int, before: Callable[[], object] | None = None
) -> tuple[float, float, Sums]:
    """Best decoding wall and CPU s over ``repeat`` passes, and the last pass's sums."""
    runs = []
    for _ in range(max(1, repeat)):
        if before is not None:
            before()
        sums = Sums()
        runs.append((*drain(chunks, sums), sums))
    return min(r[0] for r in runs), min(r[1] for r in runs), runs[-1][2]


def convert_once(path: Path, out: Path, codec: str) -> tuple[float, float]:
    """`evsplat convert` in a fresh process: (the conversion's own seconds, as it prints
    them; the process's wall seconds, start-up and imports included)."""
    cmd = [sys.executable, "-m", "evsplat.cli", "convert", str(path), str(out)]
    w0 = time.perf_counter()
    done = subprocess.run([*cmd, "--compression", codec], capture_output=True, text=True)
    process = time.perf_counter() - w0
    out.unlink(missing_ok=True)
    said = re.search(r"wrote \d+ events to .* in ([\d.]+) s", done.stdout)
    if done.returncode or said is None:
        raise RuntimeError(f"evsplat convert {path} failed: {done.stderr.strip()}")
    return float(said.group(1)), process


def measure_format(args: argparse.Namespace, encoding: str, folder: Path) -> list[dict]:
    suffix = {"dat": "dat", "bag": "bag", "bag-lz4": "bag", "aedat4": "aedat4"}.get(encoding, "raw")
    path = folder / f"bench.{suffix}"
    want = Sums()

    def chunks() -> Iterator[Chunk]:
        for c in synthetic_chunks(args.events, args.rate, args.seed):
            want.add(*c)
            yield c

    w0 = time.perf_counter()
    if encoding.startswith(("mcap", "db3")):  # a ROS 2 bag is a folder: its files are timed
        path = folder / encoding
        storage = "mcap" if encoding.startswith("mcap") else "sqlite3"
        compression = {"zstd": "storage", "message": "message", "file": "file"}
        mode = compression.get(encoding.partition("-")[2], "none")
        split_at = args.events // 2 if encoding == "mcap-split" else None
        files = write_ros2(path, chunks(), 1280, 720, storage, mode, split_at)
    elif encoding == "aedat4":
        files = [path]
        write_aedat4(path, chunks(), 1280, 720)
    elif encoding.startswith("bag"):
        files = [path]
        write_bag(path, chunks(), 1280, 720, lz4=encoding == "bag-lz4")
    else:
        files = [path]
        prophesee_writer.write_recording(path, encoding, 1280, 720, chunks())
    gen_s = time.perf_counter() - w0
    size = sum(f.stat().st_size for f in files)
    n = int(want.values[0])
    rows = []

    def row(what: str, wall: float, cpu: float, same: bool | None = None) -> None:
        rows.append(
            {
                "format": encoding,
                "what": what,
                "events": n,
                "bytes": size,
                "wall_s": wall,
                "cpu_s": cpu,
                "same": same,
            }
        )

    row("generate + write (numpy)", gen_s, gen_s)
    r = args.repeat

    def cold() -> None:
        for f in files:
            drop_cache(f)

    def read(direct: bool = False) -> None:
        for f in files:
            read_all(f, direct)

    row("disk read, O_DIRECT", *timed(lambda: read(direct=True), r))
    row("disk read, cold", *timed(read, r, cold))
    row("disk read, warm", *timed(read, r))
    wall, cpu, got = timed_decode(lambda: rust_chunks(path), r)
    row("rust decoder, warm", wall, cpu, got == want)
    reference = REFERENCES[encoding]
    try:
        wall, cpu, ref = timed_decode(lambda: reference_chunks(path, encoding), r)
        row(f"{reference}, warm", wall, cpu, ref == want)
    except ImportError:
        print(f"{reference} is not installed: no reference row for {encoding}")
    wall, cpu, got = timed_decode(lambda: rust_chunks(path), r, cold)
    row("rust decoder, cold", wall, cpu, got == want)
    if args.convert:
        from evsplat.data.provenance import source_digest

        row("sha256 of the file", *timed(lambda: source_digest(path)))
        for codec in ("none", "blosc"):
            conversion, process = convert_once(path, folder / f"bench-{codec}.h5", codec)
            row(f"convert --compression {codec}", conversion, float("nan"))
            row("  the whole process", process, float("nan"))
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()
    return rows


def run(args: argparse.Namespace) -> int:
    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    if unknown := sorted(set(formats) - set(FORMATS)):
        raise SystemExit(f"--formats: {', '.join(unknown)} unknown; use {', '.join(FORMATS)}")
    if args.dir is not None:
        args.dir.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="evsplat-bench-decode-") as tmp:
        for encoding in formats:
            rows += measure_format(args, encoding, Path(tmp))
    if args.json:
        print(json.dumps(rows))
        return 0
    print(
        f"evsplat bench decode: {args.events:,} events per format at {args.rate / 1e6:g} M ev/s "
        f"of sensor time, 1280x720; best of {args.repeat}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print(table(rows))
    print(
        "O_DIRECT: past the page cache (the device); cold: the file's cached pages dropped first "
        "(a VM's host may still cache them); warm: in the page cache (a bag's files: all of them). "
        "'x disk': wall time against the O_DIRECT read of the same file in this run. Decoder rows "
        "time the reader's opening and decoding, not the checks; 'same': count and sums of x, y, "
        "t, p equal to the generated events. convert runs once, "
        "in a fresh process: its own time as it prints it, then the whole process's."
    )
    return 0


def table(rows: list[dict]) -> str:
    head = (
        f"{'format':<11} {'what':<28} {'wall s':>8} {'cpu s':>8} {'M ev/s':>8} {'MB/s':>8} "
        f"{'M ev/s/cpu':>10} {'x disk':>7} same"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        disk = next(
            d["wall_s"]
            for d in rows
            if d["format"] == r["format"] and d["what"] == "disk read, O_DIRECT"
        )
        same = "" if r["same"] is None else ("yes" if r["same"] else "NO")
        cpu = f"{r['cpu_s']:>8.3f}" if r["cpu_s"] == r["cpu_s"] else f"{'-':>8}"
        per_cpu = r["events"] / max(r["cpu_s"], 1e-9) / 1e6 if r["cpu_s"] == r["cpu_s"] else None
        lines.append(
            f"{r['format']:<11} {r['what']:<28} {r['wall_s']:>8.3f} {cpu} "
            f"{r['events'] / r['wall_s'] / 1e6:>8.1f} {r['bytes'] / r['wall_s'] / 1e6:>8.0f} "
            f"{'-' if per_cpu is None else f'{per_cpu:.1f}':>10} {disk / r['wall_s']:>7.2f} {same}"
        )
    return "\n".join(lines)
