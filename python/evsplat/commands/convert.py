"""`evsplat convert IN OUT.h5`: any event recording -> the project's HDF5 layout, streaming,
with the millisecond index and the source's provenance (path, size, SHA-256, decoder).

Sensor recordings (AEDAT 4, Prophesee RAW/DAT, ROS bags) are converted chunk by chunk, so a
recording larger than memory converts; the other event files are read whole. A bag's
``geometry_msgs/PoseStamped`` topic can be written alongside as a TUM pose file."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

HELP = "convert an event recording (AEDAT4, Prophesee RAW/DAT, ROS bag, h5, npz, txt) to HDF5"

#: Events validated and written at once: a multiple of the writer's HDF5 chunk.
BATCH = 1 << 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from evsplat.data.event_writer import DEFAULT_CODEC, codecs

    parser.add_argument("input", type=Path, help="recording (.aedat4 .raw .dat .bag .mcap, ...)")
    parser.add_argument("output", type=Path, help="output .h5 (DSEC layout events/{x,y,t,p})")
    parser.add_argument(
        "--topic", default=None, help="event topic of a bag (default: the only one)"
    )
    parser.add_argument(
        "--poses", type=Path, default=None, help="also write the bag's PoseStamped poses (TUM)"
    )
    parser.add_argument("--pose-topic", default=None, help="pose topic (default: the only one)")
    camera = parser.add_argument_group(
        "static camera",
        "--static-camera makes OUT's folder a dataset: meta.json (camera static, no poses "
        "needed) and intrinsics.json beside OUT, which must be DIR/events.h5",
    )
    camera.add_argument("--static-camera", action="store_true", help="the camera never moved")
    camera.add_argument("--fx", type=float, default=None, help="focal length px (default a guess)")
    camera.add_argument("--fy", type=float, default=None, help="focal length y (default fx)")
    camera.add_argument("--cx", type=float, default=None, help="principal point x (default w/2)")
    camera.add_argument("--cy", type=float, default=None, help="principal point y (default h/2)")
    camera.add_argument(
        "--contrast", type=float, default=None, help="contrast threshold C (default: a guess)"
    )
    camera.add_argument("--bayer", default="mono", help="colour filter (default mono)")
    parser.add_argument(
        "--compression",
        default=DEFAULT_CODEC,
        choices=sorted(codecs()),
        help=f"HDF5 codec (default {DEFAULT_CODEC}: Blosc LZ4, needs hdf5plugin to read)",
    )


def _batched(chunks, size: int):
    """Re-cuts the chunks into batches of exactly ``size`` events (the last one shorter), so
    per-batch validation and HDF5 resizes are paid rarely (a bag message holds a few thousand
    events) and every write starts on an HDF5 chunk boundary (``size`` is a multiple of the
    writer's chunk: a write that ends mid-chunk makes HDF5 decompress and recompress that
    chunk on the next one). A batch inside one chunk is a view, not a copy."""
    parts, n = [], 0
    for c in chunks:
        start, m = 0, len(c[0])
        while start < m:
            take = min(size - n, m - start)
            parts.append(tuple(a[start : start + take] for a in c))
            n, start = n + take, start + take
            if n == size:
                yield _joined(parts)
                parts, n = [], 0
    if parts:
        yield _joined(parts)


def _ahead(chunks: Iterator[tuple], depth: int = 2) -> Iterator[tuple]:
    """``chunks`` produced by a second thread up to ``depth`` ahead: the Rust readers decode
    and validate with the GIL released, so the next batch is made while this thread writes
    the one before (HDF5 runs here, with the GIL; the default Blosc compression without it).
    Errors reach the caller in order; a caller that stops early stops the thread at its next
    chunk."""
    import queue
    import threading

    done = object()
    slots: queue.Queue = queue.Queue(depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                slots.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for c in chunks:
                if not put((c, None)):
                    return
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            put((None, e))
            return
        put((done, None))

    thread = threading.Thread(target=produce, name="evsplat-convert-ahead", daemon=True)
    thread.start()
    try:
        while True:
            c, error = slots.get()
            if error is not None:
                raise error
            if c is done:
                return
            yield c
    finally:
        stop.set()
        thread.join()


def _joined(parts: list) -> tuple:
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(4))


def convert(
    src: Path,
    out: Path,
    *,
    topic: str | None = None,
    compression: str | None = None,
    progress: bool = True,
    ahead: bool = True,
) -> tuple[int, float]:
    """Converts ``src`` to ``out`` (written atomically, with its millisecond index and the
    provenance of ``src``; ``compression`` defaults to the writer's); returns (events,
    seconds). ``ahead``: decode the next batch on a second thread while one is written."""
    from concurrent.futures import Future, ThreadPoolExecutor

    from tqdm import tqdm

    from evsplat.data import formats
    from evsplat.data.event_files import read_events
    from evsplat.data.event_writer import DEFAULT_CODEC, write_events
    from evsplat.data.events import EventStream
    from evsplat.data.provenance import provenance, source_digest
    from evsplat.errors import EvsplatError

    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise EvsplatError(f"{out}: output must be .h5 or .hdf5")
    if out.resolve() == src.resolve():
        raise EvsplatError(f"{out}: output is the input; pick another output path")
    if not out.parent.is_dir():
        raise EvsplatError(f"{out}: directory {out.parent} does not exist; create it first")
    start = time.perf_counter()
    dropped = formats.Dropped()
    if formats.is_sensor_format(src):
        source = formats.open_source(src, topic=topic)
        width, height, chunks = source.width, source.height, source.chunks
        kind, decoder, dropped = source.format, source.decoder, source.dropped
    else:
        if topic is not None:
            raise EvsplatError(f"{src}: --topic applies to ROS bags only")
        ev = read_events(src)
        width, height, chunks = ev.width, ev.height, iter([(ev.x, ev.y, ev.t, ev.p)])
        kind, decoder = src.suffix.lstrip(".").lower(), "evsplat"
    record: dict[str, object] = {}

    def validated() -> Iterator[EventStream]:
        for x, y, t, p in _batched(chunks, BATCH):
            # Validation and canonical dtypes per batch; the writer checks order across them.
            yield EventStream.from_arrays(x, y, t, p, width, height, str(src))

    def streams(bar: tqdm, digest: Future[tuple[int, str]]) -> Iterator[EventStream]:
        n = 0
        # Decoded and validated (both without the GIL, in Rust) ahead of the HDF5 writes.
        for ev in _ahead(validated()) if ahead else validated():
            yield ev
            n += len(ev)
            bar.update(len(ev))
        if n == 0:
            raise EvsplatError(f"{src}: the recording holds no events; nothing to convert")
        if (warning := dropped.warning(src)) is not None:
            bar.write(f"warning: {warning}", file=sys.stderr)
        record.update(
            provenance(
                src,
                *digest.result(),
                kind,
                decoder,
                n,
                dropped.events,
                bytes_dropped=dropped.bytes,
                words_skipped=dropped.words,
            )
        )

    bar = tqdm(
        unit="ev", unit_scale=True, desc=f"convert {src.name} ({kind})", disable=not progress
    )
    # The checksum reads the source on a second thread (hashlib releases the GIL) while the
    # decoder reads it on this one.
    with bar, ThreadPoolExecutor(1) as pool:
        digest = pool.submit(source_digest, src)
        n = write_events(
            out,
            width,
            height,
            streams(bar, digest),
            compression=compression or DEFAULT_CODEC,
            provenance=record,
        )
    return n, time.perf_counter() - start


def run(args: argparse.Namespace) -> int:
    from evsplat.data.event_store import open_store
    from evsplat.data.formats import rosbag
    from evsplat.data.poses import write_tum
    from evsplat.data.static_folder import Lens, check_output, write_static_folder
    from evsplat.errors import EvsplatError

    if (args.poses is not None or args.pose_topic is not None) and not rosbag.is_bag(args.input):
        raise EvsplatError(f"{args.input}: --poses/--pose-topic read poses from ROS bags only")
    lens = Lens(args.fx, args.fy, args.cx, args.cy)
    camera_flags = [v for v in (*vars(lens).values(), args.contrast) if v is not None]
    if args.static_camera:
        if args.poses is not None:
            raise EvsplatError(f"{args.poses}: --poses and --static-camera exclude each other")
        check_output(args.output, lens, args.bayer, args.contrast)
    elif camera_flags or args.bayer != "mono":
        raise EvsplatError("--fx/--fy/--cx/--cy/--contrast/--bayer go with --static-camera")
    n, seconds = convert(args.input, args.output, topic=args.topic, compression=args.compression)
    print(
        f"wrote {n} events to {args.output} in {seconds:.2f} s ({n / max(seconds, 1e-9):,.0f} ev/s)"
    )
    if args.static_camera:
        with open_store(args.output) as store:
            size, span = (store.width, store.height), (store.t_first_us, store.t_last_us)
        folder = args.output.parent
        notes = write_static_folder(folder, args.input, size, span, lens, args.bayer, args.contrast)
        for note in notes:
            print(f"warning: {note}", file=sys.stderr)
        print(f"wrote {folder / 'meta.json'} (static camera) and {folder / 'intrinsics.json'}")
    if args.poses is not None:
        times, c2w = rosbag.read_bag_poses(args.input, topic=args.pose_topic)
        write_tum(args.poses, times, c2w)
        print(f"wrote {len(times)} poses to {args.poses}")
    return 0
