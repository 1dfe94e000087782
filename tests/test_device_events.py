"""Event windows accumulated by torch on the training device (evsplat.train.device_events)
against the Rust core's ``EventStore.accumulate``, the oracle, on the CPU device."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsplat.data.dataset import load_dataset
from evsplat.errors import EvsplatError
from evsplat.train.device_events import SLOT_BYTES, DeviceEvents

# Not the dataset's 0.2: unequal thresholds that float32 cannot hold exactly catch a swapped
# polarity and a threshold rounded differently from the core.
C_POS, C_NEG = 0.23, 0.17


@pytest.fixture(scope="module")
def store(tiny_scene):
    data = load_dataset(tiny_scene("ball"))
    yield data.events
    data.events.close()


def windows(count: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Random index windows, and the edge cases: empty ones (also at the ends), the first and
    last events alone, both ends of the recording, all of it."""
    drawn = [tuple(sorted(rng.integers(0, count + 1, size=2))) for _ in range(12)]
    short = [(s, s + int(rng.integers(1, 50))) for s in rng.integers(0, count - 50, size=4)]
    edges = [(0, 0), (count, count), (777, 777), (0, 1), (count - 1, count)]
    ends = [(0, count // 7), (count - count // 5, count), (0, count)]
    return [(int(a), int(b)) for a, b in drawn + short + edges + ends]


def assert_same_as_core(events: DeviceEvents, store, i0: int, i1: int) -> None:
    esi, mask, count = events.accumulate(i0, i1)
    want_esi, want_mask, want_count = store.accumulate(i0, i1, C_POS, C_NEG)
    assert esi.dtype == torch.float32 and mask.dtype == torch.bool
    # Exact: both count in integers and round C+ n+ - C- n- once (one core slice: the
    # windows here are shorter than READ_CHUNK).
    np.testing.assert_array_equal(esi.numpy(), want_esi, err_msg=f"window [{i0}, {i1})")
    np.testing.assert_array_equal(mask.numpy(), want_mask)
    assert count == want_count == i1 - i0


def test_the_whole_recording_on_the_device_gives_the_cores_esi_mask_and_count(store):
    events = DeviceEvents(store, C_POS, C_NEG, "cpu")
    assert events.whole and len(events._slots) == store.count
    for i0, i1 in windows(store.count, np.random.default_rng(0)):
        assert_same_as_core(events, store, i0, i1)


def test_a_recording_over_the_budget_is_read_by_window_in_bounded_pieces(store):
    """A budget of 10,000 events: windows are read through the store in pieces of at most that,
    and the values are the core's all the same."""
    budget = 10_000
    events = DeviceEvents(store, C_POS, C_NEG, "cpu", budget_bytes=budget * SLOT_BYTES)
    assert not events.whole
    rng = np.random.default_rng(1)
    for i0, i1 in windows(store.count, rng):
        assert_same_as_core(events, store, i0, i1)
        assert len(events._slots) <= budget
    # A window inside the piece last read reads nothing new.
    i0 = store.count // 2
    events.accumulate(i0, i0 + 5000)
    read = store.events_read
    assert_same_as_core(events, store, i0 + 1000, i0 + 4000)
    assert store.events_read - read == 3000  # the oracle's own read, nothing for the device


def test_a_rectified_recording_is_left_to_the_core(store, monkeypatch):
    monkeypatch.setattr(type(store), "transforms", property(lambda s: True))
    with pytest.raises(EvsplatError, match="rectified as read are accumulated by the Rust core"):
        DeviceEvents(store, C_POS, C_NEG, "cpu")
