"""Hot pixels: sensor pixels that fire far more often than anything near them, a fault of the
sensor (a leaky photodiode), not a change in the scene. No edge or texture does that: the optics
spread every edge over several pixels, and an edge crossing a pixel crosses its neighbours too.
Under a still camera a hot pixel is the one spot of the image that "changes" in every window,
and the motion segmentation took it for a small mover (docs/real-data.md, "Hot pixels"), so
training leaves their events out (``train.views.Views``)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from evsplat.data.event_store import EventStore

#: A hot pixel fires this many times as often as the pixels near it. Every pixel of the
#: built-in scenes' tiny variants (noise-free) and of the DAVIS346 sample stays under 4.4 times;
#: hot pixels added to them are 25 times or more at 5 kHz, 6-300 at 1 kHz (docs/real-data.md,
#: "Hot pixels", 2026-12-05).
HOT_RATIO = 10.0
#: How near (px) a pixel's comparison pixels are: a 5x5 box, which holds a Bayer mosaic's
#: same-colour neighbours (2 px away), as a colour edge fires only in its own channel's pixels.
NEAR = 2
#: The busiest pixels of that box left aside (the comparison is with the next): two hot
#: pixels side by side do not hide each other.
LEFT_ASIDE = 2


def hot_pixels(counts: np.ndarray) -> np.ndarray:
    """[H,W] bool: the pixels whose event ``counts`` [H,W] are over ``HOT_RATIO`` x (one more
    than) the busiest of the pixels within ``NEAR`` px after ``LEFT_ASIDE`` of them; the one
    more keeps a pixel of a few noise events among silent ones from counting."""
    box = np.ones((2 * NEAR + 1,) * 2, dtype=bool)
    box[NEAR, NEAR] = False  # the pixel itself
    c = counts.astype(np.float64)
    near = ndimage.rank_filter(c, rank=-(LEFT_ASIDE + 1), footprint=box, mode="constant")
    return c > HOT_RATIO * (near + 1.0)


def hot_pixel_map(store: EventStore, spans: list[tuple[int, int]]) -> np.ndarray:
    """[H,W] bool: ``hot_pixels`` of the events of ``store`` in the time ``spans`` (µs)."""
    counts = np.zeros((store.height, store.width), np.int64)
    for a, b in spans:
        counts += store.event_count(*store.window(a, b))
    return hot_pixels(counts)
