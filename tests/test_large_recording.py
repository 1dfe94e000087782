"""A long recording at small scale (2 M events, `evsplat bench large`'s generator and dataset
folder): a 50 ms window costs the same events read at the start, middle and end of the file,
training streams its long windows in bounded slices instead of loading them, a capped read
(the spin's) thins a window slice by slice, and the benchmark runs end to end. The oracle is
the store's count of events the file gave (``events_read``, ``largest_read``), never a time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evsplat.bench.decode import synthetic_chunks
from evsplat.bench.large import window_starts, write_dataset_files
from evsplat.data import event_store
from evsplat.data.event_store import EventStore, open_store
from evsplat.data.event_writer import write_events
from evsplat.data.events import EventStream

SIDE, EVENTS, RATE = 64, 2_000_000, 2e6  # 1 s of recording, 2000 events per millisecond


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A dataset folder around 2 M synthetic events (row runs on a 64x64 sensor)."""
    folder = tmp_path_factory.mktemp("large") / "data"
    folder.mkdir()
    chunks = synthetic_chunks(EVENTS, RATE, seed=3, size=1 << 18, width=SIDE, height=SIDE)
    streams = (EventStream.from_arrays(*c, SIDE, SIDE) for c in chunks)
    write_events(folder / "events.h5", SIDE, SIDE, streams)
    with open_store(folder / "events.h5") as store:
        write_dataset_files(folder, SIDE, SIDE, store.t_first_us, store.t_last_us + 1)
    return folder


def test_a_window_costs_the_same_events_read_at_the_start_middle_and_end(recording):
    length = 50_000
    with open_store(recording / "events.h5") as store:
        idx = np.append(store.ms_to_idx, store.count)  # the last millisecond runs to the end
        costs = {}
        for region, starts in window_starts(store.t_first_us, store.t_last_us, length, 3).items():
            for t0 in starts:
                before = store.events_read
                ev = store.read(t0, t0 + length)
                cost = store.events_read - before
                # The window, plus each end millisecond's events and a neighbour either side
                # (read to locate the window and check the index entries it used).
                ends = [(t - store.origin) // 1000 for t in (t0, t0 + length)]
                slack = sum(int(idx[min(k + 1, len(idx) - 1)] - idx[k]) + 2 for k in ends)
                assert len(ev) <= cost <= len(ev) + slack, (region, t0)
                assert np.all((ev.t >= t0) & (ev.t < t0 + length))
                costs.setdefault(region, []).append(cost)
    medians = [float(np.median(c)) for c in costs.values()]
    assert max(medians) <= 1.5 * min(medians), costs
    assert min(medians) > 0.03 * EVENTS  # a real window: 50 ms of 1 s


def test_training_streams_long_windows_in_slices_never_the_whole_window(
    recording, tmp_path, monkeypatch
):
    from evsplat.train import train

    slice_events = 20_000
    monkeypatch.setattr(event_store, "READ_CHUNK", slice_events)
    stores: list[EventStore] = []
    windows: list[int] = []
    real = EventStore.accumulate

    def spy(self, i0, i1, c_pos, c_neg):
        out = real(self, i0, i1, c_pos, c_neg)
        stores.append(self)
        windows.append(out[2])
        return out

    monkeypatch.setattr(EventStore, "accumulate", spy)
    train(recording, tmp_path / "run", preset_name="tiny", iterations=3, progress=False)
    # L_e's windows (2-30% of the recording) hold far more events than a slice (and L_m's
    # 2% twice one)...
    assert max(windows) > 10 * slice_events
    # ... yet the file never gave more than one slice at once.
    store = stores[-1]
    assert store.largest_read <= slice_events


def test_a_capped_read_keeps_every_kth_event_one_slice_at_a_time(recording, monkeypatch):
    monkeypatch.setattr(event_store, "READ_CHUNK", 30_000)
    t0, t1 = 100_000, 400_000  # 30% of the recording: ~600 000 events
    with open_store(recording / "events.h5") as store:
        whole = store.read(t0, t1)
        store.largest_read = 0
        thinned = store.read(t0, t1, most=50_000)
        assert store.largest_read <= 30_000
    step = -(-len(whole) // 50_000)
    assert len(thinned) <= 50_000
    for k in "xytp":
        np.testing.assert_array_equal(getattr(thinned, k), getattr(whole, k)[::step])


def test_bench_large_runs_end_to_end_and_leaves_nothing(tmp_path, capsys):
    from evsplat.cli import main

    args = ["bench", "large", "--events=300000", "--iters=1", "--windows=2", "--json"]
    assert main([*args, f"--dir={tmp_path}"]) == 0
    result = json.loads(capsys.readouterr().out)
    commands = [c["command"].split()[1] for c in result["children"]]
    assert commands == ["convert", "check", "train"]
    assert all(c["peak_rss_mb"] > 0 for c in result["children"])
    for kind in ("warm", "cold"):
        assert set(result[f"windows_{kind}"]) == {"start", "middle", "end"}
    assert not list(tmp_path.iterdir())  # the scratch folder is deleted
