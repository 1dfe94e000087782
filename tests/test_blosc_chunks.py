"""The Blosc chunks made in Rust (``_core.blosc_chunks``) and written with
``write_direct_chunk``, checked against an independent oracle: stock h5py + hdf5plugin (c-blosc)
decompress them and must give back the input, for every dtype, partial last chunks, empty and
incompressible columns; and the event writer and ``evsplat convert`` built on them."""

from __future__ import annotations

from pathlib import Path

import h5py
import hdf5plugin
import numpy as np
import pytest

from evsplat import _core
from evsplat.data import event_writer
from evsplat.data.event_writer import write_events
from evsplat.data.events import EventStream

CHUNK = 1000
DTYPES = ["u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8", "<u2", ">i4"]


def _column(dtype: str, n: int, kind: str, rng) -> np.ndarray:
    dt = np.dtype(dtype)
    if kind == "noise":  # incompressible: random bytes
        return np.frombuffer(rng.bytes(n * dt.itemsize), dt).copy()
    if kind == "zeros":
        return np.zeros(n, dt)
    # Event-like: slowly rising values with noise in the low bits.
    steps = np.cumsum(rng.integers(0, 4, n))
    return (steps % 251 if dt.itemsize == 1 else steps).astype(dt)


def _write_direct(path: Path, a: np.ndarray, chunk: int, threads: int = 1) -> None:
    with h5py.File(path, "w") as f:
        d = f.create_dataset(
            "a", shape=a.shape, dtype=a.dtype, chunks=(chunk,), maxshape=(None,),
            **hdf5plugin.Blosc(),
        )  # fmt: skip
        raw = np.ascontiguousarray(a).view(np.uint8)
        size = a.dtype.itemsize
        for i, (data, mask) in enumerate(
            _core.blosc_chunks(raw, size, chunk * size, 5, True, threads)
        ):
            d.id.write_direct_chunk((i * chunk,), data, mask)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("kind", ["events", "noise", "zeros"])
def test_blosc_chunks_decode_with_hdf5plugin_to_the_input(tmp_path, dtype, kind):
    rng = np.random.default_rng([DTYPES.index(dtype), len(kind)])
    for n in (1, CHUNK - 1, CHUNK, 3 * CHUNK + 17):
        a = _column(dtype, n, kind, rng)
        path = tmp_path / f"{n}.h5"
        _write_direct(path, a, CHUNK)
        with h5py.File(path) as f:
            back = f["a"][:]
            whole = [f["a"].id.get_chunk_info(i).filter_mask for i in range(n // CHUNK)]
        assert back.dtype == a.dtype
        np.testing.assert_array_equal(back, a)
        # Whole chunks of random bytes do not shrink: stored as they are, the filter skipped
        # (as HDF5 does when the Blosc filter gives up); zeros always shrink.
        if kind == "noise" and a.dtype.itemsize > 1:
            assert set(whole) <= {1}
        if kind == "zeros":
            assert set(whole) <= {0}


def test_blosc_chunks_of_an_empty_column_are_none_and_threads_change_no_byte():
    assert _core.blosc_chunks(np.zeros(0, np.uint8), 2, 2 * CHUNK, 5, True) == []
    a = np.cumsum(np.random.default_rng(3).integers(0, 9, 20 * CHUNK + 5)).astype(np.int64)
    one, three = (
        _core.blosc_chunks(a.view(np.uint8), 8, 8 * CHUNK, 5, True, threads) for threads in (1, 3)
    )
    assert one == three and len(one) == 21
    with pytest.raises(ValueError, match="whole number"):
        _core.blosc_chunks(a.view(np.uint8), 8, 8 * CHUNK + 3, 5, True)


def _stream(n: int, seed: int = 0) -> EventStream:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 7, n)) + 1_700_000_000_000_000
    return EventStream.from_arrays(
        rng.integers(0, 1280, n), rng.integers(0, 720, n), t, rng.choice([-1, 1], n), 1280, 720
    )


def test_the_writers_blosc_chunks_match_the_filters_file_for_uneven_streams(tmp_path, monkeypatch):
    ev = _stream(7 * CHUNK + 333)
    cuts = [0, 1, 999, 1000, 2500, 6000, len(ev)]
    parts = [ev.slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])]
    write_events(tmp_path / "direct.h5", 1280, 720, parts, chunk=CHUNK)
    # The same streams through h5py's filter (main's writes before the direct chunks).
    monkeypatch.setattr(event_writer, "_blosc_lz4", lambda options: None)
    write_events(tmp_path / "filter.h5", 1280, 720, parts, chunk=CHUNK)
    with h5py.File(tmp_path / "direct.h5") as a, h5py.File(tmp_path / "filter.h5") as b:
        for k in "xytp":
            da, db = a["events"][k], b["events"][k]
            assert (da.dtype, da.shape, da.chunks, da.maxshape) == (
                db.dtype, db.shape, db.chunks, db.maxshape,
            )  # fmt: skip
            assert da._filters == db._filters == {"32001": da._filters["32001"]}
            np.testing.assert_array_equal(da[:], db[:])
        np.testing.assert_array_equal(a["events/x"][:], ev.x)
        np.testing.assert_array_equal(a["events/t"][:] + a["t_offset"][()], ev.t)
        np.testing.assert_array_equal(a["ms_to_idx"][:], b["ms_to_idx"][:])
        assert a["t_offset"][()] == b["t_offset"][()]


def test_convert_output_reads_back_the_recordings_events(tmp_path, monkeypatch):
    from evsplat.cli import main
    from evsplat.commands import convert
    from evsplat.data.event_files import read_events
    from evsplat.data.formats import prophesee_writer

    n = 3 * (1 << 16) + 4321  # three whole HDF5 chunks and a partial one
    rng = np.random.default_rng(5)
    x, y = rng.integers(0, 640, n), rng.integers(0, 480, n)
    t, p = np.sort(rng.integers(0, 3_000_000, n)), rng.integers(0, 2, n)
    src = tmp_path / "rec.raw"
    src.write_bytes(prophesee_writer.encode("evt3", x, y, t, p, 640, 480))
    monkeypatch.setattr(convert, "BATCH", 1 << 17)  # several batches, the last one short
    assert main(["convert", str(src), str(tmp_path / "rec.h5")]) == 0
    ev = read_events(tmp_path / "rec.h5")
    np.testing.assert_array_equal(ev.x, x)
    np.testing.assert_array_equal(ev.y, y)
    np.testing.assert_array_equal(ev.t, t)
    np.testing.assert_array_equal(ev.p, np.where(p > 0, 1, -1))
    with h5py.File(tmp_path / "rec.h5") as f:
        assert f["events/t"]._filters["32001"][4:] == (5, 1, 1)  # clevel 5, shuffle, LZ4
