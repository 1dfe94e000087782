"""Sensor recordings: each reader on a file made here, by the format's own writer (AEDAT 4:
iniVation's dv-processing; ROS bags: rosbags' writers) or by an encoder written from the
public spec (Prophesee EVT 2.0, EVT 3.0, DAT: evsplat.data.formats.prophesee_writer), then
`evsplat convert` on each. The Prophesee decoders are compared event by event with the
field's (evt3, expelliarmus) on the same bytes, the ROS 1 bag reader with rosbags'
deserialiser."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from evsplat import _core
from evsplat.cli import main
from evsplat.data.event_files import read_events
from evsplat.data.formats import Dropped, event_arrays, open_source, prophesee_writer, rosbag
from evsplat.errors import EvsplatError

W, H = 320, 240
N = 3000


def _events(seed: int = 0, n: int = N, t0: int = 0):
    rng = np.random.default_rng(seed)
    x = rng.integers(0, W, n)
    y = rng.integers(0, H, n)
    # Starts mid-period so TIME_HIGH/TIME_LOW wraps happen at arbitrary places.
    t = t0 + np.sort(rng.integers(0, 2_500_000, n))
    p = rng.integers(0, 2, n)
    return x, y, t, p


def _assert_same(ev, x, y, t, p):
    assert len(ev) == len(x)
    np.testing.assert_array_equal(ev.x, x)
    np.testing.assert_array_equal(ev.y, y)
    np.testing.assert_array_equal(ev.t, t)
    np.testing.assert_array_equal(ev.p, np.where(np.asarray(p) > 0, 1, -1))
    assert (ev.width, ev.height) == (W, H)


def _recording(encoding: str, x, y, t, p, head: bytes | None = None) -> bytes:
    """A Prophesee recording written from the public spec (EVT 2.0, EVT 3.0, DAT)."""
    return prophesee_writer.encode(encoding, x, y, t, p, W, H, head=head)


def write_aedat4(path: Path, x, y, t, p, compression: str = "LZ4") -> None:
    dv = pytest.importorskip("dv_processing")
    cfg = dv.io.MonoCameraWriter.EventOnlyConfig("DVXplorer_test", (W, H))
    cfg.compression = getattr(dv.CompressionType, compression)
    writer = dv.io.MonoCameraWriter(str(path), cfg)
    # Several packets, so the reader's chunking is exercised.
    for part in np.array_split(np.arange(len(x)), 4):
        store = dv.EventStore()
        for i in part:
            store.push_back(int(t[i]), int(x[i]), int(y[i]), bool(p[i]))
        writer.writeEvents(store)
    del writer  # closes the file


def _header(store, t: int, frame: str):
    """std_msgs/Header at ``t`` µs (ROS 1's carries a sequence number, ROS 2's does not)."""
    Header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"](sec=t // 10**6, nanosec=t % 10**6 * 1000)
    seq = {"seq": 7} if "seq" in Header.__dataclass_fields__ else {}
    return Header(**seq, stamp=stamp, frame_id=frame)


def _event_array(store, pkg: str, x, y, t, p, stamp: int):
    Time = store.types["builtin_interfaces/msg/Time"]
    Event = store.types[f"{pkg}/msg/Event"]
    Array = store.types[f"{pkg}/msg/EventArray"]
    events = [
        Event(
            x=int(a),
            y=int(b),
            ts=Time(sec=int(c) // 10**6, nanosec=int(c) % 10**6 * 1000),
            polarity=bool(d),
        )
        for a, b, c, d in zip(x, y, t, p)
    ]
    return Array(header=_header(store, stamp, "cam"), height=H, width=W, events=events)


def _pose(store, t: int, pos, q_wxyz):
    T = store.types
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=pos[0], y=pos[1], z=pos[2]),
        orientation=T["geometry_msgs/msg/Quaternion"](
            w=q_wxyz[0], x=q_wxyz[1], y=q_wxyz[2], z=q_wxyz[3]
        ),
    )
    return T["geometry_msgs/msg/PoseStamped"](header=_header(store, t, "world"), pose=pose)


def write_bag(
    path: Path,
    x,
    y,
    t,
    p,
    *,
    ros2: bool = False,
    pkg: str = "dvs_msgs",
    events: bool = True,
    poses: list | None = None,
    compression: str = "none",
    chunk_bytes: int | None = None,
    mcap: bool = False,
) -> Path:
    """A bag with an event topic (messages of ~500 events) and optionally a pose topic; a
    ROS 1 bag's chunks ``compression`` ("none", "lz4", "bz2") of ``chunk_bytes`` (rosbags'
    default: 1 MiB); a ROS 2 bag in SQLite, or with ``mcap`` in MCAP (``compression`` "zstd":
    zstd chunks; "message", "file": rosbag2's zstd compression of each message or file)."""
    store = rosbag.typestore(ros1=not ros2)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
        writer, ser = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
        if compression != "none":
            mode = "STORAGE" if compression == "zstd" else compression.upper()
            writer.set_compression(CompressionMode[mode], CompressionFormat.ZSTD)
    else:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
        if compression != "none":
            writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
        if chunk_bytes is not None:
            writer.chunk_threshold = chunk_bytes
    with writer:
        if events:
            conn = writer.add_connection("/dvs/events", f"{pkg}/msg/EventArray", typestore=store)
            for part in np.array_split(np.arange(len(x)), max(1, len(x) // 500)):
                stamp = int(t[part[-1]]) + 1
                msg = _event_array(store, pkg, x[part], y[part], t[part], p[part], stamp)
                writer.write(conn, stamp * 1000, ser(msg, f"{pkg}/msg/EventArray"))
        if poses:
            pconn = writer.add_connection(
                "/mocap/pose", "geometry_msgs/msg/PoseStamped", typestore=store
            )
            for tp, pos, q in poses:
                msg = _pose(store, tp, pos, q)
                writer.write(pconn, tp * 1000, ser(msg, "geometry_msgs/msg/PoseStamped"))
    return path


# --- round trips ----------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["evt2", "evt3", "dat"])
def test_prophesee_reader_recovers_spec_encoded_events(tmp_path, encoding):
    x, y, t, p = _events(1, t0=1_234_567)
    suffix = ".dat" if encoding == "dat" else ".raw"
    path = tmp_path / f"rec{suffix}"
    path.write_bytes(_recording(encoding, x, y, t, p))
    _assert_same(read_events(path), x, y, t, p)


def _decoded(encoding: str, data: bytes, tmp_path: Path):
    """Our decoder's events and dropped counts on the words ``data`` (no header)."""
    path = tmp_path / f"words.{encoding}"
    path.write_bytes(data)
    decoder = _core.EventFileDecoder(path, encoding, 0, 1 << 12)
    chunks = []
    while len((chunk := decoder.next_chunk(1000))[0]):
        chunks.append(chunk)
    x, y, t, p = (np.concatenate([c[i] for c in chunks] or [[]]) for i in range(4))
    return (x, y, t, p), decoder.dropped()


def _expelliarmus(encoding: str, head: bytes, data: bytes, tmp_path: Path):
    expelliarmus = pytest.importorskip("expelliarmus")
    path = tmp_path / ("ref.dat" if encoding == "dat" else "ref.raw")
    path.write_bytes(head + data)
    arr = expelliarmus.Wizard(encoding=encoding, fpath=path).read()
    return arr["x"], arr["y"], arr["t"], arr["p"]


def _evt3_reference(data: bytes):
    evt3 = pytest.importorskip("evt3")
    ev = evt3.decode_bytes(data, 2048, 2048)
    return ev.x, ev.y, ev.timestamp, ev.polarity


def _assert_same_events(ours, ref) -> None:
    assert len(ours[0]) == len(ref[0])
    for name, a, b in zip("xytp", ours, ref):
        np.testing.assert_array_equal(np.asarray(a, np.int64), np.asarray(b, np.int64), name)


@pytest.mark.parametrize("encoding", ["evt2", "evt3", "dat"])
def test_prophesee_decoders_match_the_reference_decoders_on_the_same_bytes(tmp_path, encoding):
    # 40k events over 40 s: EVT 3.0's 24-bit time wraps twice, several chunks and buffers.
    x, y, t, p = _events(7, n=40_000, t0=16_000_000)
    t = t0 = 16_000_000 + np.sort(np.random.default_rng(8).integers(0, 40_000_000, len(t)))
    data = prophesee_writer.Encoder(encoding).encode(x, y, t, p)
    ours, dropped = _decoded(encoding, data, tmp_path)
    if encoding == "evt3":
        ref = _evt3_reference(data)
    else:
        ref = _expelliarmus(encoding, prophesee_writer.header(encoding, W, H), data, tmp_path)
    _assert_same_events(ours, ref)
    _assert_same_events(ours, (x, y, t0, p))
    assert dropped == (0, 0, 0)


def _random_evt3_words(rng: np.random.Generator, n: int) -> bytes:
    """Every EVT 3.0 word type in random order (vectors, triggers, OTHERS, CONTINUED, time
    words), TIME_HIGH first and then climbing by small steps, sometimes wrapping."""
    kinds = rng.choice([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x8, 0xA, 0xE, 0xF], n)
    payload = rng.integers(0, 1 << 12, n)
    high = (3000 + np.cumsum(kinds == 0x8) * rng.integers(0, 3, n)) & 0xFFF
    payload = np.where(kinds == 0x8, high, payload)
    payload = np.where(kinds == 0x0, payload & 0x7FF, payload)  # y < 2048
    words = np.concatenate([[0x8000 | 3000], (kinds << 12) | payload])
    return words.astype("<u2").tobytes()


def test_evt3_decoder_matches_evt3_on_every_word_type(tmp_path):
    rng = np.random.default_rng(9)
    for _ in range(5):
        data = _random_evt3_words(rng, 20_000)
        ours, dropped = _decoded("evt3", data, tmp_path)
        _assert_same_events(ours, _evt3_reference(data))
        assert dropped == (0, 0, 0)


def test_evt2_decoder_matches_expelliarmus_on_time_and_trigger_words(tmp_path):
    rng = np.random.default_rng(10)
    n = 20_000
    kinds = rng.choice([0x0, 0x1, 0x8, 0xA], n, p=[0.4, 0.4, 0.1, 0.1])
    payload = rng.integers(0, 1 << 28, n)
    high = 1000 + np.cumsum(kinds == 0x8)
    words = (kinds << 28) | np.where(kinds == 0x8, high, payload)
    data = np.concatenate([[(0x8 << 28) | 1000], words]).astype("<u4").tobytes()
    ours, dropped = _decoded("evt2", data, tmp_path)
    head = prophesee_writer.header("evt2", W, H)
    _assert_same_events(ours, _expelliarmus("evt2", head, data, tmp_path))
    assert dropped == (0, 0, 0)


@pytest.mark.parametrize("encoding", ["evt2", "evt3", "dat"])
def test_truncated_recording_keeps_the_complete_records_and_says_what_was_dropped(
    tmp_path, capsys, encoding
):
    x, y, t, p = _events(11, n=500)
    whole = _recording(encoding, x, y, t, p)
    word = {"evt2": 4, "evt3": 2, "dat": 8}[encoding]
    path = tmp_path / ("cut.dat" if encoding == "dat" else "cut.raw")
    path.write_bytes(whole[: len(whole) - word + 1])  # the last event's word cut short
    out = tmp_path / "cut.h5"
    assert main(["convert", str(path), str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    warning = [line for line in err if line.startswith("warning:")]
    assert len(warning) == 1 and str(path) in warning[0], err
    assert "an incomplete record of 1 B at the end" in warning[0]
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], t[:-1])
        prov = dict(f["provenance"].attrs)
    assert (prov["events"], prov["events_dropped"], prov["bytes_dropped"]) == (499, 0, 1)
    assert main(["check", str(out)]) == 0
    assert "the last 1 B (a truncated record) dropped" in capsys.readouterr().out
    with pytest.warns(UserWarning, match="incomplete record"):
        assert len(read_events(path)) == 499


def test_aedat4_reader_recovers_dv_processing_recording(tmp_path):
    x, y, t, p = _events(2, t0=1_700_000_000_000_000)  # AEDAT 4 stores Unix-epoch µs
    path = tmp_path / "rec.aedat4"
    write_aedat4(path, x, y, t, p)
    _assert_same(read_events(path), x, y, t, p)


@pytest.mark.parametrize(
    ("ros2", "pkg", "mcap"),
    [(False, "dvs_msgs", False), (True, "prophesee_event_msgs", False), (True, "dvs_msgs", True)],
)
def test_bag_reader_recovers_event_arrays_and_poses(tmp_path, ros2, pkg, mcap):
    x, y, t, p = _events(3, t0=1_000_000)
    q = np.array([np.cos(0.2), 0.0, np.sin(0.2), 0.0])  # 0.4 rad about y
    poses = [(1_000_000 + 100_000 * k, (0.1 * k, -0.2, 1.5), q) for k in range(30)]
    path = write_bag(
        tmp_path / ("rec2" if ros2 else "rec.bag"),
        x,
        y,
        t,
        p,
        ros2=ros2,
        pkg=pkg,
        poses=poses,
        mcap=mcap,
    )
    _assert_same(read_events(path), x, y, t, p)
    times, c2w = rosbag.read_bag_poses(path)
    np.testing.assert_array_equal(times, [tp for tp, _, _ in poses])
    c, s = np.cos(0.4), np.sin(0.4)
    np.testing.assert_allclose(c2w[3, :3, :3], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-12)
    np.testing.assert_allclose(c2w[3, :3, 3], [0.3, -0.2, 1.5])


@pytest.mark.parametrize("ros2", [False, True])
def test_byte_views_agree_with_the_rosbags_deserializer(tmp_path, ros2):
    x, y, t, p = _events(6, n=1200, t0=3_000_000)
    bag = write_bag(tmp_path / ("b2" if ros2 else "a.bag"), x, y, t, p, ros2=ros2)
    view = event_arrays.cdr_event_records if ros2 else event_arrays.ros1_event_records
    reader = rosbag._open(bag)
    try:
        for conn, _, raw in reader.messages():
            parts = view(raw)
            assert parts is not None
            recs = np.concatenate(parts) if ros2 else parts
            msg = reader.deserialize(raw, conn.msgtype)
            assert len(recs) == len(msg.events)
            want = [(e.x, e.y, e.ts.sec, e.ts.nanosec, int(e.polarity)) for e in msg.events]
            got = [tuple(int(r[k]) for k in ("x", "y", "sec", "nsec", "p")) for r in recs]
            assert got == want
            # A message of another layout (four bytes more) is refused, not misread.
            assert view(bytes(raw) + b"\0" * 4) is None
    finally:
        reader.close()


def _aedat_events(path: Path):
    """Every event of the first event stream as the ``aedat`` package decodes it."""
    aedat = pytest.importorskip("aedat")
    decoder = aedat.Decoder(str(path))
    sid = min(i for i, s in decoder.id_to_stream().items() if s["type"] == "events")
    parts = [p["events"] for p in decoder if p["stream_id"] == sid and "events" in p]
    ev = np.concatenate(parts)
    return ev["x"], ev["y"], ev["t"], ev["on"]


@pytest.mark.parametrize("compression", ["NONE", "LZ4", "LZ4_HIGH", "ZSTD", "ZSTD_HIGH"])
def test_aedat4_reader_matches_the_aedat_package_event_by_event(tmp_path, compression):
    x, y, t, p = _events(14, n=20_000, t0=1_700_000_000_000_000)
    path = tmp_path / "rec.aedat4"
    write_aedat4(path, x, y, t, p, compression)
    source = open_source(path)
    chunks = list(source.chunks)
    ours = tuple(np.concatenate([c[i] for c in chunks]) for i in range(4))
    _assert_same_events(ours, _aedat_events(path))
    _assert_same_events(ours, (x, y, t, p))
    assert (source.width, source.height, source.decoder) == (W, H, "evsplat")
    assert source.dropped == Dropped(words_are=source.dropped.words_are)


def test_truncated_aedat4_keeps_the_complete_packets_and_says_what_was_dropped(tmp_path, capsys):
    x, y, t, p = _events(15, n=2000, t0=1_700_000_000_000_000)
    whole = tmp_path / "whole.aedat4"
    write_aedat4(whole, x, y, t, p, "NONE")  # 4 packets of 500 events, then the data table
    data = whole.read_bytes()
    # The last packet's first event (its 16-byte struct starts with t): cut just after it.
    cut = data.find(np.asarray(t[1500:1501], "<i8").tobytes()) + 16
    path = tmp_path / "cut.aedat4"
    path.write_bytes(data[:cut])
    out = tmp_path / "cut.h5"
    assert main(["convert", str(path), str(out)]) == 0
    err = capsys.readouterr().err
    assert "(the file is truncated)" in err and str(path) in err, err
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], t[:1500])


def _rosbags_events(path: Path, topic: str = "/dvs/events"):
    """Every event of ``topic`` as rosbags deserialises it (one Python object per event: the
    independent oracle for the Rust reader), message by message."""
    reader = rosbag._open(path)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        rows = [
            (e.x, e.y, e.ts.sec * 1_000_000 + e.ts.nanosec // 1000, int(e.polarity))
            for conn, _, raw in reader.messages(connections=conns)
            for e in reader.deserialize(raw, conn.msgtype).events
        ]
    finally:
        reader.close()
    return tuple(np.array(c, np.int64) for c in zip(*rows))


def _rust_bag_events(path: Path, topic: str | None = "/dvs/events", block: int = 1 << 12):
    decoder = _core.BagEventDecoder(path, topic, block)
    chunks = []
    while len((chunk := decoder.next_chunk(777))[0]):
        chunks.append(chunk)
    x, y, t, p = (np.concatenate([c[i] for c in chunks] or [[]]) for i in range(4))
    return (x, y, t, p), decoder.dropped()


@pytest.mark.parametrize("compression", ["none", "lz4", "bz2"])
@pytest.mark.parametrize("pkg", ["dvs_msgs", "prophesee_event_msgs"])
def test_ros1_bag_reader_matches_rosbags_event_by_event(tmp_path, compression, pkg):
    # 20k events in chunks of ~64 KB: messages and chunks cross the reader's buffers.
    x, y, t, p = _events(12, n=20_000, t0=1_600_000_000_000_000)
    poses = [(int(t[0]) + 50_000 * k, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)) for k in range(20)]
    path = write_bag(
        tmp_path / "rec.bag",
        x,
        y,
        t,
        p,
        pkg=pkg,
        poses=poses,
        compression=compression,
        chunk_bytes=1 << 16,
    )
    ours, dropped = _rust_bag_events(path)
    _assert_same_events(ours, _rosbags_events(path))
    _assert_same_events(ours, (x, y, t, p))
    assert dropped == (0, 0, 0)
    listed = [(topic, kind) for _, topic, kind in _core.bag_connections(path)]
    assert listed == [
        ("/dvs/events", f"{pkg}/EventArray"),
        ("/mocap/pose", "geometry_msgs/PoseStamped"),
    ]


@pytest.mark.parametrize("compression", ["none", "zstd"])
@pytest.mark.parametrize("pkg", ["dvs_msgs", "prophesee_event_msgs"])
def test_ros2_mcap_reader_matches_rosbags_event_by_event(tmp_path, compression, pkg):
    x, y, t, p = _events(16, n=20_000, t0=1_600_000_000_000_000)
    poses = [(int(t[0]) + 50_000 * k, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)) for k in range(20)]
    bag = write_bag(
        tmp_path / "rec2", x, y, t, p, ros2=True, pkg=pkg, poses=poses, mcap=True,
        compression=compression,
    )  # fmt: skip
    (mcap,) = bag.glob("*.mcap")
    decoder = _core.McapEventDecoder([mcap], "/dvs/events", 1 << 12)
    chunks = []
    while len((chunk := decoder.next_chunk(777))[0]):
        chunks.append(chunk)
    ours = tuple(np.concatenate([c[i] for c in chunks]) for i in range(4))
    _assert_same_events(ours, _rosbags_events(bag))
    _assert_same_events(ours, (x, y, t, p))
    assert decoder.dropped() == (0, 0, 0)
    listed = [(topic, kind) for _, topic, kind in _core.mcap_channels(mcap)]
    assert listed == [
        ("/dvs/events", f"{pkg}/msg/EventArray"),
        ("/mocap/pose", "geometry_msgs/msg/PoseStamped"),
    ]
    source = open_source(bag)  # the bag's folder: its one MCAP file, read in Rust
    n = sum(len(c[2]) for c in source.chunks)
    assert (source.decoder, n) == ("evsplat", len(t))


