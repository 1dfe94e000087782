"""Writes the fuzzers' seed corpus, crates/formats/fuzz/seeds/<encoding>/*.bin: valid event
words (no header) from evsplat.data.formats.prophesee_writer, and ROS 1 bags (rosbag/*.bin)
written by rosbags with each chunk compression, their bag header's 4 KB of padding cut (the
reader skips it by its length; the fuzzers need not mutate it), and AEDAT 4 packets
(aedat4/*.bin) written by dv-processing with each compression: one byte naming the compression
(0 none, 1 LZ4, 2 Zstd; see check::decode_aedat_checked), then the packets after the header;
and ROS 2 MCAP files (mcap/*.bin) written by rosbags, uncompressed and with Zstd chunks.
Run from the repository root:
`python scripts/fuzz_seeds.py`."""

from __future__ import annotations

import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

from evsplat.data.formats.prophesee_writer import Encoder

SEEDS = Path(__file__).resolve().parent.parent / "crates/formats/fuzz/seeds"


def events(seed: int, n: int, t0: int, span: int, width: int = 1280, height: int = 720):
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, span, n))
    return rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n)


def write_bag(path: Path, x, y, t, p, compression: str) -> bytes:
    """A small ROS 1 bag: dvs_msgs/EventArray messages of ~50 events in chunks of ~1 KB, a
    pose topic beside them; returned without the bag header's padding."""
    from rosbags.rosbag1 import Writer

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from test_formats import _event_array, _pose

    from evsplat.data.formats import rosbag

    store = rosbag.typestore(ros1=True)
    writer = Writer(path)
    if compression != "none":
        writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    writer.chunk_threshold = 1024
    with writer:
        conn = writer.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        pose = writer.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=store)
        for part in np.array_split(np.arange(len(x)), max(1, len(x) // 50)):
            stamp = int(t[part[-1]]) + 1
            msg = _event_array(store, "dvs_msgs", x[part], y[part], t[part], p[part], stamp)
            writer.write(conn, stamp * 1000, store.serialize_ros1(msg, "dvs_msgs/msg/EventArray"))
            msg = _pose(store, stamp, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0))
            writer.write(
                pose, stamp * 1000, store.serialize_ros1(msg, "geometry_msgs/msg/PoseStamped")
            )
    data = path.read_bytes()
    # The bag header record after the 13-byte line: header, then its data (the padding).
    (header_len,) = struct.unpack_from("<I", data, 13)
    pad_at = 13 + 4 + header_len
    (pad,) = struct.unpack_from("<I", data, pad_at)
    header = bytearray(data[17:pad_at])
    key = header.find(b"index_pos=")
    (index_pos,) = struct.unpack_from("<Q", header, key + 10)
    struct.pack_into("<Q", header, key + 10, index_pos - pad)
    return data[:17] + bytes(header) + struct.pack("<I", 0) + data[pad_at + 4 + pad :]


def aedat4_packets(path: Path, x, y, t, p, compression: str) -> bytes:
    """dv-processing's AEDAT 4 file of these events (packets of 100), as the fuzz input: the
    compression byte, then the packets (the data table, the header's, dropped)."""
    import dv_processing as dv

    cfg = dv.io.MonoCameraWriter.EventOnlyConfig("DVXplorer_seed", (1280, 720))
    cfg.compression = getattr(dv.CompressionType, compression)
    writer = dv.io.MonoCameraWriter(str(path), cfg)
    for part in np.array_split(np.arange(len(x)), max(1, len(x) // 100)):
        store = dv.EventStore()
        for i in part:
            store.push_back(int(t[i]), int(x[i]), int(y[i]), bool(p[i]))
        writer.writeEvents(store)
    del writer
    from evsplat import _core

    _, table, _, start = _core.aedat4_header(path)
    data = path.read_bytes()
    end = table if table >= 0 else len(data)
    return bytes([{"NONE": 0, "LZ4": 1, "ZSTD": 2}[compression]]) + data[start:end]


def write_mcap(path: Path, x, y, t, p, zstd: bool) -> bytes:
    """A small ROS 2 bag in MCAP: prophesee_event_msgs/EventArray messages of ~50 events and a
    pose topic, in one chunk (rosbags' MCAP writer chunks by 1 MiB); returns the .mcap file."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from test_formats import _event_array, _pose

    from evsplat.data.formats import rosbag

    store = rosbag.typestore()
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if zstd:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    kind = "prophesee_event_msgs/msg/EventArray"
    with writer:
        conn = writer.add_connection("/events", kind, typestore=store)
        pose = writer.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=store)
        for part in np.array_split(np.arange(len(x)), max(1, len(x) // 50)):
            stamp = int(t[part[-1]]) + 1
            msg = _event_array(
                store, "prophesee_event_msgs", x[part], y[part], t[part], p[part], stamp
            )
            writer.write(conn, stamp * 1000, store.serialize_cdr(msg, kind))
            msg = _pose(store, stamp, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0))
            writer.write(
                pose, stamp * 1000, store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped")
            )
    return next(path.glob("*.mcap")).read_bytes()


def main() -> None:
    cases = {
        "sparse": events(1, 200, 1_000_000, 2_000_000),  # new time words for most events
        "dense": events(2, 300, 5_000, 300),  # several events per µs and row
        "wrap": events(3, 200, (1 << 24) - 20_000, 60_000),  # EVT 3.0's 24-bit time wraps
    }
    for encoding in ("evt2", "evt3", "dat"):
        folder = SEEDS / encoding
        folder.mkdir(parents=True, exist_ok=True)
        for name, (x, y, t, p) in cases.items():
            (folder / f"{name}.bin").write_bytes(Encoder(encoding).encode(x, y, t, p))
    folder = SEEDS / "rosbag"
    folder.mkdir(parents=True, exist_ok=True)
    x, y, t, p = cases["sparse"]
    with tempfile.TemporaryDirectory() as tmp:
        for compression in ("none", "lz4", "bz2"):
            bag = write_bag(Path(tmp) / f"{compression}.bag", x, y, t, p, compression)
            (folder / f"{compression}.bin").write_bytes(bag)
        folder = SEEDS / "aedat4"
        folder.mkdir(parents=True, exist_ok=True)
        for compression in ("NONE", "LZ4", "ZSTD"):
            packets = aedat4_packets(Path(tmp) / f"{compression}.aedat4", x, y, t, p, compression)
            (folder / f"{compression.lower()}.bin").write_bytes(packets)
        folder = SEEDS / "mcap"
        folder.mkdir(parents=True, exist_ok=True)
        for name, zstd in (("none", False), ("zstd", True)):
            data = write_mcap(Path(tmp) / f"mcap-{name}", x, y, t, p, zstd)
            (folder / f"{name}.bin").write_bytes(data)


if __name__ == "__main__":
    main()
