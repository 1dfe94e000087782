"""Event file readers and the HDF5 writer: round trips for every layout and codec, unit
detection, chunked reads, atomic writes, and one-line errors for malformed files."""

from __future__ import annotations

import h5py
import hdf5plugin
import numpy as np
import pytest

from evsplat.data import event_files
from evsplat.data.event_files import read_events
from evsplat.data.event_writer import write_events_h5
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError


@pytest.fixture
def stream() -> EventStream:
    rng = np.random.default_rng(1)
    n = 2000
    t = np.sort(rng.integers(0, 5_000_000, n)) + 2**40
    return EventStream.from_arrays(
        rng.integers(0, 346, n), rng.integers(0, 260, n), t, rng.choice([-1, 1], n), 346, 260
    )


def assert_same(a: EventStream, b: EventStream) -> None:
    assert (a.width, a.height) == (b.width, b.height)
    for k in "xytp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


@pytest.mark.parametrize("compression", ["gzip", "lzf", "zstd", "blosc", "none"])
def test_h5_round_trip_preserves_events_for_every_codec(tmp_path, stream, compression):
    path = tmp_path / "ev.h5"
    write_events_h5(path, stream, compression=compression, chunk=500)
    with h5py.File(path) as f:
        assert f["events/t"].chunks == (500,)
        assert f["events/x"].dtype == np.uint16 and f.attrs["width"] == 346
    assert_same(read_events(path), stream)
    assert [p.name for p in tmp_path.iterdir()] == ["ev.h5"]


def test_h5_reader_streams_large_datasets_in_chunks(tmp_path, stream, monkeypatch):
    path = tmp_path / "ev.h5"
    write_events_h5(path, stream)
    monkeypatch.setattr(event_files, "READ_CHUNK", 7)
    assert_same(read_events(path), stream)


def test_flat_h5_with_dsec_encodings_and_t_offset(tmp_path, stream):
    """Flat /x,/y,/t,/p, polarity 0/1 as uint8 (DSEC), t relative to a t_offset dataset."""
    path = tmp_path / "flat.hdf5"
    with h5py.File(path, "w") as f:
        f["x"], f["y"] = stream.x, stream.y
        f.create_dataset("t", data=stream.t - stream.t[0], **hdf5plugin.Blosc())
        f["p"] = (stream.p > 0).astype(np.uint8)
        f["t_offset"] = stream.t[0]
    ev = read_events(path, width=346, height=260)
    assert_same(ev, stream)


def test_sensor_size_defaults_to_max_coordinate_plus_one(tmp_path, stream):
    path = tmp_path / "ev.npz"
    np.savez(path, x=stream.x, y=stream.y, t=stream.t, p=stream.p)
    ev = read_events(path)
    assert (ev.width, ev.height) == (int(stream.x.max()) + 1, int(stream.y.max()) + 1)
    np.savez(path, x=stream.x, y=stream.y, t=stream.t, p=stream.p, width=346, height=260)
    assert_same(read_events(path), stream)
    assert read_events(path, width=400).width == 400


def test_text_microseconds_and_seconds_are_detected(tmp_path, stream):
    us = tmp_path / "us.txt"
    rows = np.column_stack([stream.t, stream.x, stream.y, stream.p])
    np.savetxt(us, rows, fmt="%d", header="t x y p")
    assert_same(read_events(us, width=346, height=260), stream)
    sec = tmp_path / "sec.csv"
    rel = stream.t - stream.t[0]
    cols = [rel / 1e6, stream.x, stream.y, (stream.p > 0).astype(int)]
    with open(sec, "w") as f:
        f.write("t,x,y,p\n")
        for r in zip(*cols):
            f.write(f"{r[0]:.6f},{r[1]},{r[2]},{r[3]}\n")
    ev = read_events(sec, width=346, height=260)
    np.testing.assert_array_equal(ev.t, rel)
    np.testing.assert_array_equal(ev.p, stream.p)


def test_time_unit_overrides_detection(tmp_path):
    path = tmp_path / "ev.txt"
    path.write_text("1 0 0 1\n2 1 0 0\n")
    assert list(read_events(path, time_unit="s").t) == [1_000_000, 2_000_000]
    assert list(read_events(path).t) == [1, 2]
    path.write_text("1.0 0 0 1\n2.0 1 0 0\n")
    assert list(read_events(path, time_unit="us").t) == [1, 2]


def test_failed_write_leaves_existing_file_intact_and_no_temp_file(tmp_path, stream, monkeypatch):
    path = tmp_path / "ev.h5"
    write_events_h5(path, stream)
    before = path.read_bytes()
    calls = []

    def fail_on_second(self, name, **kw):
        calls.append(name)
        if len(calls) == 2:
            raise OSError("disk full")
        return original(self, name, **kw)

    original = h5py.Group.create_dataset
    monkeypatch.setattr(h5py.Group, "create_dataset", fail_on_second)
    with pytest.raises(EvsplatError, match="cannot write .*disk full"):
        write_events_h5(path, stream)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ev.h5"]


