"""Find every moving object after the warm-up and start its motion: ``segment``, ``tracks``,
``align``, ``turn`` and ``paths`` (docs/motion.md, "The steps"); here, Gaussians placed on each
object's shape and an ``ObjectMotion``."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from scipy import stats

from evsplat.config import MoverConfig
from evsplat.model.densify import set_rows
from evsplat.model.gaussians import T_LOG_SCALE_RANGE, GaussianModel
from evsplat.model.motion import BEHIND, ObjectMotion, knot_times_us
from evsplat.motion import sphere
from evsplat.motion.align import align
from evsplat.motion.border import in_image, touches_border
from evsplat.motion.paths import (
    circling,
    despiked,
    hops,
    steadied,
    turn_angles,
    turns,
    two_ends,
)
from evsplat.motion.segment import (
    Blob,
    apart,
    blurred,
    floor,
    made_by_events,
    pooled,
    regions,
)
from evsplat.motion.still import behind_objects, is_still
from evsplat.motion.tracks import (
    Track,
    chain,
    jump_limit,
    on_its_line,
    partial,
    step_lengths,
    together,
)
from evsplat.motion.turn import WindowEvents, axis_rate, steady, turn_rate
from evsplat.projection import back_project, project
from evsplat.render import RenderOut
from evsplat.train.views import Views

#: Most events a turn window reads, thinned past it (one object's turn needs a few thousand).
TURN_WINDOW_EVENTS = 1_000_000
OPAQUE = 0.5  # rendered alpha above which the static model's depth is read


@dataclass
class Seeded:
    """Numbers for the log; the objects' motion and each Gaussian's object (None: none); the
    objects found here, by id, and the reference time (µs) each was placed at."""

    stats: dict[str, float]
    motion: ObjectMotion | None
    object_id: torch.Tensor | None
    references_us: dict[int, int] = field(default_factory=dict)


@dataclass
class Sightings:
    """Per window: its middle time, regions, residual, and the rendered depth where opaque;
    whether the camera stood still over them."""

    times_us: np.ndarray  # [W]
    blobs: list[list[Blob]]
    residual: list[np.ndarray]
    depth: list[np.ndarray]  # 0 where the render's alpha is not over ``OPAQUE``
    still: bool


@torch.no_grad()
def sight(views: Views, mc: MoverConfig) -> Sightings:
    """Segment ``mc.windows`` short windows spread over the sequence against what the renderer
    draws (after the warm-up, the static model; later, everything found so far); with
    ``mc.slow_window`` (under a still camera ``mc.still_window``), also a longer window about
    each middle, whose regions are added where they are ``apart`` from the short window's."""
    data = views.data
    least = floor(data.c_pos, data.c_neg, mc.pool)
    half = max(int(mc.window * (data.t_end_us - data.t_start_us)) // 2, 1)
    mids = np.linspace(data.t_start_us + half, data.t_end_us - half, mc.windows).astype(np.int64)
    windows = [(m, _clipped(views, m, half)) for m in mids.tolist()]
    windows = [(m, w) for m, w in windows if views.allowed(*w)]  # held out: unread
    times = np.array([m for m, _ in windows], dtype=np.int64)
    still = is_still(data.trajectory.pose(times.astype(np.float64)))
    length = mc.still_window if still else mc.slow_window
    slow = max(int(length * (data.t_end_us - data.t_start_us)) // 2, half)
    blobs, residuals, depth = [], [], []
    for mid, window in windows:
        residual, found, kept, end = _segment(views, mid, window, mc, least)
        # A slow or small object fires too few events in the short window.
        longer = _clipped(views, mid, slow)
        if slow > half and views.allowed(*longer):
            kept += apart(_segment(views, mid, longer, mc, least)[2], found)
        blobs.append(kept)
        residuals.append(residual)
        depth.append(np.where(end.alpha.cpu().numpy() > OPAQUE, end.depth.cpu().numpy(), 0.0))
    return Sightings(times, blobs, residuals, depth, still)


def _clipped(views: Views, mid: int, half: int) -> tuple[int, int]:
    """The window of ``half`` µs each side of ``mid``, clipped to the data."""
    return max(mid - half, views.data.t_start_us), min(mid + half, views.data.t_end_us)


def _segment(
    views: Views, mid: int, window: tuple[int, int], mc: MoverConfig, least: float
) -> tuple[np.ndarray, list[Blob], list[Blob], RenderOut]:
    """(residual, regions timed at ``mid``, those ``made_by_events``, the render at the end) of
    the ``window`` (µs, ``_clipped`` about ``mid``): the one its caller checked is readable."""
    t0, t1 = window
    start, end = (views.renderer.render(t, views.pose(t)) for t in (t0, t1))
    change, esi = views.log_image(end) - views.log_image(start), views.esi(t0, t1)[0]
    residual = pooled(esi - change, mc.pool)
    found = regions(residual, mid, mc, least)
    return residual, found, made_by_events(found, esi, change, mc.pool, mc.events), end


def object_depth(track: Track, sightings: Sightings, quantile: float) -> float | None:
    """The median over the track's regions of a near ``quantile`` of their depth, or None."""
    found = []
    for k, blob in track.blobs.items():
        seen = blob.mask & (sightings.depth[k] > 0)
        if seen.any():
            found.append(float(np.quantile(sightings.depth[k][seen], quantile)))
    return float(np.median(found)) if found else None


def span(track: Track, times: np.ndarray, coast: int) -> list[float]:
    """The normalised times the object is in view between, of the windows' ``times`` [W]: from
    half a window spacing before its first sighting where it came in through the border,
    likewise at its end; ±inf otherwise (it was there all along, still). Not where the sequence
    ends within ``coast`` windows of it: an object may go unseen that long (``tracks.chain``)."""
    ks, last, inf = sorted(track.blobs), len(times) - 1, float("inf")
    step = 0.5 / max(last, 1)
    enters = ks[0] > coast and touches_border(track.blobs[ks[0]].mask)
    leaves = ks[-1] < last - coast and touches_border(track.blobs[ks[-1]].mask)
    return [times[ks[0]] - step if enters else -inf, times[ks[-1]] + step if leaves else inf]


def slid(
    path: np.ndarray,
    times_us: np.ndarray,
    at_us: np.ndarray,
    reach: list[float],
    n: int,
    pose: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """The object's ``path`` [F,3] at its sightings' ``times_us`` [F], read at ``at_us`` [G]:
    linear between its sightings; before the first (after the last) carried on for up to
    ``reach`` [2] µs at the velocity fitted to its first (last) ``n`` sightings, then held where
    the camera (``pose``: µs -> [..,4,4] camera-to-world) sees it, in the camera's frame: an
    object unseen inside the image moved little in it."""
    out = np.stack([np.interp(at_us, times_us, path[:, j]) for j in range(3)], 1)
    for most, i, used, beyond in (
        (reach[0], 0, slice(None, n), at_us < times_us[0]),
        (reach[1], -1, slice(-n, None), at_us > times_us[-1]),
    ):
        t = times_us[used].astype(np.float64)
        velocity = np.zeros(3)
        if most > 0 and len(t) >= 2:
            velocity = np.polyfit(t - t.mean(), path[used], 1)[0]  # [3] per µs
        dt = np.clip(at_us[beyond, None] - times_us[i], -most, most)
        out[beyond] = path[i] + dt * velocity
        past = beyond & (np.abs(at_us - times_us[i]) > most)
        if past.any():  # held where the camera saw it at the carry's end
            step = most if i else -most
            held = np.append(path[i] + step * velocity, 1.0)
            local = np.linalg.inv(pose(float(times_us[i]) + step)) @ held
            out[past] = (pose(at_us[past].astype(np.float64)) @ local)[:, :3]
    return out


def disc(
    points: np.ndarray, radii: np.ndarray, c2w: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(pixel centres [N,2], radii [N] px) of balls at ``points`` [N,3] of ``radii`` [N] seen
    from ``c2w``; NaN and 0 for one behind the camera (a path carried on past its sightings can
    get there)."""
    uv, z = project(points, c2w, K)
    ahead = z > 0
    px = radii * float(K[0, 0]) / np.where(ahead, z, 1.0)
    return np.where(ahead[:, None], uv, np.nan), np.where(ahead, px, 0.0)


def in_view(
    held: np.ndarray, knots: np.ndarray, ends: list[float], radius: float, views: Views
) -> list[float]:
    """The span ``ends`` (normalised times, ``span``'s) widened to where the object's disc of
    ``radius`` on its path ``held`` [G,3] at ``knots`` [G] (µs) overlaps the image: to the
    nearest knot it is out of view at, so that it has faded in by the next. Not where its path
    keeps it in view all along: an object in view that long would have fired events
    (docs/experiments/objects.md, "An object partly in view before its first sighting")."""
    data = views.data
    size, seen = np.array([data.width, data.height]), []
    for point, t_us in zip(held, knots.tolist()):
        uv, r = disc(point[None], np.array([radius]), data.trajectory.pose(t_us), data.K)
        seen.append(bool(((uv[0] > -r[0]) & (uv[0] < size + r[0])).all()))  # NaN behind: False
    times = [views.renderer.time(t) for t in knots.tolist()]
    before = [g for g, t in enumerate(times) if t < ends[0] and not seen[g]]
    after = [g for g, t in enumerate(times) if t > ends[1] and not seen[g]]
    return [times[before[-1]] if before else ends[0], times[after[0]] if after else ends[1]]


def reference(track: Track) -> int:
    """The window to place the object at: its clearest sighting of those ``Track.clear`` (its
    own region, not shared with another object, and clear of the border if any)."""
    return max(track.clear, key=lambda k: track.blobs[k].contrast)


def shape(
    track: Track, i: int, middle: np.ndarray, end: np.ndarray, seen: np.ndarray
) -> np.ndarray:
    """[H,W] bool: the object's pixels at its ``i``-th sighting, its region there; with two ends
    (``paths.two_ends``: centres ``middle``, ``end``), also the other end's clearest region clear
    of the border, carried there by its turn ``seen`` (rad) about its centre; with one end seen
    going round (``end`` 0), also the region through the centre, as a card's other end."""
    blobs = [track.blobs[k] for k in sorted(track.blobs)]
    mask = blobs[i].mask.copy()
    if (end == 0).all():
        ys, xs = np.nonzero(mask)
        uv = 2.0 * middle[i] - (np.stack([xs, ys], 1) + 0.5)
    else:
        other = [j for j, b in enumerate(blobs) if end[j] != end[i] and not touches_border(b.mask)]
        if not other:
            return mask
        j = max(other, key=lambda j: blobs[j].contrast)
        ys, xs = np.nonzero(blobs[j].mask)
        uv = (np.stack([xs, ys], 1) + 0.5 - middle[j]) @ turns(seen[i] - seen[j]).T + middle[i]
    px = np.floor(uv).astype(np.int64)
    px = px[in_image(px, mask.shape)]
    mask[px[:, 1], px[:, 0]] = True
    return mask


def smear(
    points: np.ndarray, track: Track, poses: np.ndarray, K: np.ndarray, back: float
) -> np.ndarray:
    """Bool [N]: the ``points`` [N,3] that a region of ``track`` holds from its window's pose
    (``poses`` [F,4,4]) nearer than ``back``: the warm-up's smear of it, spread along the rays."""
    out = np.zeros(len(points), dtype=bool)
    for blob, pose in zip((track.blobs[k] for k in sorted(track.blobs)), poses):
        uv, z = project(points, pose, K)
        px = np.floor(uv).astype(np.int64)
        seen = in_image(px, blob.mask.shape) & (z > 0) & (z <= back)
        out[seen] |= blob.mask[px[seen, 1], px[seen, 0]]
    return out


def carried(
    views: Views, t_us: int, half_us: int, velocity: np.ndarray, spread: bool = False
) -> tuple[np.ndarray, ...] | None:
    """(pixel centres [E,2], seconds from ``t_us`` [E], polarity [E], the centres carried back
    to ``t_us`` by the image ``velocity`` [2] px/s) of the events within ``half_us`` of it,
    the hot pixels' left out; None beyond the data or where held out. ``spread``: each event
    anywhere in its pixel, not at its centre (where nothing carries them off whole pixels, their
    votes there make no turn the sharpest)."""
    data = views.data
    t0, t1 = max(t_us - half_us, data.t_start_us), min(t_us + half_us, data.t_end_us)
    if t1 <= t0 or not views.allowed(t0, t1):
        return None
    ev = data.events.read(t0, t1, TURN_WINDOW_EVENTS)
    keep = slice(None) if views.hot is None else ~views.hot.cpu().numpy()[ev.y, ev.x]
    dt = (ev.t[keep] - t_us) * 1e-6
    xy = np.stack([ev.x[keep], ev.y[keep]], 1).astype(np.float64)
    xy += np.random.default_rng(t_us).random(xy.shape) if spread else 0.5
    return xy, dt, ev.p[keep], xy - velocity[None] * dt[:, None]


def turn_rates(views: Views, track: Track, mc: MoverConfig) -> np.ndarray:
    """The object's turn rate (rad/s) at each sighting: ``turn.turn_rate`` on the events of a
    window that its region holds (``reading``), carried back by its image velocity; 0
    where the turn sharpens them by less than ``mc.turn_min_gain`` (a turn not seen is no turn,
    not an unknown one), NaN where fewer than ``mc.turn_min_events`` are in it; 0 in every
    window where the turns shown are not ``turn.steady``."""
    times, centres = track.times_us, track.centres
    half_us, top, velocity, held = reading(views, track, centres, mc)
    out = np.full(len(times), np.nan)
    for i, k in enumerate(sorted(track.blobs)):
        mask = track.blobs[k].mask
        got = carried(views, int(times[i]), half_us, velocity[i], held)
        if got is None:
            continue
        xy, dt, p, back = got
        back = np.floor(back).astype(np.int64)
        inside = in_image(back, mask.shape)
        inside[inside] = mask[back[inside, 1], back[inside, 0]]
        if inside.sum() < mc.turn_min_events:
            continue
        window = WindowEvents(xy[inside], dt[inside], p[inside])
        rate, gain = turn_rate(window, track.blobs[k].centre, velocity[i], top, mask.shape)
        out[i] = rate if gain >= mc.turn_min_gain else 0.0
    shown = turned(out)
    return out if steady(out[shown], mc.turn_min_windows) else np.where(shown, 0.0, out)


def turned(rates: np.ndarray) -> np.ndarray:
    """[F] bool: the sightings whose events show a turn (``turn_rates`` neither NaN nor 0)."""
    return np.isfinite(rates) & (rates != 0)


def turn_window(views: Views, length: float) -> tuple[int, float]:
    """(half the turn's window of ``length`` (of the sequence), µs; the fastest turn sought,
    rad/s: at one radian per window an edge's events smear over the whole object)."""
    data = views.data
    half_us = max(int(length * (data.t_end_us - data.t_start_us)) // 2, 1)
    return half_us, 1.0 / (2 * half_us * 1e-6)


def reading(
    views: Views, track: Track, centres: np.ndarray, mc: MoverConfig
) -> tuple[int, float, np.ndarray, bool]:
    """How a track's turn is read: (half its windows, µs; the fastest turn sought, rad/s; the
    image velocity [F,2] px/s of its ``centres`` [F,2]; whether it is held in place). An object
    whose centres' Theil-Sen line moves under a pixel over a ``mc.held_window`` is held: its
    turn, maybe too slow to show in a short window, is read in that longer one (as fast turns as
    in a short one), unmoved, its events ``carried`` ``spread``."""
    times = track.times_us * 1e-6
    half_us, top = turn_window(views, mc.turn_window)
    held_us = turn_window(views, mc.held_window)[0]
    if mc.held_window > 0 and len(times) >= 2:
        speed = np.hypot(*(stats.theilslopes(centres[:, j], times)[0] for j in range(2)))
        if speed * 2 * held_us * 1e-6 < 1.0:
            return held_us, top, np.zeros_like(centres), True
    velocity = np.gradient(centres, times, axis=0) if len(times) > 1 else 0.0 * centres
    return half_us, top, velocity, False


@dataclass
class Ball:
    """A round object: its outline's centres [F,2] and radius (px), and its turn's rotation
    vectors [G,3] at the knots."""

    centres: np.ndarray
    radius_px: float
    rotvecs: np.ndarray


def sphere_turn(
    views: Views, track: Track, middle: np.ndarray, knots: np.ndarray, t_ref: int,
    mc: MoverConfig,
) -> Ball | None:  # fmt: skip
    """A round object's outline and its turn about three axes (``sphere``) at ``knots`` from
    ``t_ref``, from its sightings clear of the border, its centres ``middle`` [F,2]; its
    outline's centre also where the border cuts it (``sphere.on_outline``). None where its
    outline is no steady ring (not round) or too few sightings show it."""
    if not (mc.turn and mc.sphere):
        return None
    data, (half_us, top, velocity, held) = views.data, reading(views, track, middle, mc)
    times, radius = track.times_us, track.radius
    fits = []
    for i, k in enumerate(sorted(track.blobs)):
        got = None if touches_border(track.blobs[k].mask) else carried(  # a cut outline: no ring
            views, int(times[i]), half_us, velocity[i], held)  # fmt: skip
        if got is None:
            continue
        _, dt, p, back = got
        off = back - middle[i]
        near = np.linalg.norm(off, axis=1) < sphere.REACH * radius
        near &= in_image(np.floor(back).astype(np.int64), (data.height, data.width))
        fit = sphere.ring(off[near], radius) if near.sum() >= mc.turn_min_events else None
        if fit is not None:
            fits.append((i, off[near] - fit[0], dt[near], p[near], *fit))
    rings = [[f[k] for f in fits] for k in (4, 6)]  # centres, contrasts
    if len(fits) < mc.turn_min_windows or not sphere.is_round(*rings):
        return None
    found, omegas = [], []
    for i, off, dt, p, centre, rho, _ in fits:
        front = np.linalg.norm(off, axis=1) < sphere.FRONT * rho
        if front.sum() < mc.turn_min_events:
            continue
        args = (off[front], dt[front], p[front], middle[i] + centre, rho, top)
        omega = sphere.sphere_rate(*args, (data.height, data.width))
        found.append(float(times[i]))
        omegas.append(data.trajectory.pose(float(times[i]))[:3, :3] @ omega)  # to the world
    if len(found) < mc.turn_min_windows:
        return None
    rho = float(np.median([f[5] for f in fits]))
    centres = middle + np.median(rings[0], axis=0)  # its regions' usual offset, unless ...
    placed = np.zeros(len(times), dtype=bool)
    for f in fits:  # ... its ring places it
        centres[f[0]], placed[f[0]] = middle[f[0]] + f[4], True
    ringed, unplaced = placed.copy(), centres.copy()
    for i in np.flatnonzero(~placed):  # ... or its outline's arc
        got = carried(views, int(times[i]), half_us, velocity[i], held)
        if got is None:
            continue
        off = got[3] - centres[i]
        off = off[np.linalg.norm(off, axis=1) < sphere.REACH * rho]
        if len(off) < mc.turn_min_events:
            continue
        size = np.array([data.width, data.height]) - centres[i]
        at = sphere.on_outline(off, rho, -centres[i], size, 0.5 * rho)
        if at is not None:
            centres[i], placed[i] = centres[i] + at, True
    windows = np.array(sorted(track.blobs))
    off = off_their_line(centres, placed, placed & ~ringed, times, windows, mc.coast + 1)
    centres[off], placed[off] = unplaced[off], False
    centres = between_placed(centres, placed, times, windows, mc.coast + 1, track.cut)
    rotvecs = sphere.rotvecs(np.array(found), np.array(omegas), knots, t_ref)
    return Ball(centres, rho, rotvecs)


def on_line(points: np.ndarray, t: np.ndarray, p: int, q: int, at: float) -> np.ndarray:
    """[D]: the point at time ``at`` on the line through ``points`` [F,D] ``p`` and ``q`` at
    their times ``t`` [F] (distinct)."""
    return points[p] + (points[q] - points[p]) * (at - t[p]) / (t[q] - t[p])


def predicted(
    centres: np.ndarray, placed: np.ndarray, t: np.ndarray, windows: np.ndarray, i: int,
    gap: int, one_sided: bool,
) -> np.ndarray | None:  # fmt: skip
    """[2]: sighting ``i``'s centre read from the other ``placed`` [F] ``centres`` [F,2] at
    times ``t`` [F] and ``windows`` [F]: on the line between the nearest before and after it
    where those are at most ``gap`` windows apart; else, ``one_sided``, on the line through the
    nearest two on its nearer side, both within ``gap`` windows of it; else None."""
    at = np.flatnonzero(placed)
    a, b = at[at < i], at[at > i]
    if len(a) and len(b) and windows[b[0]] - windows[a[-1]] <= gap:
        return on_line(centres, t, a[-1], b[0], t[i])
    near = [two for two in (a[-2:], b[:2]) if len(two) == 2]
    near = [two for two in near if np.abs(windows[two] - windows[i]).max() <= gap]
    if not (one_sided and near):
        return None
    p, q = min(near, key=lambda two: np.abs(windows[two] - windows[i]).min())
    return on_line(centres, t, p, q, t[i])


def off_their_line(
    centres: np.ndarray, placed: np.ndarray, outlined: np.ndarray, times: np.ndarray,
    windows: np.ndarray, gap: int,
) -> np.ndarray:  # fmt: skip
    """[F] bool: of the ``centres`` [F,2] at ``times`` [F] (µs) and ``windows`` [F], those
    ``outlined`` [F] (placed by a cut outline's arc) further off the Theil-Sen line through the
    other ``placed`` [F] ones within ``gap`` windows (three or more) than the object steps in a
    window (``jump_limit``), the furthest dropped first: there the background's events outweighed
    a sliver's arc (docs/experiments/objects.md, "A ball's slivers read from its placed
    sightings")."""
    placed, out = placed.copy(), np.zeros(len(centres), dtype=bool)
    at = np.flatnonzero(placed)
    if len(at) < 3:
        return out
    limit, t = jump_limit(step_lengths(windows[at], centres[at])), times.astype(np.float64)
    while True:
        off = {}
        for i in np.flatnonzero(outlined & placed):
            near = np.flatnonzero(placed & (np.abs(windows - windows[i]) <= gap))
            near = near[near != i]
            if len(near) >= 3:  # Theil-Sen: two arcs off side by side do not hold each other up
                a, b = np.triu_indices(len(near), 1)
                rate = (centres[near[b]] - centres[near[a]]) / (t[near[b]] - t[near[a]])[:, None]
                slope = np.median(rate, axis=0)
                line = np.median(centres[near] - slope * t[near, None], axis=0) + slope * t[i]
                off[i] = float(np.linalg.norm(centres[i] - line))
        worst = max(off, key=off.__getitem__, default=None)
        if worst is None or off[worst] <= limit:
            return out
        out[worst], placed[worst] = True, False


def between_placed(
    centres: np.ndarray, placed: np.ndarray, times: np.ndarray, windows: np.ndarray, gap: int,
    cut: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """The ``centres`` [F,2] at ``times`` [F] (µs) and ``windows`` [F], each not ``placed`` [F]
    by an outline where the placed ones put it (``predicted``): between two, or, ``cut`` [F] by
    the border (going out or coming in), past two: a sliver's region is the least sure centre
    (docs/experiments/objects.md, "A ball's slivers read from its placed sightings")."""
    out, t = centres.copy(), times.astype(np.float64)
    for i in np.flatnonzero(~placed):
        line = predicted(centres, placed, t, windows, i, gap, bool(cut[i]))
        if line is not None:
            out[i] = line
    return out


Turning = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # ``turning``'s


def turning(views: Views, track: Track, mc: MoverConfig) -> Turning:
    """(``turn_rates`` [F]; ``paths.two_ends``' centres [F,2], ends [F] and turn angles [F], rad
    from the first sighting, 0 with no turn shown; with two ends, from a steady turn; with one,
    where ``mc.turn_axes`` and its regions' long axes show a steady turn, ``turn.axis_rate``
    at every sighting)."""
    ks, times = np.array(sorted(track.blobs)), track.times_us
    rates = turn_rates(views, track, mc) if mc.turn else np.full(len(ks), np.nan)
    used, shown, seen = np.isfinite(rates), turned(rates), np.zeros(len(ks))
    if shown.any():  # ``turn_rates`` shows only a steady turn, in enough windows
        seen = turn_angles(times[used], rates[used], times, min(times))
    centres, radius, cut = track.centres, track.radius, track.cut  # each derived: read once
    found = two_ends(ks, centres, seen, radius, mc.coast, cut)
    if (found[1] < 0).any() and shown.any():
        # Its ends' rates stray: a steady turn at their median instead, read again at the hops.
        at_median = np.median(rates[shown]) * (times - times[0]) * 1e-6
        again = two_ends(ks, centres, at_median, radius, mc.coast, cut)
        found = again if (again[1] < 0).any() else found
    if not (found[1] < 0).any():  # one end: no hop is its motion
        piece = partial(track.areas, cut) & ~cut
        found = (despiked(ks, found[0], mc.coast, piece), *found[1:])  # as long as it may go unseen
        if mc.turn and mc.turn_axes:  # an elongated one's regions show its turn by their shape
            clear = track.clear
            masks = [track.blobs[k].mask for k in clear]
            at = np.searchsorted(ks, clear)
            rate = axis_rate(
                times[at], masks, mc.turn_min_windows, turn_window(views, mc.turn_window)[1]
            )
            if rate is not None:
                rates = np.full(len(ks), rate)
                found = (*found[:2], rate * (times - min(times)) * 1e-6)
    return rates, *found


def going_round(track: Track, turn: Turning, mc: MoverConfig) -> Turning:
    """``turn``, or for an object with one end whose track is ``paths.circling`` (under a still
    camera, where the regions are the objects' own): the circle's rate, its centre, ends 0 (one
    end seen going round) and the angles about it."""
    ring = None
    if mc.turn and not (turn[2] < 0).any():
        ring = circling(track.times_us, track.centres, track.radius, mc.min_windows)
    if ring is None:
        return turn
    n = len(track.blobs)
    return np.full(n, ring[2]), np.tile(ring[0], (n, 1)), np.zeros(n), ring[1]


def ends_turning(views: Views, track: Track, mc: MoverConfig) -> tuple[Track, Turning]:
    """The ``track`` and its ``turning``; where that shows no two ends, the track less its tail
    of at most ``mc.coast`` sightings after its last hop, and its turning, if that shows them:
    an end that stops firing leaves its track coasting onto one more "hop" that no two ends
    explain (docs/experiments/objects.md, "A spinning card's two arms joined again"). Else,
    with one end, the track ``on_its_line`` and its turning."""
    turn = turning(views, track, mc)
    if (turn[2] < 0).any():
        return track, turn
    ks = np.array(sorted(track.blobs))
    at = np.flatnonzero(hops(ks, track.centres, track.radius, mc.coast, track.cut)[0])
    if len(at) and len(ks) - 1 - at[-1] <= mc.coast:
        cut = track.part(ks[0], ks[at[-1]])
        again = turning(views, cut, mc)
        if (again[2] < 0).any():
            return cut, again
    kept = on_its_line(track, mc)
    return (track, turn) if kept is track else (kept, turning(views, kept, mc))


def joined_ends(tracks: list[Track], views: Views, mc: MoverConfig) -> list[tuple[Track, Turning]]:
    """The objects and their ``turning``, where the chaining broke one at a hop between its ends
    made one: a track starting at most ``mc.coast`` + 1 windows past another's end (its last
    sighting before a gap longer than a track coasts; the rest a track of its own) and ending
    after it joins it where the two show two ends (``two_ends``). A track ``tracks.together``
    with a two-ended object's centre is its other end firing at once, unless it explains more of
    the events (``Track.area``): then the "ends" were pieces of its edge."""
    gone: set[int] = set()  # ids of the tracks that are part of another
    turns: dict[int, Turning] = {}  # a joined track's, from its join's test
    for track in sorted(tracks, key=lambda t: min(t.blobs)):
        first, last = min(track.blobs), max(track.blobs)
        for home in tracks:
            ks = sorted(home.blobs)
            # Up to a long gap: resumed past it (``tracks._resumes``), it may hold the other end.
            gaps = [a for a, b in zip(ks, ks[1:]) if b > first and b - a > mc.coast + 1]
            start, end = ks[0], gaps[0] if gaps else ks[-1]
            if id(home) in gone or not (start < first <= end + mc.coast + 1 and end < last):
                continue
            own, later = home.part(start, end), track.part(end + 1, last)
            both = Track(own.blobs | later.blobs, own.shared | later.shared)
            both, turn = ends_turning(views, both, mc)
            if (turn[2] < 0).any():
                rest = home.part(end + 1, ks[-1])
                if rest.blobs:  # a track of its own, to be tested as the other end below
                    tracks = [*tracks, rest]
                home.blobs, home.shared = both.blobs, both.shared
                turns[id(home)] = turn
                gone.add(id(track))
                break
    found = []
    for home in tracks:
        if id(home) in gone:
            continue
        if id(home) not in turns:
            cut, turns[id(home)] = ends_turning(views, home, mc)
            home.blobs, home.shared = cut.blobs, cut.shared
        found.append((home, turns[id(home)]))
        middle, end = found[-1][1][1:3]
        if (end < 0).any():  # its other end, firing at once, may be a track of its own
            ks = sorted(home.blobs)
            centred = Track({k: replace(home.blobs[k], centre=c) for k, c in zip(ks, middle)})
            near = [t for t in tracks if t is not home and together(centred, t, mc)]
            if any(t.area > home.area for t in near):
                gone.add(id(home))  # a round object's rim, read as two ends about its centre
            else:
                gone |= {id(t) for t in near}
    return [(t, turn) for t, turn in found if id(t) not in gone]


def ends_offset(track: Track, middle: np.ndarray) -> float:
    """How far (px, median) the track's regions lie from its object's centres ``middle`` [F,2]:
    0 for one end, the ends' offset for two (``paths.two_ends``), whose object reaches past its
    ends' regions."""
    return float(np.median(np.linalg.norm(track.centres - middle, axis=1)))


def on_sphere(rng: np.random.Generator, n: int) -> np.ndarray:
    """[n,3] points spread evenly over the unit sphere."""
    v = rng.normal(size=(n, 3))
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)


def place(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    rows: np.ndarray,
    points: np.ndarray,
    spacing: float,
    opacity: float,
) -> None:
    """Re-place the Gaussians ``rows`` [M] at ``points`` [M,3]: isotropic at ``spacing``,
    identity rotation, grey, ``opacity``, shown at all times; their optimizer state afresh."""
    o = min(max(opacity, 1e-4), 1.0 - 1e-4)
    device = model.means.device
    scales = np.log(np.maximum(np.full(len(rows), spacing), 1e-12)).astype(np.float32)
    values = {
        "means": torch.from_numpy(points.astype(np.float32)).to(device),
        "log_scales": torch.from_numpy(scales).to(device).unsqueeze(1),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0], device=device),
        "opacity_logits": math.log(o / (1.0 - o)),
        "sh": 0.0,
        "t_mean": 0.5,
        "t_log_scale": T_LOG_SCALE_RANGE[1],
    }
    set_rows(model, optimizer, torch.from_numpy(rows).to(device), values)


def projected(motion: ObjectMotion, views: Views, t_us: float) -> tuple[np.ndarray, np.ndarray]:
    """``disc`` of the objects of ``motion`` at ``t_us``."""
    data = views.data
    at = (motion.centres + motion.at(views.renderer.time(t_us))[1]).detach().cpu().numpy()
    return disc(at, motion.radii.cpu().numpy(), data.trajectory.pose(t_us), data.K)


def known_object(track: Track, motion: ObjectMotion, views: Views) -> bool:
    """Whether ``track`` follows an object already found (what its model leaves unexplained):
    in most of its windows it lies within the two radii of one object's centre on its path."""
    near = np.zeros(motion.centres.shape[0])
    for centre, t_us in zip(track.centres, track.times_us.astype(float).tolist()):
        uv, radii = projected(motion, views, t_us)
        near += np.linalg.norm(uv - centre[None], axis=1) <= track.radius + radii
    return bool(near.size) and float(near.max()) >= 0.5 * len(track.blobs)


def seed_objects(
    views: Views,
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    mc: MoverConfig,
    seed: int,
    depth_range: tuple[float, float],
    known: tuple[ObjectMotion, torch.Tensor] | None = None,
) -> Seeded:
    """Find the moving objects and start each one's motion: the Gaussians that smear it along
    its path (the warm-up's static smear), then the faintest, re-placed on its shape at its
    reference window; its path and turn on an ``ObjectMotion``. ``known``: the objects found
    before and each Gaussian's; only new objects are seeded then, and the motion holds all."""
    data = views.data
    sightings = sight(views, mc)
    still = sightings.still
    tracks = chain(sightings.blobs, mc, still)
    energy = [blurred(r, mc.blur_px) for r in sightings.residual]
    tracks = [align(t, energy, mc.align) for t in tracks]
    if known is not None:
        tracks = [t for t in tracks if not known_object(t, known[0], views)]
    found = joined_ends(tracks, views, mc)
    found = [(t, going_round(t, turn, mc) if still else turn) for t, turn in found]
    tracks = [t for t, _ in found]
    moving = float(np.mean([len(b) > 0 for b in sightings.blobs]))
    stats = {"objects": float(len(tracks)), "windows_with_motion": moving}
    if not tracks:
        return Seeded(stats, *(known or (None, None)))
    rng = np.random.default_rng(seed)
    n, focal = model.num_gaussians, float(data.K[0, 0])
    means = model.means.detach().cpu().numpy().astype(np.float64)
    object_id = np.full(n, -1, dtype=np.int64) if known is None else known[1].cpu().numpy().copy()
    first = 0 if known is None else known[0].centres.shape[0]  # the new objects' first id
    free = object_id < 0
    faintest = np.argsort(model.opacities().detach().cpu().numpy(), kind="stable")
    areas = np.array([np.median(t.areas) for t in tracks])
    # Shares by area among all objects, known ones too: else a new one takes all ``mc.fraction``.
    mid_us = (data.t_start_us + data.t_end_us) // 2
    known_areas = np.pi * projected(known[0], views, mid_us)[1] ** 2 if known else np.zeros(0)
    total = areas.sum() + known_areas.sum()
    knots = knot_times_us(data.t_start_us, data.t_end_us, mc.knots)
    windows = np.array([views.renderer.time(t) for t in sightings.times_us])  # the spans' clock
    # How long an object inside the image may have moved unseen: ``coast`` windows (``chain``).
    spacing = np.diff(sightings.times_us)
    unseen_us = (mc.coast + 1) * float(spacing.mean()) if spacing.size else 0.0
    centres, radii, shifts, rotvecs, spans, backs = ([] for _ in range(6))
    references_us = {}
    for k, (track, (rates, middle, end, seen)) in enumerate(found):
        depth = object_depth(track, sightings, mc.depth_quantile) or float(np.mean(depth_range))
        ks, ref = sorted(track.blobs), reference(track)
        t_ref, r = int(track.blobs[ref].t_us), ks.index(ref)
        radius = track.radius * depth / focal
        used, shown, seen = np.isfinite(rates), turned(rates), seen - seen[r]
        rate = float(np.median(rates[shown])) if shown.any() else 0.0
        angles = np.zeros(len(knots))  # at the knots
        if (end < 0).any():  # the turn its two ends show, beyond its sightings at its median rate
            angles = np.interp(knots, track.times_us, seen)
            t = track.times_us.astype(np.float64)  # carried on as a measured turn is
            beyond = np.minimum(knots - t[0], 0.0) + np.maximum(knots - t[-1], 0.0)
            angles += rate * beyond * 1e-6
        elif shown.any():
            angles = turn_angles(track.times_us[used], rates[used], knots, t_ref)
        ball = sphere_turn(views, track, middle, knots, t_ref, mc)
        if ball is not None:  # its front at depth, its outline ``radius_px`` seen from there
            sine = math.sin(math.atan(ball.radius_px / focal))
            radius = sine * depth / (1.0 - sine)
        # Two ends reach past their regions: the smear, track prior and disc are the object's.
        extent = radius + ends_offset(track, middle) * depth / focal
        poses = data.trajectory.pose(track.times_us.astype(np.float64))
        # A ball's path is its centre's; any other object's, its front's.
        on, deep = (middle, depth) if ball is None else (ball.centres, depth + radius)
        path = back_project(on, np.full(len(ks), deep), poses, data.K)
        path = steadied(track.times_us, path, track.areas, track.cut, mc.min_windows)
        back = depth + BEHIND * extent  # its front surface at depth, its back behind
        swept = np.flatnonzero(smear(means, track, poses, data.K, back) & free)
        share = max(int(mc.fraction * n * areas[k] / total), mc.min_gaussians)
        rest = faintest[free[faintest]]
        rest = rest[~np.isin(rest, swept)][: max(share - len(swept), 0)]
        pick = np.concatenate([swept, rest])
        free[pick] = False
        object_id[pick] = first + k
        pose_ref = data.trajectory.pose(float(t_ref))
        if ball is None:  # its reference region's pixels, from its front surface one radius deep
            mask = shape(track, r, middle, end, seen)
            ys, xs = np.nonzero(mask)
            j = rng.integers(len(xs), size=len(pick))
            uv = np.stack([xs[j], ys[j]], 1) + rng.random((len(pick), 2))
            placed = back_project(uv, depth + radius * rng.random(len(pick)), pose_ref, data.K)
            spacing = (mask.sum() * (depth / focal) ** 2 * radius / max(len(pick), 1)) ** (1 / 3)
        else:  # on the sphere its outline shows: a ball turns its far side into view
            placed = path[r] + radius * on_sphere(rng, len(pick))
            spacing = math.sqrt(4 * math.pi / max(len(pick), 1)) * radius
        place(model, optimizer, pick, placed, spacing, mc.opacity)
        backs.append(back)
        centres.append(placed.mean(0) if ball is None else path[r])  # what it turns about
        radii.append(extent)
        edges = span(track, windows, mc.coast)
        reach = [np.inf if np.isfinite(e) else unseen_us for e in edges]
        held = slid(path, track.times_us, knots, reach, mc.min_windows, data.trajectory.pose)
        shifts.append(held - path[r])
        spans.append(in_view(held, knots, edges, extent, views))
        in_plane = angles[:, None] * pose_ref[:3, 2][None]  # about the viewing axis
        rotvecs.append(in_plane if ball is None else ball.rotvecs)
        numbers = {"windows": len(ks), "ends": 1 + (end < 0).any(), "depth": depth}
        numbers |= {"radius_px": track.radius, "gaussians": len(pick)}
        numbers |= {"turn_windows": shown.sum(), "turn_rate": rate, "sphere": ball is not None}
        stats |= {f"object{first + k}_{name}": float(v) for name, v in numbers.items()}
        references_us[first + k] = t_ref
    if still:
        c2w = data.trajectory.pose(float(sightings.times_us[0]))  # the camera's one pose
        footprint = views.renderer.render(int(sightings.times_us[0]), c2w).meta["radii"]
        drawn = footprint.cpu().numpy().reshape(-1) > 0
        z = project(model.means.detach().cpu().numpy().astype(np.float64), c2w, data.K)[1]
        back = max(max(backs), float(z[object_id >= 0].max()))  # the objects found before too
        moved = behind_objects(model, optimizer, object_id < 0, back, c2w, data.K, drawn)
        stats["moved_behind"] = float(moved)
    parts = (centres, radii, shifts, rotvecs, spans)  # faded in and out over a window spacing
    # Under a moving camera the space an object hides is the surface behind it, placed there by
    # parallax; under a still one nothing places it, and what the warm-up left on the object's
    # rays behind it is swept too (docs/experiments/objects.md, "The space behind an object,
    # swept under a still camera only").
    behind = BEHIND if still else 0.0
    tensors = (torch.from_numpy(np.array(p)) for p in parts)
    motion = ObjectMotion(*tensors, fade=1 / mc.windows, behind=behind)
    device = model.means.device
    motion = motion.to(device) if known is None else known[0].joined(motion)
    return Seeded(stats, motion, torch.from_numpy(object_id).to(device), references_us)