def test_cut_ros1_bag_keeps_its_complete_messages_and_says_what_was_dropped(tmp_path, capsys):
    # A recording killed mid-write: no index, the last chunk cut inside a message.
    x, y, t, p = _events(13, n=3000)
    whole = write_bag(tmp_path / "whole.bag", x, y, t, p)
    data = whole.read_bytes()
    reader = rosbag._open(whole)
    raws = [bytes(raw) for _, _, raw in reader.messages()]
    reader.close()
    at = data.find(raws[3])
    path = tmp_path / "cut.bag"
    path.write_bytes(data[: at + len(raws[3]) // 2])
    kept = sum(len(event_arrays.ros1_event_records(r)) for r in raws[:3])
    out = tmp_path / "cut.h5"
    assert main(["convert", str(path), str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    warning = [line for line in err if line.startswith("warning:")]
    assert len(warning) == 1 and str(path) in warning[0], err
    assert "an incomplete record of" in warning[0] and "(the file is truncated)" in warning[0]
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], t[:kept])
        np.testing.assert_array_equal(f["events/x"][:], x[:kept])
        prov = dict(f["provenance"].attrs)
    assert prov["events"] == kept and prov["bytes_dropped"] > 0


def test_mcap_without_its_summary_converts_and_a_cut_chunk_is_dropped_whole(tmp_path, capsys):
    x, y, t, p = _events(17, n=6000)
    bag = write_bag(tmp_path / "whole", x, y, t, p, ros2=True, mcap=True)  # one chunk
    (whole,) = bag.glob("*.mcap")
    data = whole.read_bytes()
    # Cut before DataEnd (0x0F): no summary, no footer; every event is still there.
    path = tmp_path / "nosummary.mcap"
    path.write_bytes(data[: data.rfind(b"\x0f" + (4).to_bytes(8, "little"))])
    out = tmp_path / "nosummary.h5"
    assert main(["convert", str(path), str(out)]) == 0
    assert "warning" not in capsys.readouterr().err
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], t)
    # Cut inside the chunk: the chunk (its channels and messages) is dropped whole, so the
    # file has no topics left; one line says so.
    path = tmp_path / "cut.mcap"
    chunk_at = 8 + 9 + int.from_bytes(data[9:17], "little")  # after the magic and the header
    assert data[chunk_at] == 0x06
    path.write_bytes(data[: chunk_at + 1000])
    assert main(["convert", str(path), str(tmp_path / "cut.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(path) in err and "topics: none" in err, err


#: The PyPI decoder each converted file's provenance must name.
DECODERS = {"a": "evsplat", "b": "evsplat", "c": "evsplat", "d": "evsplat", "e": "evsplat"}


def test_convert_streams_every_format_into_the_same_h5(tmp_path, capsys):
    x, y, t, p = _events(4, t0=5_000)
    inputs = {
        "a.raw": _recording("evt3", x, y, t, p),
        "b.raw": _recording("evt2", x, y, t, p),
        "c.dat": _recording("dat", x, y, t, p),
    }
    for name, data in inputs.items():
        (tmp_path / name).write_bytes(data)
    write_aedat4(tmp_path / "d.aedat4", x, y, t, p)
    poses = [(k * 200_000, (0.0, 0.0, float(k)), (1.0, 0.0, 0.0, 0.0)) for k in range(14)]
    write_bag(tmp_path / "e.bag", x, y, t, p, poses=poses)
    for name in [*inputs, "d.aedat4", "e.bag"]:
        out = tmp_path / f"{name}.h5"
        extra = ["--poses", str(tmp_path / "poses.txt")] if name.endswith(".bag") else []
        assert main(["convert", str(tmp_path / name), str(out), *extra]) == 0
        line = capsys.readouterr().out
        rate = re.search(r"wrote (\d+) events .* \(([\d,]+) ev/s\)", line)
        assert rate and int(rate.group(1)) == N, line
        with h5py.File(out) as f:
            assert (f.attrs["width"], f.attrs["height"]) == (W, H)
            # DSEC layout: t relative to t_offset, the first event's millisecond.
            assert f["t_offset"][()] == t[0] // 1000 * 1000
            np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], t)
            prov = dict(f["provenance"].attrs)
            np.testing.assert_array_equal(f["events/x"][:], x)
            np.testing.assert_array_equal(f["events/p"][:], np.where(p > 0, 1, -1))
        raw = (tmp_path / name).read_bytes()
        assert prov["source"] == str((tmp_path / name).resolve())
        assert prov["source_bytes"] == len(raw)
        assert prov["source_sha256"] == hashlib.sha256(raw).hexdigest()
        assert (prov["events"], prov["events_dropped"], prov["bytes_dropped"]) == (N, 0, 0)
        assert prov["decoder"].split()[0] == DECODERS[name.split(".")[0]]
    from evsplat.data.poses import read_tum

    times, c2w = read_tum(tmp_path / "poses.txt")
    np.testing.assert_array_equal(times, [tp for tp, _, _ in poses])
    np.testing.assert_allclose(c2w[:, 2, 3], np.arange(14.0))


# --- bad inputs: one line naming the file and the fix ---------------------------------------


def _bad_cases(tmp_path: Path):
    x, y, t, p = _events(5, n=600)
    cases = {}
    pose_only = write_bag(
        tmp_path / "poses_only.bag",
        x,
        y,
        t,
        p,
        events=False,
        poses=[(0, (0, 0, 0), (1, 0, 0, 0))],
    )
    cases["bag without event topic"] = (pose_only, [], "no event-array topic")
    cases["unknown message type on the chosen topic"] = (
        pose_only,
        ["--topic", "/mocap/pose"],
        "has message type geometry_msgs/msg/PoseStamped",
    )
    cases["missing topic"] = (pose_only, ["--topic", "/nope"], "no topic '/nope'")
    corrupt = tmp_path / "corrupt.raw"
    corrupt.write_bytes(_recording("evt2", x, y, t, p, b"% evt 9.9\n% geometry 320x240\n% end\n"))
    cases["RAW with corrupt header (unknown encoding)"] = (corrupt, [], "corrupt header")
    nogeom = tmp_path / "nogeom.raw"
    nogeom.write_bytes(_recording("evt2", x, y, t, p, b"% evt 2.0\n% end\n"))
    cases["RAW without sensor size"] = (nogeom, [], "no sensor size")
    dat = tmp_path / "wrongtype.dat"
    head = prophesee_writer.header("dat", W, H).replace(prophesee_writer.DAT_KIND, bytes([0, 4]))
    dat.write_bytes(_recording("dat", x, y, t, p, head))
    cases["DAT of another event type"] = (dat, [], "type/size bytes 0004")
    garbage = tmp_path / "garbage.aedat4"
    garbage.write_bytes(b"#!AER-DAT4.0\r\n" + bytes(range(256)) * 4)
    cases["corrupt AEDAT 4"] = (garbage, [], "cannot decode AEDAT 4")
    notbag = tmp_path / "not.bag"
    notbag.write_bytes(b"this is not a bag\n" * 10)
    cases["file that is not a bag"] = (notbag, [], "cannot open the bag")
    empty = tmp_path / "empty.dat"
    empty.write_bytes(b"")
    cases["empty recording"] = (empty, [], "file is empty")
    return cases


def test_bad_recordings_fail_with_one_line_naming_the_file(tmp_path, capsys):
    for what, (path, extra, expected) in _bad_cases(tmp_path).items():
        out = tmp_path / "out.h5"
        assert main(["convert", str(path), str(out), *extra]) == 2, what
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and str(path) in err and expected in err, (what, err)
        assert not out.exists() and not list(tmp_path.glob(".out.h5*")), what
        if not extra:  # the same error from the library entry point
            with pytest.raises(EvsplatError, match=re.escape(expected)):
                read_events(path)


# --- ROS 2 bags in SQLite (.db3), read in Rust --------------------------------------------


def _db3_events(files: list[Path], topic: str = "/dvs/events", compression: str = "none"):
    decoder = _core.Db3EventDecoder([str(f) for f in files], topic, 1000, compression)
    chunks = []
    while len((chunk := decoder.next_chunk(777))[0]):
        chunks.append(chunk)
    return tuple(np.concatenate([c[i] for c in chunks]) for i in range(4)), decoder.dropped()


@pytest.mark.parametrize("pkg", ["dvs_msgs", "prophesee_event_msgs"])
def test_ros2_db3_reader_matches_rosbags_event_by_event(tmp_path, pkg):
    x, y, t, p = _events(21, n=20_000, t0=1_600_000_000_000_000)
    poses = [(int(t[0]) + 50_000 * k, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)) for k in range(20)]
    bag = write_bag(tmp_path / "rec2", x, y, t, p, ros2=True, pkg=pkg, poses=poses)
    (db3,) = bag.glob("*.db3")
    ours, dropped = _db3_events([db3])
    _assert_same_events(ours, _rosbags_events(bag))
    _assert_same_events(ours, (x, y, t, p))
    assert dropped == (0, 0, 0)
    listed = [(topic, kind) for _, topic, kind in _core.db3_topics(db3)]
    assert listed == [
        ("/dvs/events", f"{pkg}/msg/EventArray"),
        ("/mocap/pose", "geometry_msgs/msg/PoseStamped"),
    ]
    for opened in (bag, db3):  # the bag's folder, or its .db3 file: read in Rust
        source = open_source(opened)
        n = sum(len(c[2]) for c in source.chunks)
        assert (source.decoder, source.width, source.height, n) == ("evsplat", W, H, len(t))
    # The topic's messages in timestamp order, not insertion order: rosbags' order.
    import sqlite3

    with sqlite3.connect(db3) as db:
        ids = [r[0] for r in db.execute("SELECT id FROM messages ORDER BY id")]
        db.execute("UPDATE messages SET id = -id")  # rows now stored in reverse
        assert len(ids) > 2
    ours, _ = _db3_events([db3])
    _assert_same_events(ours, (x, y, t, p))


