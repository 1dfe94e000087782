"""Where the training windows fall in the sequence (evsplat.train.views.Views.draw_times), and
the held-out intervals they keep off (evsplat.train.heldout)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from evsplat.config import HoldoutConfig, LossConfig
from evsplat.errors import EvsplatError
from evsplat.train.heldout import free_spans, heldout_intervals
from evsplat.train.views import Views


def test_windows_reach_both_ends_as_the_analytic_placement_says() -> None:
    """A fixed window of length L over a sequence of T (flow window τ after it) is placed as
    if the sequence went on past its ends and then pushed inside: its last render is drawn
    from T - τ + L + 1 equally likely instants, L of which push it to the start and L to the
    end, so each end takes L / (T - τ + L + 1) of the windows, and no window leaves the
    sequence."""
    start, duration = 1_000_000, 1_000_000
    lc = LossConfig(views=2, window_min=0.25, window_max=0.25, flow_window=0.005)
    owner = _views(start, start + duration)
    rng = np.random.default_rng(0)
    draws = [owner.draw_times(rng, lc, True) for _ in range(20_000)]
    span, dtau = duration // 4, duration // 200
    times = np.array([d[0] for d in draws])
    assert all(d[1] == dtau for d in draws)
    np.testing.assert_array_equal(times[:, 1] - times[:, 0], span)
    assert times.min() >= start and times[:, 1].max() <= start + duration - dtau
    share = span / (duration - dtau + span + 1)
    assert abs(np.mean(times[:, 0] == start) - share) < 0.015
    assert abs(np.mean(times[:, 1] == start + duration - dtau) - share) < 0.015


def test_a_window_longer_than_the_sequence_is_not_drawn() -> None:
    lc = LossConfig(views=3, window_min=0.6, window_max=0.6)
    assert _views(0, 1000).draw_times(np.random.default_rng(0), lc, False) is None


def _views(start: int, end: int, heldout: list | None = None) -> Views:
    """Views of a sequence [start, end] µs: all ``draw_times`` needs."""
    data = SimpleNamespace(t_start_us=start, t_end_us=end)
    return Views(data, renderer=None, channel_map=None, heldout=heldout or [])


@pytest.mark.parametrize("moving", [True, False])
def test_no_drawn_window_nor_what_follows_it_touches_a_held_out_interval(moving) -> None:
    """With held-out intervals, everything a step reads, [t_0, t_last + the motion losses'
    reach), stays off them, long windows included (then redrawn or shortened), and the gaps
    stay positive and in order."""
    start, end = 0, 2_000_000
    cfg = HoldoutConfig(windows=8, length=0.025)
    heldout = heldout_intervals(start, end, cfg, seed=3)
    views = _views(start, end, heldout)
    lc = LossConfig(views=3)
    reach = int(max(lc.flow_window, lc.motion_window) * (end - start)) if moving else 0
    rng = np.random.default_rng(1)
    spans = []
    for _ in range(3000):
        times, dtau = views.draw_times(rng, lc, moving)
        assert all(b > a for a, b in zip(times, times[1:]))
        assert times[0] >= start and times[-1] + dtau <= end  # L_m's window stops at the end
        first, last = times[0], min(times[-1] + reach, end)
        assert not any(first < b and a < last for a, b in heldout), (times, heldout)
        spans.append(times[-1] - times[0])
    # Free spans between the intervals are ~10% of the sequence: L_e's windows of up to 30%
    # come out shorter, but not all of them minimal.
    assert max(spans) <= max(b - a for a, b in free_spans(heldout, start, end))
    assert np.std(spans) > 0


def test_held_out_intervals_are_evenly_spread_seeded_and_bounded() -> None:
    cfg = HoldoutConfig(windows=8, length=0.02)
    a = heldout_intervals(1_000, 1_001_000, cfg, seed=0)
    assert a == heldout_intervals(1_000, 1_001_000, cfg, seed=0)
    assert a != heldout_intervals(1_000, 1_001_000, cfg, seed=1)
    assert [t1 - t0 for t0, t1 in a] == [20_000] * 8
    for k, (t0, t1) in enumerate(a):  # one inside each eighth
        assert 1_000 + k * 125_000 <= t0 and t1 <= 1_000 + (k + 1) * 125_000
    assert heldout_intervals(0, 10, HoldoutConfig(), seed=0) == []
    with pytest.raises(EvsplatError, match="fewer or shorter"):
        heldout_intervals(0, 1_000_000, HoldoutConfig(windows=30, length=0.02), seed=0)
    assert free_spans([(10, 20), (30, 40)], 0, 50) == [(0, 10), (20, 30), (40, 50)]
