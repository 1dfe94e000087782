"""An object's image track lifted to a world path, and its turn (docs/motion.md, step 5): held
beyond its sightings (a still object makes no events; one out of view is hidden, ``seed.span``)."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from evsplat.motion.tracks import filled, jump_limit, partial, step_lengths
from evsplat.motion.turn import one_way

# A piece going round an object held in place keeps its distance from the centre within this x
# the circle's radius (median absolute deviation; docs/motion.md, "Tuning numbers").
ROUND = 0.25


def turn_angles(
    times_us: np.ndarray, rates: np.ndarray, query_us: np.ndarray, t_ref_us: int
) -> np.ndarray:
    """In-plane turn angles [Q] (rad) from ``t_ref_us`` to ``query_us``, integrating the turn
    ``rates`` [F] (rad/s) measured at ``times_us`` [F]: linear between them, held beyond."""
    grid = np.union1d(np.asarray(query_us, dtype=np.float64), [float(t_ref_us)])
    rate = np.interp(grid, times_us.astype(np.float64), rates)
    steps = np.concatenate([[0.0], 0.5 * (rate[1:] + rate[:-1]) * np.diff(grid) * 1e-6])
    angle = np.cumsum(steps)
    angle -= angle[np.searchsorted(grid, float(t_ref_us))]
    return np.interp(np.asarray(query_us, dtype=np.float64), grid, angle)


def steadied(
    times_us: np.ndarray, path: np.ndarray, areas: np.ndarray, cut: np.ndarray, n: int
) -> np.ndarray:
    """The ``path`` [F,D] sighted at ``times_us`` [F] with its first and last run of slivers
    (``cut`` [F] by the border to under ``tracks.SLIVER`` of the median uncut area, ``areas`` [F]
    px) read from the line fitted, weighed by area, through the run and the ``n`` sightings after
    (before) it: a sliver's centre is the least sure. Only where those ``n`` are whole, the run is
    no longer than they (a line is not read farther out than it spans) and no window is missed
    (unseen, the object may have turned)."""
    out = path.astype(np.float64, copy=True)
    sliver = cut & partial(areas, cut)
    step = np.diff(times_us).min() if len(times_us) > 1 else 0
    for order in (np.arange(len(cut)), np.arange(len(cut))[::-1]):
        run = leading(sliver[order])
        used = order[: run + n]
        gaps = np.abs(np.diff(times_us[used])) > 1.5 * step
        if not 0 < run <= n or len(used) < run + n or sliver[used].sum() > run or gaps.any():
            continue
        t = times_us.astype(np.float64)[:, None]
        fit = np.polyfit(t[used, 0], path[used], 1, w=np.sqrt(areas[used]))  # [2,D]
        out[order[:run]] = np.polyval(fit, t[order[:run]])
    return out


def leading(flags: np.ndarray) -> int:
    """How many of ``flags`` [F] (bool) are set before the first that is not."""
    return int(np.argmin(flags)) if not flags.all() else len(flags)


def despiked(
    windows: np.ndarray, centres: np.ndarray, longest: int, piece: np.ndarray
) -> np.ndarray:
    """The ``centres`` [F,2] sighted at ``windows`` [F], each run of at most ``longest`` that jumps
    off and straight back (steps in and out over ``JUMP`` x the median, its neighbours within that
    of each other) put on the line between its neighbours: a stray region (a piece of the object,
    or another's) taken for a few windows. A first or last run of at most ``longest`` past a jump,
    each a ``piece`` [F] (bool: ``partial``, not cut by the border), is held at the nearest other:
    nothing beyond it comes back (docs/experiments/objects.md, "A sighting that jumps off and
    straight back")."""
    step = step_lengths(windows, centres)
    if step.size < 2:
        return centres.astype(np.float64, copy=True)
    limit = jump_limit(step)
    off = np.zeros(len(centres), dtype=bool)
    last, i = len(centres) - 1, 1

    def back(before: int, j: int) -> bool:  # the step in at j is a jump, to where ``before`` is
        gap = windows[j] - windows[before]
        return step[j - 1] > limit and np.linalg.norm(centres[j] - centres[before]) / gap <= limit

    while i < last:
        if step[i - 1] > limit:  # it jumps off at i: back at the first j after it that returns
            ahead = range(i + 1, min(i + longest, last) + 1)
            j = next((j for j in ahead if back(i - 1, j)), None)
            if j is not None:
                off[i:j], i = True, j
        i += 1
    for order in (np.arange(len(off)), np.arange(len(off))[::-1]):
        run = leading(piece[order])
        if 0 < run <= longest and run < len(off) and step[min(order[run], order[run - 1])] > limit:
            off[order[:run]] = True
    return filled(windows.astype(np.float64), ~off, centres.astype(np.float64))


def turns(angles: np.ndarray | float) -> np.ndarray:
    """[...,2,2] image-plane rotations (x right, y down) by ``angles`` [...] (rad)."""
    c, s = np.cos(angles), np.sin(angles)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def hops(
    windows: np.ndarray, centres: np.ndarray, radius: float, coast: int, cut: np.ndarray
) -> tuple[np.ndarray, float]:
    """(bool [F-1]: which steps between the ``centres`` [F,2] sighted at ``windows`` [F] hop
    between two ends; the jump limit, px per window). A hop is over ``JUMP`` x the median step,
    at most ``coast`` + 1 windows and at least ``radius`` px long (ends at ±d with |d| >= radius
    lie 2|d| apart: a fast step is no hop), neither sighting ``cut`` [F] by the border (a cut
    region's centre is the least sure; docs/experiments/objects.md, "Hops at the border are no
    ends")."""
    step, gap = step_lengths(windows, centres), np.diff(windows)
    limit = jump_limit(step)
    whole = ~cut[:-1] & ~cut[1:]
    return (step > limit) & (gap <= coast + 1) & (step * gap >= radius) & whole, limit


def two_ends(
    windows: np.ndarray,
    centres: np.ndarray,
    angles: np.ndarray,
    radius: float,
    coast: int,
    cut: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centres [F,2]; ends [F], +1 where the track started, -1 at the other; turn angles [F],
    rad) of an object turning in place, whose track hops (``hops``) to whichever end the camera's
    motion lights. The ends sit at ±d about the centre, turned with it, d fitted to the hops; each
    hop (-2 x the offset, turned) reads the turn, taking the ``angles``' drift out. Only where two
    hops or more, |d| >= ``radius`` and no hop left in the centres; else the track's own centres,
    ends all +1 and ``angles``."""
    none = (centres, np.ones(len(centres)), angles)
    hop = hops(windows, centres, radius, coast, cut)[0]
    if hop.sum() < 2:
        return none
    end = np.concatenate([[1.0], (-1.0) ** np.cumsum(hop)])
    d = _about_centre(centres, end, hop, angles)[1]
    jump = -(end[:-1, None] * np.diff(centres, axis=0))[hop]
    read = np.arctan2(jump[:, 1], jump[:, 0]) - np.arctan2(d[1], d[0])
    drift = np.unwrap(np.angle(np.exp(1j * (read - 0.5 * (angles[:-1] + angles[1:])[hop]))))
    angles = angles + np.interp(windows, 0.5 * (windows[:-1] + windows[1:])[hop], drift)
    middle, d = _about_centre(centres, end, hop, angles)
    moved = step_lengths(windows, middle)  # a hop left: a jump of the centre's own steps
    left = (moved[hop] > jump_limit(moved)).any()
    return none if left or np.linalg.norm(d) < radius else (middle, end, angles)


def circling(
    times_us: np.ndarray, centres: np.ndarray, radius: float, least: int
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(the centre [2]; turn angles [F], rad from the first sighting; the rate, rad/s) of an
    object held in place that shows one piece going round its centre (a turning card's tip, the
    other hidden), or None: its ``centres`` [F] (at least 2 x ``least``) at ``times_us`` on a
    circle (the algebraic fit) of at least ``radius`` (the piece lies off the centre), within
    ``ROUND`` of it, sweeping half a turn or more (which pins the centre), ``turn.one_way``."""
    if len(centres) < 2 * least:
        return None
    c = centres.astype(np.float64)
    fit = np.linalg.lstsq(np.c_[2 * c, np.ones(len(c))], (c**2).sum(1), rcond=None)[0]
    centre = fit[:2]
    reach = math.sqrt(max(float(fit[2] + centre @ centre), 0.0))
    off = np.linalg.norm(c - centre, axis=1)
    if reach < radius or np.median(np.abs(off - np.median(off))) > ROUND * reach:
        return None
    angles = np.unwrap(np.arctan2(c[:, 1] - centre[1], c[:, 0] - centre[0]))
    t = (times_us - times_us[0]) * 1e-6
    if np.ptp(angles) < np.pi or not one_way(angles, t):
        return None
    return centre, angles - angles[0], float(stats.theilslopes(angles, t)[0])


def _about_centre(
    centres: np.ndarray, end: np.ndarray, hop: np.ndarray, angles: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(the ``centres`` [F,2] less their ends' offsets, the offset d [2]) at ends ``end`` [F] (±1)
    turned by ``angles`` [F]: d by least squares on the ``hop`` steps [F-1]."""
    turned = end[:, None, None] * turns(angles)
    a = (turned[1:] - turned[:-1])[hop].reshape(-1, 2)
    d = np.linalg.lstsq(a, np.diff(centres, axis=0)[hop].reshape(-1), rcond=None)[0]
    return centres - turned @ d, d