def test_split_db3_bag_reads_its_files_in_the_metadata_order(tmp_path):
    # rosbags writes no split bags: two bags' files put in one folder, metadata listing both.
    x, y, t, p = _events(22, n=6000, t0=2_000_000)
    first = write_bag(tmp_path / "a", x[:3000], y[:3000], t[:3000], p[:3000], ros2=True)
    second = write_bag(tmp_path / "b", x[3000:], y[3000:], t[3000:], p[3000:], ros2=True)
    (db_a,), (db_b,) = first.glob("*.db3"), second.glob("*.db3")
    db_b.rename(first / "a_1.db3")
    meta = (first / "metadata.yaml").read_text()
    name = db_a.name
    assert f"- {name}" in meta
    (first / "metadata.yaml").write_text(meta.replace(f"- {name}", f"- {name}\n  - a_1.db3"))
    assert rosbag.ros2_files(first, "sqlite3").files == [db_a, first / "a_1.db3"]
    assert rosbag.ros2_files(db_a, "sqlite3").files == [db_a, first / "a_1.db3"]
    _assert_same_events(_db3_events(rosbag.ros2_files(first, "sqlite3").files)[0], (x, y, t, p))
    _assert_same_events(_rosbags_events(first), (x, y, t, p))  # the oracle agrees
    stream = read_events(first)
    _assert_same(stream, x, y, t, p)


