"""ROS bags: event arrays (``dvs_msgs/EventArray`` from rpg_dvs_ros,
``prophesee_event_msgs/EventArray`` from prophesee_ros_driver) and ``geometry_msgs/PoseStamped``
poses.

The events of every bag evsplat reads are decoded by the project's Rust readers (crates/formats,
``rosbag``, ``mcap`` and ``db3``), in bounded chunks of events: a ROS 1 bag (.bag); a ROS 2 bag
in MCAP or in SQLite (.db3), in one file or split over several that its metadata.yaml lists
(read one after another), uncompressed or zstd-compressed by rosbag2 per message or per file
(``NAME.mcap.zstd``, ``NAME.db3.zstd``). The .bag and MCAP readers read records in file order,
chunks uncompressed or compressed (bags: LZ4, bzip2; MCAP: Zstd, LZ4), with no need for the
index or summary, so a bag whose recording was cut off reads up to its last complete message
or chunk (a compressed MCAP file is unpacked as it is read); the .db3 reader queries SQLite for
the topic's messages in timestamp order (a compressed file unpacked first into a temporary
.db3, removed after it). Poses go through ``rosbags`` (pure Python; a few thousand messages),
whose reader is also `evsplat bench decode`'s reference for the events; its message
definitions stored in the bag are used, and the two event types are also registered here, so
ROS 2 bags recorded without definitions read too. The Rust readers were checked event by event
against rosbags' deserialiser (tests/test_formats.py, tests/test_formats_samples.py)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from evsplat import _core
from evsplat.data.formats import (
    BLOCK_BYTES,
    CHECK_FILE,
    CHUNK_EVENTS,
    Dropped,
    EventSource,
    decoded_chunks,
    is_ros2_bag,
    packed_storage,
)
from evsplat.errors import EvsplatError

#: Field layout shared by both drivers' Event messages (ROS 1 ``time`` = builtin Time).
EVENT_MSG = "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n"
EVENT_ARRAY_MSG = "std_msgs/Header header\nuint32 height\nuint32 width\n{pkg}/Event[] events\n"
EVENT_PACKAGES = ("dvs_msgs", "prophesee_event_msgs")
EVENT_TYPES = tuple(f"{pkg}/msg/EventArray" for pkg in EVENT_PACKAGES)
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
BAG_SUFFIXES = (".bag", ".mcap", ".db3")


def typestore(ros1: bool = False):
    """The ROS 2 Humble (or, with ``ros1``, ROS 1 Noetic: Header with seq) types plus both
    event-message packages."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for pkg in EVENT_PACKAGES:
        types.update(get_types_from_msg(EVENT_MSG, f"{pkg}/msg/Event"))
        types.update(get_types_from_msg(EVENT_ARRAY_MSG.format(pkg=pkg), f"{pkg}/msg/EventArray"))
    store.register(types)
    return store


def is_bag(path: Path) -> bool:
    """A ROS 1 .bag, a ROS 2 storage file (maybe zstd-packed whole), or a ROS 2 bag folder."""
    return path.suffix.lower() in BAG_SUFFIXES or is_ros2_bag(path)


def _bag_root(path: Path) -> Path:
    # rosbags opens a ROS 2 bag by its folder (the one with metadata.yaml).
    storage = path.suffix.lower() in STORAGE_SUFFIXES.values() or packed_storage(path) is not None
    return path.parent if storage else path


def _open(path: Path) -> AnyReader:
    try:
        reader = AnyReader([_bag_root(path)], default_typestore=typestore())
        reader.open()
    except Exception as e:  # rosbags raises its own error classes per storage back end
        what = " ".join(str(e).split())
        raise EvsplatError(
            f"{path}: cannot open the bag ({what}); the file is not a ROS bag, is truncated, or "
            "a ROS 2 bag lacks its metadata.yaml"
        ) from None
    return reader


@dataclass(frozen=True)
class Connection:
    """A bag's topic and message type (``pkg/msg/Name``), as the Rust reader lists them."""

    topic: str
    msgtype: str


def _topics(connections) -> str:
    return ", ".join(f"{c.topic} ({c.msgtype})" for c in connections) or "none"


def _pick(path: Path, connections, topic: str | None, types: tuple[str, ...], what: str):
    """The connections of ``topic`` (checked to carry ``types``) or of the only such topic."""
    if topic is not None:
        conns = [c for c in connections if c.topic == topic]
        if not conns:
            raise EvsplatError(f"{path}: no topic {topic!r}; topics: {_topics(connections)}")
        bad = [c.msgtype for c in conns if c.msgtype not in types]
        if bad:
            raise EvsplatError(
                f"{path}: topic {topic} has message type {bad[0]}, not {what} "
                f"({' or '.join(types)}); pick another topic"
            )
        return conns
    found = sorted({c.topic for c in connections if c.msgtype in types})
    if not found:
        raise EvsplatError(
            f"{path}: no {what} topic ({' or '.join(types)}); topics: {_topics(connections)}"
        )
    if len(found) > 1:
        raise EvsplatError(f"{path}: several {what} topics ({', '.join(found)}); pass --topic")
    return [c for c in connections if c.topic == found[0]]


