"""Observed-ness: where the events training read say anything at all.

Events only report change. Where none fired over the whole of training's data (a still
background under a still camera, a flat wall), the model's colour there is whatever its random
initialisation left: nothing constrained it. ``observed_map`` marks the pixels that saw at
least one event outside the run's held-out windows, grown by ``GROW`` pixels (an edge's events
fire on a row of pixels while the render spreads the edge over its neighbours too);
``evsplat render`` writes it as observed.png and shows the unobserved pixels at the
background grey, the least committal value, in its frames and videos."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from evsplat.data.event_store import EventStore
from evsplat.train.heldout import Interval, free_spans

GROW = 1  # px added around every pixel that saw an event (a 3x3 neighbourhood)


def observed_map(
    store: EventStore, t_start_us: int, t_end_us: int, heldout: list[Interval]
) -> np.ndarray:
    """[H,W] bool: the pixels with an event in [t_start_us, t_end_us) outside ``heldout``
    (streamed: ``EventStore.accumulate`` reads in bounded slices), grown by ``GROW`` px."""
    seen = np.zeros((store.height, store.width), bool)
    for a, b in free_spans(heldout, t_start_us, t_end_us):
        seen |= store.accumulate(*store.window(a, b), 1.0, 1.0)[1]
    if GROW > 0:
        side = 2 * GROW + 1
        grown = F.max_pool2d(torch.from_numpy(seen).float()[None, None], side, 1, GROW)
        seen = grown[0, 0].numpy() > 0
    return seen


def masked(image: np.ndarray, observed: np.ndarray, background: float) -> np.ndarray:
    """``image`` [H,W,C] with the unobserved pixels set to ``background``."""
    return np.where(observed[..., None], image, np.float32(background))
