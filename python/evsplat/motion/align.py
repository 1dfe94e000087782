"""An object's centres aligned across its windows to its template, the mean of its other views
(docs/motion.md, step 3): a region's weighted centre is where its events were, not the object."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage, signal

from evsplat.motion.border import touches_border
from evsplat.motion.tracks import Track
from evsplat.motion.turn import vertex

EPS = 1e-12  # guards normalisations of empty patches
# Each round moves the centres part of the way, the template being the blur of the views until
# they agree (a one-sided ring: 10 rounds left 0.8 px, 30 left 0.2; tests/test_motion_units.py).
ROUNDS = 50
SETTLED = 0.1  # px: no centre moved more in a round
MIN_WINDOWS = 3  # a template from fewer windows is one or two views, not the object


def _patch(image: np.ndarray, centre: np.ndarray, half: int) -> np.ndarray:
    """[2h+1, 2h+1] ``image`` about ``centre`` (x, y px), bilinear, zero beyond the image."""
    r = np.arange(-half, half + 1, dtype=np.float64)
    ys, xs = np.meshgrid(centre[1] - 0.5 + r, centre[0] - 0.5 + r, indexing="ij")
    return ndimage.map_coordinates(image, [ys, xs], order=1, mode="constant", cval=0.0)


def _peak(score: np.ndarray) -> np.ndarray:
    """[2] (dx, dy) of ``score``'s maximum about its middle, refined by a parabola per axis."""
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    lines = ((ix, score[iy, :]), (iy, score[:, ix]))
    return np.array([i + vertex(line, i) - (len(line) - 1) / 2 for i, line in lines])


def align(track: Track, energy: list[np.ndarray], search: float) -> Track:
    """``track`` with its own windows' centres moved to where their residual ``energy`` (per
    window, [H,W]) best matches the object's template, at most ``search`` x its radius away
    (shared windows keep theirs, ``Track.centres``). The template is the mean of the windows
    whose region is clear of the image border, where there are enough (a cut view is partial)."""
    own = [k for k in sorted(track.blobs) if k not in track.shared]
    if len(own) < MIN_WINDOWS:
        return track
    whole = [k for k in own if not touches_border(track.blobs[k].mask)]
    whole = whole if len(whole) >= MIN_WINDOWS else own
    half = int(np.ceil(2.0 * track.radius))  # an elongated one reaches beyond its disc radius
    reach = max(int(np.ceil(search * track.radius)), 1)
    start = {k: track.blobs[k].centre.astype(np.float64) for k in own}
    # A view cut by the border (its disc reaches out of the image) would drift to the template's
    # middle: it keeps border.uncut's centre from the whole shape.
    h, w = energy[own[0]].shape
    inside = {k: min(*c, w - c[0], h - c[1]) >= track.radius for k, c in start.items()}
    own = [k for k in own if k in whole or inside[k]]
    centres = dict(start)
    for _ in range(ROUNDS):
        # Each window's search area about its centre; the object's view is its middle.
        wide = {k: _patch(energy[k], centres[k], half + reach) for k in own}
        patches = {k: wide[k][reach:-reach, reach:-reach] for k in own}
        patches = {k: v / max(float(np.linalg.norm(v)), EPS) for k, v in patches.items()}
        total = sum(patches[k] for k in whole)
        moved = {}
        for k in own:
            template = total - patches[k] if k in whole else total  # the others' view
            template = template - template.mean()  # a uniform background scores nothing
            score = signal.correlate(wide[k], template, mode="valid")
            off = centres[k] + _peak(score) - start[k]
            moved[k] = start[k] + off * min(1.0, reach / max(float(np.linalg.norm(off)), EPS))
        shift = max(float(np.linalg.norm(moved[k] - centres[k])) for k in own)
        centres = moved
        if shift < SETTLED:
            break
    # Where the template sits is arbitrary: the centres keep their mean (the whole regions').
    drift = np.mean([centres[k] - start[k] for k in whole], axis=0)
    moved_blobs = {k: replace(track.blobs[k], centre=centres[k] - drift) for k in own}
    return replace(track, blobs=track.blobs | moved_blobs)