def is_ros1_bag(path: Path) -> bool:
    """A ROS 1 bag file (decoded in Rust), not a ROS 2 storage file or folder."""
    return path.suffix.lower() == ".bag" and path.is_file()


#: The file suffix of each ROS 2 storage (metadata.yaml's ``storage_identifier``).
STORAGE_SUFFIXES = {"sqlite3": ".db3", "mcap": ".mcap"}
#: rosbag2's compression modes (``compression_mode``, format zstd) the Rust readers unpack.
COMPRESSION_MODES = ("none", "message", "file")


@dataclass(frozen=True)
class BagFiles:
    """A bag's files in reading order (a ROS 1 bag: its one file; a ROS 2 bag: its storage
    files), how they are compressed (a ROS 2 bag's metadata.yaml ``compression_mode`` of zstd:
    "none", "message": each message's data a zstd frame, "file": each file one zstd stream,
    ``NAME.db3.zstd``) and its topics as its metadata lists them (none without metadata)."""

    files: list[Path]
    compression: str = "none"
    topics: tuple[Connection, ...] = ()

    def connections(self, lister: Callable[[Path], list[tuple]]) -> list[Connection]:
        """The bag's topics, first seen first: its metadata's for a file-compressed bag (its
        storage cannot list them), else each file's (``lister``: (id, topic, type) rows)."""
        if self.compression == "file":
            return list(self.topics)
        listed = (row for f in self.files for row in lister(f))
        return list(dict.fromkeys(Connection(t, _msgtype(m)) for _, t, m in listed))


def _lone(path: Path, storage: str) -> BagFiles | None:
    """A file of ``storage`` on its own, or a folder's only storage file, without metadata
    (a packed file, whose topics only the metadata lists, is an error saying so)."""
    suffix = STORAGE_SUFFIXES[storage]
    if path.is_file():
        if packed_storage(path) == suffix:  # its storage cannot list topics while packed
            raise EvsplatError(
                f"{path}: a ROS 2 file packed whole with zstd has its topics listed only in the "
                "bag's metadata.yaml; pass the bag's folder with its metadata.yaml"
            )
        return BagFiles([path]) if path.suffix.lower() == suffix else None
    found = [f for kind in STORAGE_SUFFIXES.values() for f in sorted(path.glob(f"*{kind}"))]
    return BagFiles(found) if len(found) == 1 and found[0].suffix.lower() == suffix else None


def ros2_files(path: Path, storage: str) -> BagFiles | None:
    """The files of a ROS 2 bag in ``storage`` ("sqlite3" or "mcap"), which the Rust readers
    decode: those its metadata.yaml lists, for the bag folder or one of its files; without
    metadata (or for a file it does not list), the file itself or a folder's only storage
    file. None for other bags, for compression other than zstd and for metadata that cannot
    be read or lists missing files (rosbags reports what is wrong)."""
    root = _bag_root(path)
    meta = root / "metadata.yaml"
    if not meta.is_file():
        return _lone(path, storage)
    try:
        from ruamel.yaml import YAML  # rosbags' own YAML parser

        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        files = [root / Path(str(name)).name for name in info["relative_file_paths"]]
        mode = str(info.get("compression_mode") or "none").lower()
        zstd = str(info.get("compression_format") or "zstd").lower() == "zstd"
        topics = tuple(
            Connection(t["topic_metadata"]["name"], t["topic_metadata"]["type"])
            for t in info.get("topics_with_message_count") or ()
        )
        storage_ok = info.get("storage_identifier") == storage
    except Exception:  # noqa: BLE001 - any unreadable metadata: rosbags says what is wrong
        return None
    if path.is_file() and path not in files:
        return _lone(path, storage)
    if not (storage_ok and mode in COMPRESSION_MODES and (zstd or mode == "none")):
        return None
    return BagFiles(files, mode, topics) if files and all(f.is_file() for f in files) else None


#: What to do about a .db3 file SQLite cannot read.
DB3_FIX = (
    "the .db3 file is not a ROS 2 SQLite bag, or it is truncated or damaged: recover what it "
    "holds with `sqlite3 BAG.db3 .recover | sqlite3 FIXED.db3`, or re-record"
)
#: What to do about a compressed bag that does not unpack.
ZSTD_FIX = (
    "the bag's zstd-compressed data is damaged or cut short (test a .zstd file with `zstd -t`): "
    "copy the bag again from where it was recorded, or re-record"
)


def _rust_source(
    path: Path,
    chosen: str,
    decoder: object,
    size: tuple[int, int] | None,
    dropped: Dropped,
    fix: str = CHECK_FILE,
) -> EventSource:
    """The EventSource of a Rust bag reader opened on topic ``chosen``, whose first event
    message gave ``size``; a missing or unfilled sensor size is a one-line error."""
    if size is None:
        raise EvsplatError(f"{path}: topic {chosen} has no readable event messages")
    width, height = size
    if not (width > 0 and height > 0):
        raise EvsplatError(
            f"{path}: topic {chosen} gives sensor size {width}x{height}; "
            "the driver did not fill width/height: re-record or fix the messages"
        )
    chunks = decoded_chunks(path, lambda: decoder, dropped, fix)
    return EventSource(path, int(width), int(height), chunks, "rosbag", "evsplat", dropped)


