"""Time-indexed event access: the millisecond index against numpy's searchsorted, window reads
against boolean masks of the whole file, files without an index (built once, cached beside
them, never rewritten), `check` on a corrupted index, `train --time-range`, and the
provenance `check` prints."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from evsplat import __version__
from evsplat.cli import main
from evsplat.data.dataset import load_dataset
from evsplat.data.event_files import read_events
from evsplat.data.event_index import sidecar_path
from evsplat.data.event_store import open_store
from evsplat.data.event_writer import write_events, write_events_h5
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError

W, H = 64, 48


def _stream(seed: int, n: int = 20_000, t0: int = 2**40 + 123_457) -> EventStream:
    """Bursts, gaps of several ms and repeated timestamps, on an absolute clock far from 0."""
    rng = np.random.default_rng(seed)
    gaps = rng.choice([0, 1, 7, 300, 4_000], size=n, p=[0.3, 0.4, 0.2, 0.09, 0.01])
    t = t0 + np.cumsum(gaps)
    return EventStream.from_arrays(
        rng.integers(0, W, n), rng.integers(0, H, n), t, rng.choice([-1, 1], n), W, H
    )


def _oracle_index(t: np.ndarray) -> tuple[int, np.ndarray]:
    origin = int(t[0]) // 1000 * 1000
    starts = origin + 1000 * np.arange((int(t[-1]) - origin) // 1000 + 1)
    return origin, np.searchsorted(t, starts, side="left")


def _masked(ev: EventStream, t0: int, t1: int) -> tuple[np.ndarray, ...]:
    keep = (ev.t >= t0) & (ev.t < t1)
    return tuple(getattr(ev, k)[keep] for k in "xytp")


def _assert_window(store, ev: EventStream, t0: int, t1: int) -> None:
    got = store.read(t0, t1)
    for k, want in zip("xytp", _masked(ev, t0, t1)):
        np.testing.assert_array_equal(getattr(got, k), want, err_msg=f"{k} of [{t0}, {t1})")


@pytest.mark.parametrize("pieces", [1, 7])
def test_written_index_matches_searchsorted_on_the_timestamps(tmp_path, pieces):
    ev = _stream(pieces)
    path = tmp_path / "ev.h5"
    # Several appended streams: the index is built across their boundaries.
    cuts = np.linspace(0, len(ev), pieces + 1).astype(int)
    write_events(path, W, H, [ev.slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])], chunk=999)
    origin, want = _oracle_index(ev.t)
    with h5py.File(path) as f:
        assert f["t_offset"][()] == origin
        np.testing.assert_array_equal(f["ms_to_idx"][()], want)
        assert f["events/t"].chunks == (999,) and f["events/t"].compression is not None
    store = open_store(path)
    assert (store.count, store.t_first_us, store.t_last_us) == (len(ev), ev.t[0], ev.t[-1])
    assert (store.width, store.height, store.index_source) == (W, H, "in the file")
    assert store.provenance == {}


def test_window_reads_equal_boolean_masks_of_the_whole_file(tmp_path):
    ev = _stream(3)
    path = tmp_path / "ev.h5"
    write_events_h5(path, ev, chunk=1000)
    store = open_store(path)
    first, last = int(ev.t[0]), int(ev.t[-1])
    rng = np.random.default_rng(0)
    windows = [
        (first, first + 50_000),  # the file's start
        (last - 50_000, last + 1),  # its end, last event included
        (first - 10**9, first + 1),  # from far before the file to its first event
        (last, last + 10**9),  # from the last event to far after
        (first - 10**9, first - 1),  # entirely before: empty
        (last + 1, last + 10**9),  # entirely after: empty
        (first - 10**9, last + 10**9),  # everything
        (first + 5_000, first + 5_000),  # zero length: empty
        (first + 9_000, first + 1_000),  # reversed: empty
    ]
    for _ in range(300):
        a = int(rng.integers(first - 3_000, last + 3_000))
        windows.append((a, a + int(rng.choice([1, 999, 1000, 1001, 20_000, 300_000]))))
    gap = int(np.argmax(np.diff(ev.t)))  # inside the longest gap: empty
    windows.append((int(ev.t[gap]) + 1, int(ev.t[gap + 1])))
    for t0, t1 in windows:
        _assert_window(store, ev, t0, t1)
    assert len(store.read(first - 10**9, first - 1)) == 0
    assert len(store.read(first + 9_000, first + 1_000)) == 0


def _foreign(path: Path, ev: EventStream) -> None:
    """DSEC-like flat file without ms_to_idx nor sensor size: t uint32 relative to t_offset,
    polarity 0/1."""
    with h5py.File(path, "w") as f:
        f["x"], f["y"] = ev.x, ev.y
        f["t"] = (ev.t - ev.t[0] + 17).astype(np.uint32)
        f["p"] = (ev.p > 0).astype(np.uint8)
        f["t_offset"] = ev.t[0] - 17


def test_foreign_file_gets_its_index_built_once_and_cached_beside_it(tmp_path):
    ev = _stream(5)
    path = tmp_path / "dsec.h5"
    _foreign(path, ev)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    store = open_store(path, width=W, height=H)
    assert store.index_source == f"built by a streaming pass, cached in {sidecar_path(path)}"
    assert sidecar_path(path).is_file() and sidecar_path(path).parent == tmp_path
    for t0 in ev.t[::1500]:
        _assert_window(store, ev, int(t0), int(t0) + 25_000)
    again = open_store(path, width=W, height=H)
    assert again.index_source == f"cached in {sidecar_path(path)}"
    np.testing.assert_array_equal(again.ms_to_idx, _oracle_index(ev.t)[1])
    _assert_window(again, ev, int(ev.t[0]), int(ev.t[-1]) + 1)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before  # never rewritten
    # Without a sensor size the smallest sensor holding the events, as read_events does.
    bare = open_store(path)
    assert (bare.width, bare.height) == (int(ev.x.max()) + 1, int(ev.y.max()) + 1)


def test_a_stale_cached_index_is_rebuilt(tmp_path):
    path = tmp_path / "dsec.h5"
    _foreign(path, _stream(6))
    open_store(path, width=W, height=H)
    other = _stream(7, n=5_000)
    _foreign(path, other)  # another recording under the same name
    store = open_store(path, width=W, height=H)
    assert store.index_source.startswith("built")
    _assert_window(store, other, int(other.t[0]), int(other.t[-1]) + 1)


def test_unsorted_foreign_file_fails_without_caching_anything(tmp_path):
    ev = _stream(8, n=3_000)
    path = tmp_path / "dsec.h5"
    _foreign(path, ev)
    with h5py.File(path, "r+") as f:
        t = f["t"][()]
        t[1000], t[1001] = t[1001] + 5, t[1000]
        f["t"][...] = t
    with pytest.raises(EvsplatError, match=r"dsec\.h5.*sort"):
        open_store(path, width=W, height=H)
    assert not sidecar_path(path).exists()


@pytest.fixture
def ball(tiny_scene, tmp_path) -> Path:
    """A copy of the tiny ball dataset, free to corrupt."""
    return Path(shutil.copytree(tiny_scene("ball"), tmp_path / "ball"))


def _edit_index(path: Path, edit) -> None:
    with h5py.File(path, "r+") as f:
        idx = f["ms_to_idx"][()].astype(np.int64)
        edit(idx)
        del f["ms_to_idx"]
        f["ms_to_idx"] = idx.astype(np.uint64)


def test_check_fails_on_an_index_that_disagrees_with_the_timestamps(ball, capsys):
    assert main(["check", str(ball)]) == 0
    _edit_index(ball / "events.h5", lambda idx: idx.__setitem__(300, idx[300] - 40))
    assert main(["check", str(ball)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2  # the problem, then the count
    assert "events.h5: the ms index (in the file) disagrees with the timestamps" in err[0]
    assert "ms_to_idx[300]" in err[0] and "re-convert" in err[0]
    # Loading checks only the structure; the window that uses the entry catches it.
    data = load_dataset(ball)
    with pytest.raises(EvsplatError, match=r"events\.h5: ms_to_idx\[300\] = .* disagrees"):
        data.events.read(300_000, 300_500)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda idx: idx.__setitem__(-1, idx[-1] + 10**6), "outside the file's"),
        (lambda idx: idx.__setitem__(10, 10**9), "decreases at ms 11"),
        (lambda idx: idx.resize(len(idx) - 5, refcheck=False), "span 600 ms"),
    ],
    ids=["past the end", "not monotone", "short of the span"],
)
def test_structurally_broken_index_is_a_one_line_load_error(ball, edit, match, capsys):
    _edit_index(ball / "events.h5", edit)
    with pytest.raises(EvsplatError, match=match) as e:
        load_dataset(ball)
    assert "\n" not in str(e.value) and "events.h5" in str(e.value)
    assert main(["check", str(ball)]) == 2
    assert match.split()[0] in capsys.readouterr().err


def test_train_on_a_time_range_reads_windows_inside_it_only(ball, tmp_path, monkeypatch):
    from evsplat.data.event_store import EventStore
    from evsplat.run_state import RunState

    reads = []
    real = EventStore.window  # every time-window read locates its events through it

    def spy(self, t0, t1):
        reads.append((t0, t1))
        return real(self, t0, t1)

    monkeypatch.setattr(EventStore, "window", spy)
    run = tmp_path / "run"
    argv = ["train", str(ball), "--out", str(run), "--preset", "tiny", "--iters", "3"]
    assert main([*argv, "--time-range", "0.2:0.45", "--no-progress"]) == 0
    camera = RunState.load(run).camera
    assert (camera.t_start_us, camera.t_end_us) == (200_000, 450_000)
    assert reads and all(200_000 <= a and b <= 450_000 for a, b in reads if b > a)


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ("abc", "expected START:END in seconds"),
        ("1:2:3", "expected START:END in seconds"),
        ("nan:1", "expected START:END in seconds"),
        ("0.5:0.9", "not inside the recording, 0:0.6 s"),
        ("0.4:0.2", "not inside the recording"),
        ("-1:", "0 <= START < END <= 0.6"),
    ],
)
def test_bad_time_range_is_a_one_line_error_and_writes_nothing(
    tiny_scene, tmp_path, capsys, value, match
):
    run = tmp_path / "run"
    argv = ["train", str(tiny_scene("ball")), "--out", str(run), "--iters", "1"]
    assert main([*argv, f"--time-range={value}", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "--time-range" in err and "\n" not in err
    assert not run.exists()


def test_check_reports_the_provenance_of_a_converted_file(tmp_path, capsys):
    ev = _stream(9, n=4_000)
    src = tmp_path / "rec.npz"
    np.savez(src, x=ev.x, y=ev.y, t=ev.t, p=ev.p, width=W, height=H)
    out = tmp_path / "rec.h5"
    assert main(["convert", str(src), str(out)]) == 0
    capsys.readouterr()
    assert main(["check", str(out)]) == 0
    text = capsys.readouterr().out
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    assert f"converted from {src.resolve()} ({src.stat().st_size:,} bytes, sha256 {digest})" in text
    assert f"with evsplat {__version__} (format npz): 4,000 events written, 0 dropped" in text
    assert "ms index:" in text and "in the file" in text
    np.testing.assert_array_equal(read_events(out).t, ev.t)


def _quiet_start(ball: Path, recorded_us: tuple[int, int] | None) -> None:
    """The ball's events before 200 ms dropped (as a still camera sees a scene where nothing
    moves until then), rewritten with or without the span the sensor recorded."""
    ev = read_events(ball / "events.h5")
    late = ev.slice(int(np.searchsorted(ev.t, 200_000)), len(ev))
    write_events_h5(ball / "events.h5", late, recorded_us=recorded_us)


def test_a_quiet_start_is_no_cut_recording_where_the_file_says_what_it_recorded(ball, capsys):
    _quiet_start(ball, None)
    assert main(["check", str(ball)]) == 2  # its first event at 200 ms: cut, as far as one knows
    assert "shorter than the data's time range" in capsys.readouterr().err
    _quiet_start(ball, (0, 600_000))
    assert main(["check", str(ball)]) == 0
    store = load_dataset(ball).events
    assert store.recorded_us == (0, 600_000) and store.t_first_us >= 200_000


def test_a_recorded_span_must_hold_the_events(ball, tmp_path):
    ev = read_events(ball / "events.h5")
    with pytest.raises(EvsplatError, match=r"outside the recorded span \[0, 500000\]"):
        write_events_h5(tmp_path / "e.h5", ev, recorded_us=(0, 500_000))
    assert not (tmp_path / "e.h5").exists()  # atomic: nothing half-written
    with h5py.File(ball / "events.h5", "r+") as f:
        f.attrs["recorded_us"] = np.array([300_000, 600_000], dtype=np.int64)
    with pytest.raises(EvsplatError, match="does not hold the events") as e:
        load_dataset(ball)
    assert "\n" not in str(e.value) and "events.h5" in str(e.value)
