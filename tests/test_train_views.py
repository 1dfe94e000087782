"""Where the training windows fall in the sequence (evsplat.train.views.Views.draw_times)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from evsplat.config import LossConfig
from evsplat.train.views import Views


def test_windows_reach_both_ends_as_the_analytic_placement_says() -> None:
    """A fixed window of length L over a sequence of T (flow window τ after it) is placed as
    if the sequence went on past its ends and then pushed inside: its last render is drawn
    from T - τ + L + 1 equally likely instants, L of which push it to the start and L to the
    end, so each end takes L / (T - τ + L + 1) of the windows, and no window leaves the
    sequence."""
    start, duration = 1_000_000, 1_000_000
    lc = LossConfig(views=2, window_min=0.25, window_max=0.25, flow_window=0.005)
    owner = SimpleNamespace(data=SimpleNamespace(t_start_us=start, t_end_us=start + duration))
    rng = np.random.default_rng(0)
    draws = [Views.draw_times(owner, rng, lc, True) for _ in range(20_000)]
    span, dtau = duration // 4, duration // 200
    times = np.array([d[0] for d in draws])
    assert all(d[1] == dtau for d in draws)
    np.testing.assert_array_equal(times[:, 1] - times[:, 0], span)
    assert times.min() >= start and times[:, 1].max() <= start + duration - dtau
    share = span / (duration - dtau + span + 1)
    assert abs(np.mean(times[:, 0] == start) - share) < 0.015
    assert abs(np.mean(times[:, 1] == start + duration - dtau) - share) < 0.015


def test_a_window_longer_than_the_sequence_is_not_drawn() -> None:
    owner = SimpleNamespace(data=SimpleNamespace(t_start_us=0, t_end_us=1000))
    lc = LossConfig(views=3, window_min=0.6, window_max=0.6)
    assert Views.draw_times(owner, np.random.default_rng(0), lc, False) is None