def open_db3_bag(path: Path, bag: BagFiles, *, topic: str | None = None) -> EventSource:
    """Opens the event topic of a ROS 2 SQLite bag (its files, in order, plain or
    zstd-compressed) with the Rust reader; the sensor size comes from its first event
    message."""
    fix = DB3_FIX if bag.compression == "none" else ZSTD_FIX
    try:
        connections = bag.connections(_core.db3_topics)
        chosen = _pick(path, connections, topic, EVENT_TYPES, "event-array")[0].topic
        files = [str(f) for f in bag.files]
        decoder = _core.Db3EventDecoder(files, chosen, CHUNK_EVENTS, bag.compression)
        size = decoder.sensor_size()
    except OSError as e:
        what = " ".join(str(e).split())
        raise EvsplatError(f"{path}: cannot open the bag ({what}); {fix}") from None
    dropped = Dropped(words_are="messages not of the EventArray layout")
    return _rust_source(path, chosen, decoder, size, dropped, fix)


def _msgtype(ros1_type: str) -> str:
    """``pkg/Name`` (ROS 1) as ``pkg/msg/Name`` (rosbags' and the ROS 2 spelling)."""
    pkg, _, name = ros1_type.rpartition("/")
    return f"{pkg}/msg/{name}" if pkg and "/msg/" not in ros1_type else ros1_type


def _rust_fail(path: Path, e: OSError) -> EvsplatError:
    what = " ".join(str(e).split())
    return EvsplatError(
        f"{path}: cannot open the bag ({what}); the file is not a ROS bag or is damaged"
    )


def open_rust_bag(path: Path, bag: BagFiles, *, topic: str | None = None) -> EventSource:
    """Opens the event topic of a ROS 1 bag (one file) or a ROS 2 MCAP bag (its files, read
    one after another, plain or zstd-compressed) with the Rust readers; the sensor size comes
    from its first event message."""
    ros1 = bag.files[0].suffix.lower() == ".bag"
    try:
        connections = bag.connections(_core.bag_connections if ros1 else _core.mcap_channels)
    except OSError as e:
        raise _rust_fail(path, e) from None
    chosen = _pick(path, connections, topic, EVENT_TYPES, "event-array")[0].topic
    block = max(1, min(BLOCK_BYTES, max(f.stat().st_size for f in bag.files)))
    try:
        if ros1:
            decoder = _core.BagEventDecoder(bag.files[0], chosen, block)
        else:
            files = [str(f) for f in bag.files]
            decoder = _core.McapEventDecoder(files, chosen, block, bag.compression)
        size = decoder.sensor_size()
    except OSError as e:
        raise _rust_fail(path, e) from None
    dropped = Dropped(words_are="event messages or records that could not be read")
    return _rust_source(path, chosen, decoder, size, dropped)


def open_bag(path: Path, *, topic: str | None = None) -> EventSource:
    """Opens the event topic of a bag; the sensor size comes from its first message. Every
    bag evsplat reads decodes in Rust; for any other input rosbags says what is wrong."""
    if is_ros1_bag(path):
        return open_rust_bag(path, BagFiles([path]), topic=topic)
    if (mcap := ros2_files(path, "mcap")) is not None:
        return open_rust_bag(path, mcap, topic=topic)
    if (db3 := ros2_files(path, "sqlite3")) is not None:
        return open_db3_bag(path, db3, topic=topic)
    _open(path).close()  # rosbags' own error for what it cannot open
    raise EvsplatError(
        f"{path}: not a bag evsplat reads (a ROS 1 .bag, or a ROS 2 bag in MCAP or SQLite with "
        "its metadata.yaml, uncompressed or zstd-compressed); pass the bag's folder or file"
    )


def read_bag_poses(path: Path, *, topic: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Poses of a ``geometry_msgs/PoseStamped`` topic: header times (µs) [N] and camera-to-world
    matrices [N,4,4] (the message's pose taken as camera in world)."""
    from evsplat.data.poses import quat_to_matrix

    reader = _open(path)
    try:
        conns = _pick(path, reader.connections, topic, (POSE_TYPE,), "pose")
        times, mats = [], []
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            pos, q = msg.pose.position, msg.pose.orientation
            m = np.eye(4)
            m[:3, :3] = quat_to_matrix(np.array([q.w, q.x, q.y, q.z], np.float64))
            m[:3, 3] = (pos.x, pos.y, pos.z)
            times.append(msg.header.stamp.sec * 1_000_000 + msg.header.stamp.nanosec // 1000)
            mats.append(m)
    finally:
        reader.close()
    if not times:
        raise EvsplatError(f"{path}: pose topic {conns[0].topic} has no messages")
    return np.array(times, np.int64), np.stack(mats)
