"""Recordings written in the formats `evsplat bench decode` times, from generated event
chunks: ROS 1 bags and ROS 2 bags (MCAP or SQLite) through rosbags, AEDAT 4 through
dv-processing's header and packets built here. The messages and packets are serialised with
numpy: the writers' own serialisers build one Python object per event."""

from __future__ import annotations

import struct
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from evsplat.data.formats import Chunk

#: Events per AEDAT 4 packet of a generated file.
AEDAT_PACKET_EVENTS = 10_000
#: An AEDAT 4 event struct: t, x, y, on and 3 bytes of padding.
AEDAT_EVENT = np.dtype(
    {
        "names": ["t", "x", "y", "on"],
        "formats": ["<i8", "<i2", "<i2", "u1"],
        "offsets": [0, 8, 10, 12],
        "itemsize": 16,
    }
)
#: Events per EventArray message of a generated bag (a 10 M ev/s sensor's ~1 ms).
BAG_MESSAGE_EVENTS = 10_000


def write_bag(path: Path, chunks: Iterator[Chunk], width: int, height: int, lz4: bool) -> int:
    """A ROS 1 bag written by rosbags: one dvs_msgs/EventArray topic, messages of
    ``BAG_MESSAGE_EVENTS`` serialised here with numpy (rosbags' serialiser builds one object
    per event), chunks of 1 MiB, uncompressed or LZ4. Returns the file's size."""
    from rosbags.rosbag1 import Writer

    from evsplat.data.formats import event_arrays, rosbag

    store = rosbag.typestore(ros1=True)
    writer = Writer(path)
    if lz4:
        writer.set_compression(Writer.CompressionFormat.LZ4)
    with writer:
        conn = writer.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        for seq, (x, y, t, p) in enumerate(chunks):
            for i in range(0, len(t), BAG_MESSAGE_EVENTS):
                sl = slice(i, i + BAG_MESSAGE_EVENTS)
                rec = np.empty(len(t[sl]), event_arrays.ROS1_EVENT)
                tt = np.asarray(t[sl], np.int64)
                rec["x"], rec["y"], rec["p"] = x[sl], y[sl], p[sl]
                rec["sec"], rec["nsec"] = tt // 1_000_000, tt % 1_000_000 * 1000
                stamp = int(tt[-1])
                head = struct.pack(
                    "<IIII3sIII", seq, stamp // 10**6, stamp % 10**6 * 1000, 3, b"cam",
                    height, width, len(rec),
                )  # fmt: skip
                writer.write(conn, stamp * 1000, head + rec.tobytes())
    return path.stat().st_size