def test_damaged_db3_is_one_line_naming_the_file_and_the_fix(tmp_path):
    x, y, t, p = _events(23, n=20_000, t0=2_000_000)
    bag = write_bag(tmp_path / "rec2", x, y, t, p, ros2=True)
    (db3,) = bag.glob("*.db3")
    data = db3.read_bytes()
    lone = tmp_path / "lone"
    lone.mkdir()
    for name, content in [("cut.db3", data[: len(data) // 2]), ("junk.db3", b"\x01" * 5000)]:
        path = lone / name
        path.write_bytes(content)
        with pytest.raises(EvsplatError) as err:
            read_events(path)
        msg = str(err.value)
        assert "\n" not in msg and str(path) in msg, msg
        assert "sqlite3 BAG.db3 .recover" in msg and "re-record" in msg, msg


def _temp_db3s() -> list[Path]:
    """This process's temporary .db3 files (the Rust reader's unpacked .db3.zstd files)."""
    import os
    import tempfile

    return sorted(Path(tempfile.gettempdir()).glob(f"evsplat-{os.getpid()}-*.db3"))


@pytest.mark.parametrize("mode", ["message", "file"])
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_compressed_ros2_bag_readers_match_rosbags_event_by_event(tmp_path, storage, mode):
    x, y, t, p = _events(24, n=20_000, t0=1_600_000_000_000_000)
    poses = [(int(t[0]) + 50_000 * k, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)) for k in range(20)]
    mcap = storage == "mcap"
    bag = write_bag(
        tmp_path / "rec2", x, y, t, p, ros2=True, poses=poses, compression=mode, mcap=mcap
    )
    found = rosbag.ros2_files(bag, storage)
    assert found is not None and found.compression == mode
    # rosbags names a compressed file NAME.db3.zstd (.mcap.zstd), listed so in metadata.yaml.
    name = "rec2.mcap" if mcap else "rec2.db3"
    assert [f.name for f in found.files] == [f"{name}.zstd" if mode == "file" else name]
    before = _temp_db3s()
    if mcap:
        decoder = _core.McapEventDecoder(found.files, "/dvs/events", 1 << 12, mode)
        chunks = []
        while len((chunk := decoder.next_chunk(777))[0]):
            chunks.append(chunk)
        ours = tuple(np.concatenate([c[i] for c in chunks]) for i in range(4))
        dropped = decoder.dropped()
    else:
        ours, dropped = _db3_events(found.files, compression=mode)
    _assert_same_events(ours, _rosbags_events(bag))
    _assert_same_events(ours, (x, y, t, p))
    assert dropped == (0, 0, 0)
    source = open_source(bag)
    n = sum(len(c[2]) for c in source.chunks)
    assert (source.decoder, source.width, source.height, n) == ("evsplat", W, H, len(t))
    assert _temp_db3s() == before  # a .db3's unpacked copy is removed once read
    times, _ = rosbag.read_bag_poses(bag)  # poses: still rosbags
    np.testing.assert_array_equal(times, [tp for tp, _, _ in poses])
    if mode == "file":
        # The packed file given itself reads as its bag; moved out of it, its topics are
        # nowhere to be found (its metadata.yaml lists them): one line saying so.
        _assert_same(read_events(found.files[0]), x, y, t, p)
        alone = tmp_path / "alone" / found.files[0].name
        alone.parent.mkdir()
        alone.write_bytes(found.files[0].read_bytes())
        with pytest.raises(EvsplatError, match="pass the bag's folder with its metadata.yaml"):
            open_source(alone)


def test_damaged_compressed_db3_is_one_line_naming_the_file_and_the_fix(tmp_path, capsys):
    import sqlite3

    x, y, t, p = _events(25, n=6000, t0=2_000_000)
    before = _temp_db3s()
    message = write_bag(tmp_path / "message", x, y, t, p, ros2=True, compression="message")
    (db3,) = message.glob("*.db3")
    with sqlite3.connect(db3) as db:  # the last message's zstd frame cut in half
        db.execute(
            "UPDATE messages SET data = substr(data, 1, length(data) / 2) "
            "WHERE id = (SELECT max(id) FROM messages)"
        )
    whole = write_bag(tmp_path / "file", x, y, t, p, ros2=True, compression="file")
    (packed,) = whole.glob("*.db3.zstd")
    packed.write_bytes(packed.read_bytes()[: packed.stat().st_size // 2])
    cases = [(message, db3, "message 12 of /dvs/events: zstd"), (whole, packed, "zstd")]
    for bag, named, what in cases:
        out = tmp_path / "out.h5"
        assert main(["convert", str(bag), str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and str(named) in err and what in err, err
        assert "zstd -t" in err and "re-record" in err, err
        assert not out.exists() and not list(tmp_path.glob(".out.h5*"))
    assert _temp_db3s() == before


def test_split_mcap_bag_reads_its_files_in_the_metadata_order(tmp_path):
    # rosbags' Writer does not split bags: two bags' files put in one folder, its
    # metadata.yaml edited to list both, as rosbag2 lists the files of a split bag.
    x, y, t, p = _events(26, n=20_000, t0=1_600_000_000_000_000)
    half = 11_000
    first = write_bag(tmp_path / "a", x[:half], y[:half], t[:half], p[:half], ros2=True, mcap=True)
    second = write_bag(tmp_path / "b", x[half:], y[half:], t[half:], p[half:], ros2=True, mcap=True)
    (mcap_a,), (mcap_b,) = first.glob("*.mcap"), second.glob("*.mcap")
    mcap_b.rename(first / "a_1.mcap")
    meta = (first / "metadata.yaml").read_text()
    assert f"- {mcap_a.name}" in meta
    listed = meta.replace(f"- {mcap_a.name}", f"- {mcap_a.name}\n  - a_1.mcap")
    (first / "metadata.yaml").write_text(listed)
    files = [mcap_a, first / "a_1.mcap"]
    assert rosbag.ros2_files(first, "mcap").files == files
    assert rosbag.ros2_files(mcap_a, "mcap").files == files
    decoder = _core.McapEventDecoder(files, "/dvs/events", 1 << 12)
    assert decoder.sensor_size() == (W, H)
    chunks = []
    while len((chunk := decoder.next_chunk(777))[0]):
        chunks.append(chunk)
    assert all(len(c[0]) == 777 for c in chunks[:-1])  # chunks run on across the files
    ours = tuple(np.concatenate([c[i] for c in chunks]) for i in range(4))
    _assert_same_events(ours, _rosbags_events(first))
    _assert_same_events(ours, (x, y, t, p))
    assert decoder.dropped() == (0, 0, 0)
    source = open_source(first)
    assert source.decoder == "evsplat"
    _assert_same(read_events(first), x, y, t, p)


def test_convert_reads_ahead_in_order_passes_errors_on_and_stops_with_its_reader():
    import time

    from evsplat.commands.convert import _ahead

    def failing():
        yield from ((i,) for i in range(5))
        raise EvsplatError("x.raw: cannot read events (boom); check the file")

    got = []
    with pytest.raises(EvsplatError, match="boom"):
        for (i,) in _ahead(failing()):
            got.append(i)
    assert got == [0, 1, 2, 3, 4]

    made = []

    def endless():
        while True:
            made.append(len(made))
            yield (made[-1],)

    ahead = _ahead(endless(), depth=2)
    assert next(ahead) == (0,)
    ahead.close()  # joins the thread
    n = len(made)
    time.sleep(0.3)
    assert len(made) == n <= 4  # one taken, two queued, one waiting to be queued