def _h5(path, **arrays):
    with h5py.File(path, "w") as f:
        for k, v in arrays.items():
            f[f"events/{k}"] = v
    return path


def _good(**change):
    arrays = {"x": [0, 1, 2], "y": [0, 0, 1], "t": [1, 2, 3], "p": [1, -1, 1]}
    arrays.update(change)
    return {k: np.asarray(v) for k, v in arrays.items()}


def _truncated(tmp_path, stream):
    path = tmp_path / "cut.h5"
    write_events_h5(path, stream)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


MALFORMED = {
    "unsorted t": (
        lambda d, s: _h5(d / "a.h5", **_good(t=[1, 5, 3])),
        r"timestamps not sorted at index 2 \(t=3 < 5\)",
    ),
    "x >= width": (
        lambda d, s: np.savez(d / "a.npz", **_good(x=[0, 9, 1]), width=4, height=2) or d / "a.npz",
        r"x outside the sensor at index 1 \(x=9 >= width 4\)",
    ),
    "negative y": (
        lambda d, s: _h5(d / "a.h5", **_good(y=[0, -2, 0])),
        r"y negative at index 1 \(y=-2\)",
    ),
    "polarity 3": (
        lambda d, s: (d / "a.txt").write_text("1 0 0 1\n2 0 0 3\n") and d / "a.txt",
        r"polarity 3 at index 1",
    ),
    "length mismatch": (
        lambda d, s: _h5(d / "a.h5", **_good(t=[1, 2])),
        r"different lengths \(x: 3, y: 3, t: 2, p: 3\)",
    ),
    "NaN in text": (
        lambda d, s: (d / "a.txt").write_text("1 0 0 1\n2 nan 0 1\n") and d / "a.txt",
        r"x is not finite at index 1",
    ),
    "truncated HDF5": (_truncated, r"cannot read HDF5 .*truncated"),
    "missing dataset": (
        lambda d, s: _h5(d / "a.h5", **{k: v for k, v in _good().items() if k != "p"}),
        r"missing dataset /events/p",
    ),
    "empty file": (lambda d, s: (d / "a.h5").touch() or d / "a.h5", r"file is empty"),
    "float x with fractions": (
        lambda d, s: np.savez(d / "a.npz", **_good(x=[0.0, 1.5, 2.0])) or d / "a.npz",
        r"x is not an integer at index 1 \(x=1.5\)",
    ),
    "string dtype": (
        lambda d, s: np.savez(d / "a.npz", **_good(y=["a", "b", "c"])) or d / "a.npz",
        r"y has dtype <U1",
    ),
    "wrong column count": (
        lambda d, s: (d / "a.txt").write_text("1 0 0\n2 0 0\n") and d / "a.txt",
        r"3 columns; expected 4",
    ),
    "mixed polarity encodings": (
        lambda d, s: _h5(d / "a.h5", **_good(p=[0, -1, 1])),
        r"mixes the 0/1 and -1/\+1",
    ),
    "missing npz array": (
        lambda d, s: np.savez(d / "a.npz", x=[0], y=[0], t=[0]) or d / "a.npz",
        r"missing array p",
    ),
    "not a zip": (
        lambda d, s: (d / "a.npz").write_bytes(b"garbage") and d / "a.npz",
        r"cannot read .npz",
    ),
    "unknown extension": (
        lambda d, s: (d / "a.aedat").write_bytes(b"x") and d / "a.aedat",
        r"unknown event file type '.aedat'",
    ),
    "comments only": (
        lambda d, s: (d / "a.txt").write_text("# t x y p\n\n") and d / "a.txt",
        r"no events",
    ),
    "2-D dataset": (
        lambda d, s: _h5(d / "a.h5", **_good(x=[[0, 1, 2]])),
        r"dataset /events/x has shape \(1, 3\)",
    ),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_file_gives_one_line_error_naming_file_and_problem(tmp_path, stream, case):
    make, message = MALFORMED[case]
    path = make(tmp_path, stream)
    with pytest.raises(EvsplatError, match=message) as err:
        read_events(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "\n" not in text


def test_bad_reader_and_writer_arguments_are_one_line_errors(tmp_path, stream):
    with pytest.raises(EvsplatError, match="time_unit 'ms' is unknown"):
        read_events(tmp_path / "a.h5", time_unit="ms")
    with pytest.raises(EvsplatError, match="no such file"):
        read_events(tmp_path / "missing.h5")
    with pytest.raises(EvsplatError, match="compression 'brotli' is unknown"):
        write_events_h5(tmp_path / "a.h5", stream, compression="brotli")
    with pytest.raises(EvsplatError, match="cannot write"):
        write_events_h5(tmp_path / "no" / "dir" / "a.h5", stream)


def test_text_reader_streams_lines_in_chunks(tmp_path, stream, monkeypatch):
    path = tmp_path / "ev.txt"
    np.savetxt(path, np.column_stack([stream.t, stream.x, stream.y, stream.p]), fmt="%d")
    monkeypatch.setattr(event_files, "TEXT_CHUNK", 7)
    assert_same(read_events(path, width=346, height=260), stream)
