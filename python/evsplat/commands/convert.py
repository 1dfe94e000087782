"""`evsplat convert IN OUT.h5`: any event recording -> the project's HDF5 layout, streaming.

Sensor recordings (AEDAT 4, Prophesee RAW/DAT, ROS bags) are converted chunk by chunk, so a
recording larger than memory converts; the other event files are read whole. A bag's
``geometry_msgs/PoseStamped`` topic can be written alongside as a TUM pose file."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

HELP = "convert an event recording (AEDAT4, Prophesee RAW/DAT, ROS bag, h5, npz, txt) to HDF5"

#: HDF5 chunk length (events) of the output datasets, and events validated and written at once.
H5_CHUNK = 1 << 18
BATCH = 1 << 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", type=Path, help="recording (.aedat4 .raw .dat .bag .mcap, ...)")
    parser.add_argument("output", type=Path, help="output .h5 (DSEC layout events/{x,y,t,p})")
    parser.add_argument(
        "--topic", default=None, help="event topic of a bag (default: the only one)"
    )
    parser.add_argument(
        "--poses", type=Path, default=None, help="also write the bag's PoseStamped poses (TUM)"
    )
    parser.add_argument("--pose-topic", default=None, help="pose topic (default: the only one)")
    parser.add_argument(
        "--compression", default="gzip", choices=("gzip", "lzf", "none"), help="HDF5 codec"
    )


def _batched(chunks, size: int):
    """Joins small chunks (a bag message holds a few thousand events) into ~``size`` events,
    so per-chunk validation and HDF5 resizes are paid rarely."""
    parts, n = [], 0
    for c in chunks:
        parts.append(c)
        n += len(c[0])
        if n >= size:
            yield tuple(np.concatenate([p[i] for p in parts]) for i in range(4))
            parts, n = [], 0
    if parts:
        yield tuple(np.concatenate([p[i] for p in parts]) for i in range(4))


def convert(
    src: Path,
    out: Path,
    *,
    topic: str | None = None,
    compression: str = "gzip",
    progress: bool = True,
) -> tuple[int, float]:
    """Converts ``src`` to ``out`` (written atomically); returns (events, seconds)."""
    import h5py
    from tqdm import tqdm

    from evsplat.data import formats
    from evsplat.data.event_files import read_events
    from evsplat.data.events import EventStream
    from evsplat.errors import EvsplatError

    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise EvsplatError(f"{out}: output must be .h5 or .hdf5")
    if out.resolve() == src.resolve():
        raise EvsplatError(f"{out}: output is the input; pick another output path")
    if not out.parent.is_dir():
        raise EvsplatError(f"{out}: directory {out.parent} does not exist; create it first")
    start = time.perf_counter()
    if formats.is_sensor_format(src):
        source = formats.open_source(src, topic=topic)
        width, height, chunks = source.width, source.height, source.chunks
        kind = source.format
    else:
        if topic is not None:
            raise EvsplatError(f"{src}: --topic applies to ROS bags only")
        ev = read_events(src)
        width, height, chunks = ev.width, ev.height, iter([(ev.x, ev.y, ev.t, ev.p)])
        kind = src.suffix.lstrip(".").lower()
    codec = {"gzip": {"compression": "gzip"}, "lzf": {"compression": "lzf"}, "none": {}}
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    n, last_t = 0, None
    try:
        with (
            h5py.File(tmp, "w") as f,
            tqdm(
                unit="ev",
                unit_scale=True,
                desc=f"convert {src.name} ({kind})",
                disable=not progress,
            ) as bar,
        ):
            f.attrs["width"], f.attrs["height"] = width, height
            group = f.create_group("events")
            dtypes = {"x": np.uint16, "y": np.uint16, "t": np.int64, "p": np.int8}
            dsets = {
                k: group.create_dataset(
                    k,
                    shape=(0,),
                    maxshape=(None,),
                    dtype=dt,
                    chunks=(H5_CHUNK,),
                    **codec[compression],
                )
                for k, dt in dtypes.items()
            }
            for x, y, t, p in _batched(chunks, BATCH):
                if len(t) == 0:
                    continue
                # Validation and canonical dtypes per chunk; order across chunks checked here.
                ev = EventStream.from_arrays(x, y, t, p, width, height, str(src))
                if last_t is not None and ev.t[0] < last_t:
                    raise EvsplatError(
                        f"{src}: events go back in time at event {n} ({ev.t[0]} µs after "
                        f"{last_t} µs); the recording's packets are out of order"
                    )
                for k in "xytp":
                    d = dsets[k]
                    d.resize((n + len(ev),))
                    d[n:] = getattr(ev, k)
                n += len(ev)
                last_t = int(ev.t[-1])
                bar.update(len(ev))
        if n == 0:
            raise EvsplatError(f"{src}: the recording holds no events; nothing to convert")
        os.replace(tmp, out)
    except OSError as e:
        raise EvsplatError(f"{out}: cannot write ({' '.join(str(e).split())})") from None
    finally:
        tmp.unlink(missing_ok=True)
    return n, time.perf_counter() - start


def run(args: argparse.Namespace) -> int:
    from evsplat.data.formats import rosbag
    from evsplat.data.poses import write_tum
    from evsplat.errors import EvsplatError

    if (args.poses is not None or args.pose_topic is not None) and not rosbag.is_bag(args.input):
        raise EvsplatError(f"{args.input}: --poses/--pose-topic read poses from ROS bags only")
    n, seconds = convert(args.input, args.output, topic=args.topic, compression=args.compression)
    print(
        f"wrote {n} events to {args.output} in {seconds:.2f} s ({n / max(seconds, 1e-9):,.0f} ev/s)"
    )
    if args.poses is not None:
        times, c2w = rosbag.read_bag_poses(args.input, topic=args.pose_topic)
        write_tum(args.poses, times, c2w)
        print(f"wrote {len(times)} poses to {args.poses}")
    return 0