def write_ros2(
    folder: Path,
    chunks: Iterator[Chunk],
    width: int,
    height: int,
    storage: str = "mcap",
    compression: str = "none",
    split_at: int | None = None,
) -> list[Path]:
    """A ROS 2 bag in ``folder``, in MCAP or SQLite (``storage`` "sqlite3"), written by
    rosbags: one dvs_msgs/EventArray topic, messages of ``BAG_MESSAGE_EVENTS`` serialised in
    CDR here with numpy, MCAP chunks of 1 MiB; ``compression`` "storage" (MCAP's Zstd chunks),
    "message" or "file" (rosbag2's zstd of each message or file) or "none". ``split_at``: the
    messages from that event on go into a second file (rosbags' Writer does not split: a
    second bag, its file moved into ``folder`` and listed in its metadata.yaml, as rosbag2
    lists a split bag's files). Returns the bag's files, as its metadata lists them."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    from evsplat.data.formats import event_arrays, rosbag

    store = rosbag.typestore()
    kind = "dvs_msgs/msg/EventArray"

    def writer(path: Path, stack: ExitStack) -> tuple[Writer, object]:
        w = Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
        if compression != "none":
            w.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
        stack.enter_context(w)
        return w, w.add_connection("/dvs/events", kind, typestore=store)

    bags = [folder] if split_at is None else [folder, folder.with_name(f"{folder.name}-part")]
    done = 0
    with ExitStack() as stack:
        writers = [writer(b, stack) for b in bags]
        for x, y, t, p in chunks:
            for i in range(0, len(t), BAG_MESSAGE_EVENTS):
                sl = slice(i, i + BAG_MESSAGE_EVENTS)
                tt = np.asarray(t[sl], np.int64)
                parts = []
                for dtype, rows in (
                    (event_arrays.CDR_FIRST_EVENT, slice(0, 1)),
                    (event_arrays.CDR_EVENT, slice(1, None)),
                ):
                    rec = np.zeros(len(tt[rows]), dtype)
                    rec["x"], rec["y"], rec["p"] = x[sl][rows], y[sl][rows], p[sl][rows]
                    rec["sec"], rec["nsec"] = tt[rows] // 1_000_000, tt[rows] % 1_000_000 * 1000
                    parts.append(rec.tobytes())
                stamp = int(tt[-1])
                head = struct.pack(
                    "<4siII4sIII", b"\x00\x01\x00\x00", stamp // 10**6, stamp % 10**6 * 1000,
                    4, b"cam\x00", height, width, len(tt),
                )  # fmt: skip
                w, conn = writers[split_at is not None and done >= split_at]
                w.write(conn, stamp * 1000, head + b"".join(parts))
                done += len(tt)
    if split_at is not None:
        meta = folder / "metadata.yaml"
        (first,) = rosbag.ros2_files(folder, storage).files
        (second,) = rosbag.ros2_files(bags[1], storage).files
        moved = second.rename(folder / f"{first.stem}_1{first.suffix}")
        bags[1].joinpath("metadata.yaml").unlink()
        bags[1].rmdir()
        text = meta.read_text()
        meta.write_text(text.replace(f"- {first.name}", f"- {first.name}\n  - {moved.name}", 1))
    return rosbag.ros2_files(folder, storage).files


def write_aedat4(path: Path, chunks: Iterator[Chunk], width: int, height: int) -> int:
    """An AEDAT 4 file: dv-processing's header for one event stream of this size (LZ4, its
    default; the data table's position cleared), then LZ4-compressed event packets of
    ``AEDAT_PACKET_EVENTS`` built here with numpy (dv-processing takes events one by one from
    Python). Returns the file's size."""
    import dv_processing as dv
    import lz4.frame

    from evsplat import _core

    with tempfile.TemporaryDirectory() as tmp:
        empty = Path(tmp) / "header.aedat4"
        cfg = dv.io.MonoCameraWriter.EventOnlyConfig("DVXplorer_bench", (width, height))
        writer = dv.io.MonoCameraWriter(str(empty), cfg)
        del writer  # closes the file
        compression, table, _, start = _core.aedat4_header(empty)
        head = bytearray(empty.read_bytes()[:start])
    if compression not in (1, 2):
        raise RuntimeError(f"dv-processing wrote compression {compression}, not LZ4")
    if table >= 0:
        at = head.find(struct.pack("<q", table), len(b"#!AER-DAT4.0\r\n") + 4)
        head[at : at + 8] = struct.pack("<q", -1)
    # The packet's flatbuffer before its events, aligned as flatbuffers' verifier wants (the
    # events at a multiple of 8 from the size prefix): root offset, "EVTS", vtable (its size,
    # the table's, field 0 at +4) and 2 bytes of padding, table (soffset 8, vector offset 4).
    fixed = struct.pack("<I4s3H2xiI", 16, b"EVTS", 6, 8, 4, 8, 4)
    with open(path, "wb") as f:
        f.write(head)
        for x, y, t, p in chunks:
            for i in range(0, len(t), AEDAT_PACKET_EVENTS):
                sl = slice(i, i + AEDAT_PACKET_EVENTS)
                rec = np.zeros(len(t[sl]), AEDAT_EVENT)
                rec["t"], rec["x"], rec["y"], rec["on"] = t[sl], x[sl], y[sl], p[sl]
                body = fixed + struct.pack("<I", len(rec)) + rec.tobytes()
                packet = lz4.frame.compress(struct.pack("<I", len(body)) + body)
                f.write(struct.pack("<iI", 0, len(packet)) + packet)
    return path.stat().st_size
