"""Held-out event windows (``HoldoutConfig``): intervals of the recording that training never
reads, so `evsplat eval` can score how well the model predicts events it has not seen.

Unlike the early stop's windows (``skips.holdout_windows``), which training also learns from,
these are kept out of every read: L_e's, L_ef's and L_m's windows (``Views.draw_times``), the
static-scene evidence, the early stop's windows and the mover's seeding."""

from __future__ import annotations

import numpy as np

from evsplat.config import HoldoutConfig
from evsplat.errors import EvsplatError

HELDOUT_STREAM = 2**40 + 2  # RNG stream of the held-out windows; no iteration's seed reaches it

#: The most of the sequence held out: training keeps at least half of the events.
MAX_SHARE = 0.5

Interval = tuple[int, int]  # [t0, t1) µs


def heldout_intervals(t_start_us: int, t_end_us: int, cfg: HoldoutConfig, seed: int) -> list:
    """``cfg.windows`` intervals of ``cfg.length`` of [t_start_us, t_end_us], evenly spread:
    one at a seeded random place inside each of ``cfg.windows`` equal slots. Empty when off."""
    if cfg.windows <= 0:
        return []
    duration = t_end_us - t_start_us
    length = int(cfg.length * duration)
    slot = duration / cfg.windows
    if not (0 < length and cfg.windows * cfg.length <= MAX_SHARE):
        raise EvsplatError(
            f"holdout: {cfg.windows} windows of {cfg.length:g} of the sequence ({length} µs "
            f"each) hold out more than {MAX_SHARE:g} of it, or nothing; give fewer or shorter "
            "windows"
        )
    rng = np.random.default_rng([seed, HELDOUT_STREAM])
    starts = t_start_us + np.arange(cfg.windows) * slot + rng.uniform(0, slot - length, cfg.windows)
    return [(int(a), int(a) + length) for a in starts]


def overlaps(intervals: list[Interval], t0: int, t1: int) -> bool:
    """Whether [t0, t1) shares any instant with one of ``intervals``."""
    return any(t0 < b and a < t1 for a, b in intervals)


def free_spans(intervals: list[Interval], t_start_us: int, t_end_us: int) -> list[Interval]:
    """The parts of [t_start_us, t_end_us) outside ``intervals``, in time order."""
    spans, at = [], t_start_us
    for a, b in sorted(intervals):
        if a > at:
            spans.append((at, a))
        at = max(at, b)
    if t_end_us > at:
        spans.append((at, t_end_us))
    return spans
