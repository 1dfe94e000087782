"""After the warm-up: find every moving object in the events and start its motion (not in the
paper, which starts from a point cloud that event data does not have). The steps, each in its
own module (docs/motion.md): ``segment`` the windows' unexplained events into regions, chain
them into ``tracks``, ``align`` their centres, measure each object's ``turn``, lift the tracks
to world ``paths``; here, Gaussians placed on each object's shape and an ``ObjectMotion`` that
carries them along the path and turn. The scene's Gaussians skip the MLP afterwards (the
background's gradients drowned a mover's in a shared MLP: docs/experiments/motion.md); nothing
changes when no object is found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from evsplat.config import MoverConfig
from evsplat.model.densify import set_rows
from evsplat.model.gaussians import T_LOG_SCALE_RANGE, GaussianModel
from evsplat.model.motion import ObjectMotion
from evsplat.motion.align import align
from evsplat.motion.border import in_image, touches_border
from evsplat.motion.paths import hold_path, near_path, turn_angles, turns, two_ends
from evsplat.motion.segment import Blob, blurred, floor, regions, unexplained
from evsplat.motion.still import behind_objects, is_still
from evsplat.motion.tracks import Track, chain, together
from evsplat.motion.turn import WindowEvents, turn_rate
from evsplat.projection import back_project, project
from evsplat.train.views import Views

#: Most events a turn window reads, evenly thinned past it (a 500 M-event recording's windows
#: hold millions; the turn of one object needs a few thousand).
TURN_WINDOW_EVENTS = 1_000_000
OPAQUE = 0.5  # rendered alpha above which the static model's depth is read


@dataclass
class Seeded:
    """What the seeding found: its numbers for the log, and the objects' motion and each
    Gaussian's object (None when nothing moves)."""

    stats: dict[str, float]
    motion: ObjectMotion | None
    object_id: torch.Tensor | None


@dataclass
class Sightings:
    """The segmentation's output: per window, its middle time, regions, residual, and the
    static model's rendered depth and alpha at its end."""

    times_us: np.ndarray  # [W]
    blobs: list[list[Blob]]
    residual: list[np.ndarray]
    depth: list[np.ndarray]
    alpha: list[np.ndarray]


@torch.no_grad()
def sight(views: Views, mc: MoverConfig) -> Sightings:
    """Segment ``mc.windows`` short windows spread over the sequence against what the renderer
    draws (after the warm-up, the static model; later, everything found so far)."""
    data, renderer = views.data, views.renderer
    least = floor(data.c_pos, data.c_neg, mc.pool)
    span = data.t_end_us - data.t_start_us
    half = max(int(mc.window * span) // 2, 1)
    mids = np.linspace(data.t_start_us + half, data.t_end_us - half, mc.windows).astype(np.int64)
    mids = mids[[views.allowed(int(m) - half, int(m) + half) for m in mids]]  # held out: unread
    blobs, residuals, depth, alpha = [], [], [], []
    for mid in mids:
        t0, t1 = int(mid) - half, int(mid) + half
        start = renderer.render(t0, views.pose(t0))
        end = renderer.render(t1, views.pose(t1))
        change = views.log_image(end) - views.log_image(start)
        residual = unexplained(views.esi(t0, t1)[0], change, mc.pool)
        blobs.append(regions(residual, int(mid), mc, least))
        residuals.append(residual)
        depth.append(end.depth.cpu().numpy())
        alpha.append(end.alpha.cpu().numpy())
    return Sightings(mids, blobs, residuals, depth, alpha)


def object_depth(track: Track, sightings: Sightings, quantile: float) -> float | None:
    """A near ``quantile`` of the static model's opaque rendered depth in each of the track's
    regions, median over them; None where no region is drawn."""
    found = []
    for k, blob in track.blobs.items():
        seen = blob.mask & (sightings.alpha[k] > OPAQUE) & (sightings.depth[k] > 0)
        if seen.any():
            found.append(float(np.quantile(sightings.depth[k][seen], quantile)))
    return float(np.median(found)) if found else None


def span(track: Track, sightings: Sightings, t_start_us: int, t_end_us: int) -> list[float]:
    """The normalised times the object is in view between: from half a window spacing before
    its first sighting when that region touches the image border (it came in there), unless it
    is the first window; likewise at its end; ±inf otherwise (it was there all along, still)."""
    ks, last = sorted(track.blobs), len(sightings.times_us) - 1
    ends = (sightings.times_us[[ks[0], ks[-1]]] - t_start_us) / max(t_end_us - t_start_us, 1)
    step, inf = 0.5 / max(last, 1), float("inf")
    enters = ks[0] > 0 and touches_border(track.blobs[ks[0]].mask)
    leaves = ks[-1] < last and touches_border(track.blobs[ks[-1]].mask)
    return [ends[0] - step if enters else -inf, ends[1] + step if leaves else inf]


def reference(track: Track) -> int:
    """The window to place the object at: its clearest sighting clear of the image border
    (a cut object looks smaller and off-centre), else its clearest."""
    ks = sorted(track.blobs)
    inside = [k for k in ks if not touches_border(track.blobs[k].mask)] or ks
    return max(inside, key=lambda k: track.blobs[k].contrast)


def shape(
    track: Track, i: int, middle: np.ndarray, end: np.ndarray, seen: np.ndarray
) -> np.ndarray:
    """[H,W] bool: the object's pixels at its ``i``-th sighting, its region there; where its
    track hops between two ends (``paths.two_ends``: centres ``middle``, ``end``), with the other
    end's clearest region clear of the border carried there by the object's turn (``seen``,
    rad) about its centre."""
    blobs = [track.blobs[k] for k in sorted(track.blobs)]
    mask = blobs[i].mask.copy()
    other = [j for j, b in enumerate(blobs) if end[j] != end[i] and not touches_border(b.mask)]
    if not other:
        return mask
    j = max(other, key=lambda j: blobs[j].contrast)
    ys, xs = np.nonzero(blobs[j].mask)
    uv = (np.stack([xs, ys], 1) + 0.5 - middle[j]) @ turns(seen[i] - seen[j]).T
    px = np.floor(uv + middle[i]).astype(np.int64)
    px = px[in_image(px, mask.shape)]
    mask[px[:, 1], px[:, 0]] = True
    return mask


def turn_rates(views: Views, track: Track, mc: MoverConfig) -> np.ndarray:
    """The object's in-plane turn rate (rad/s) at each sighting (``turn.turn_rate`` on the
    events of a ``mc.turn_window`` window that its region holds once carried back by its image
    velocity), NaN where the turn sharpens them by less than ``mc.turn_min_gain``."""
    data = views.data
    half_us = max(int(mc.turn_window * (data.t_end_us - data.t_start_us)) // 2, 1)
    times, centres = track.times_us, track.centres
    seconds = times.astype(np.float64) * 1e-6
    velocity = np.gradient(centres, seconds, axis=0) if len(times) > 1 else np.zeros_like(centres)
    out = np.full(len(times), np.nan)
    for i, k in enumerate(sorted(track.blobs)):
        mask = track.blobs[k].mask
        # Inside the data's time range (a run on part of a recording reads nothing beyond it).
        t0 = max(int(times[i]) - half_us, data.t_start_us)
        t1 = min(int(times[i]) + half_us, data.t_end_us)
        if t1 <= t0 or not views.allowed(t0, t1):
            continue  # held out: never read in training
        ev = data.events.read(t0, t1, TURN_WINDOW_EVENTS)
        dt = (ev.t - times[i]) * 1e-6
        xy = np.stack([ev.x, ev.y], 1).astype(np.float64) + 0.5
        back = np.floor(xy - velocity[i][None] * dt[:, None]).astype(np.int64)
        inside = in_image(back, mask.shape)
        inside[inside] = mask[back[inside, 1], back[inside, 0]]
        if inside.sum() < mc.turn_min_events:
            continue
        window = WindowEvents(xy[inside], dt[inside], ev.p[inside])
        # At one radian per window an edge's events smear over the whole object: no faster.
        top = 1.0 / max(2 * half_us * 1e-6, 1e-9)
        rate, gain = turn_rate(window, track.blobs[k].centre, velocity[i], top, mask.shape)
        if gain >= mc.turn_min_gain:
            out[i] = rate
    return out


Turning = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # ``turning``'s


def turning(views: Views, track: Track, mc: MoverConfig) -> Turning:
    """(the turn rates [F] (``turn_rates``); the object's centres [F,2], ends [F] and turn
    angles [F] (rad, from its first sighting; 0 where too few rates were measured) at its
    sightings, ``paths.two_ends``; for an object with two ends, from a steady turn)."""
    ks, times = np.array(sorted(track.blobs)), track.times_us
    rates = turn_rates(views, track, mc) if mc.turn else np.full(len(ks), np.nan)
    used, seen = np.isfinite(rates), np.zeros(len(ks))
    if used.sum() >= mc.turn_min_windows:
        seen = turn_angles(times[used], rates[used], times, min(times))
    found = two_ends(ks, track.centres, seen, track.radius, mc.coast)
    if (found[1] < 0).any() and used.sum() >= mc.turn_min_windows:
        # Its regions are its ends, whose rates stray (-17 to +30 rad/s late in the spinner's
        # 8, docs/motion.md): a steady turn at their median instead, read again at the hops.
        steady = np.median(rates[used]) * (times - times[0]) * 1e-6
        again = two_ends(ks, track.centres, steady, track.radius, mc.coast)
        found = again if (again[1] < 0).any() else found
    return rates, *found


def joined_ends(tracks: list[Track], views: Views, mc: MoverConfig) -> list[tuple[Track, Turning]]:
    """The objects and their ``turning``, an object turning in place one track where the
    chaining broke it at a hop between its ends: a track that starts after another, at most
    ``mc.coast`` + 1 windows past its end, and ends after it joins it where the two (the
    earlier's windows, then the later's) hop between two ends (``two_ends``). A track together
    with a two-ended object's centre (``tracks.together``) is its other end firing at once."""
    gone: set[int] = set()  # ids of the tracks that are part of another
    turns: dict[int, Turning] = {}  # a joined track's, from its join's test
    for track in sorted(tracks, key=lambda t: min(t.blobs)):
        first, last = min(track.blobs), max(track.blobs)
        for home in tracks:
            start, end = min(home.blobs), max(home.blobs)
            if id(home) in gone or not (start < first <= end + mc.coast + 1 and end < last):
                continue
            later = {k: b for k, b in track.blobs.items() if k > end}
            both = Track(home.blobs | later, home.shared | (track.shared & set(later)))
            turn = turning(views, both, mc)
            if (turn[2] < 0).any():
                home.blobs, home.shared = both.blobs, both.shared
                turns[id(home)] = turn
                gone.add(id(track))
                break
    found = []
    for home in tracks:
        if id(home) in gone:
            continue
        found.append((home, turns.get(id(home)) or turning(views, home, mc)))
        middle, end = found[-1][1][1:3]
        if (end < 0).any():  # its other end, firing at once, may be a track of its own
            ks = sorted(home.blobs)
            centred = Track({k: replace(home.blobs[k], centre=c) for k, c in zip(ks, middle)})
            gone |= {id(t) for t in tracks if t is not home and together(centred, t, mc)}
    return [(t, turn) for t, turn in found if id(t) not in gone]


def place(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    rows: torch.Tensor,
    points: np.ndarray,
    spacing: np.ndarray,
    opacity: float,
) -> None:
    """Re-place the Gaussians ``rows`` at ``points`` [M,3]: isotropic at ``spacing`` [M],
    identity rotation, grey, ``opacity``, shown at all times; their optimizer state starts
    afresh."""
    o = min(max(opacity, 1e-4), 1.0 - 1e-4)
    device = model.means.device
    scales = torch.from_numpy(np.log(np.maximum(spacing, 1e-12)).astype(np.float32))
    values = {
        "means": torch.from_numpy(points.astype(np.float32)).to(device),
        "log_scales": scales.to(device).unsqueeze(1),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0], device=device),
        "opacity_logits": math.log(o / (1.0 - o)),
        "sh": 0.0,
        "t_mean": 0.5,
        "t_log_scale": T_LOG_SCALE_RANGE[1],
    }
    set_rows(model, optimizer, rows.to(device), values)


def known_object(track: Track, motion: ObjectMotion, views: Views) -> bool:
    """Whether ``track`` follows an object already found (what its model leaves unexplained
    beside it): in most of the track's windows its centre lies within the two radii of one
    object's centre on its path."""
    data, renderer = views.data, views.renderer
    radii = motion.radii.cpu().numpy() * float(data.K[0, 0])
    near = np.zeros(motion.centres.shape[0])
    for centre, k in zip(track.centres, sorted(track.blobs)):
        t_us = float(track.blobs[k].t_us)
        at = (motion.centres + motion.at(renderer.time(t_us))[1]).detach().cpu().numpy()
        uv, z = project(at, data.trajectory.pose(t_us), data.K)
        reach = track.radius + radii / np.maximum(z, 1e-6)
        near += np.linalg.norm(uv - centre[None], axis=1) <= reach
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
    """Find the moving objects (``sight``, ``tracks.chain``) and start each one's motion: the
    Gaussians that smear it along its path (the warm-up drew it there as a static smear), then
    the faintest, re-placed on its shape at its reference window; its path and turn on the
    knots of an ``ObjectMotion``. ``known``: the objects found before and each Gaussian's
    object; only new objects are seeded then, from the scene's Gaussians, and the motion
    returned holds all objects."""
    data = views.data
    sightings = sight(views, mc)
    tracks = chain(sightings.blobs, mc)
    energy = [blurred(r, mc.blur_px) for r in sightings.residual]
    tracks = [align(t, energy, mc.align) for t in tracks]
    if known is not None:
        tracks = [t for t in tracks if not known_object(t, known[0], views)]
    found = joined_ends(tracks, views, mc)
    tracks = [t for t, _ in found]
    stats = {
        "objects": float(len(tracks)),
        "windows_with_motion": float(np.mean([len(b) > 0 for b in sightings.blobs])),
    }
    if not tracks:
        return Seeded(stats, *(known or (None, None)))
    rng = np.random.default_rng(seed)
    n, focal = model.num_gaussians, float(data.K[0, 0])
    means = model.means.detach().cpu().numpy().astype(np.float64)
    object_id = np.full(n, -1, dtype=np.int64) if known is None else known[1].cpu().numpy().copy()
    first = 0 if known is None else known[0].centres.shape[0]  # the new objects' first id
    free = object_id < 0
    faintest = np.argsort(model.opacities().detach().cpu().numpy(), kind="stable")
    areas = np.array([np.median([b.area for b in t.blobs.values()]) for t in tracks])
    knots = np.linspace(data.t_start_us, data.t_end_us, mc.knots)
    rows, points, spacing, centres, radii, shifts, rotvecs, spans, backs = ([] for _ in range(9))
    for k, (track, (rates, middle, end, seen)) in enumerate(found):
        depth = object_depth(track, sightings, mc.depth_quantile) or float(np.mean(depth_range))
        ref = reference(track)
        t_ref = int(track.blobs[ref].t_us)
        radius = track.radius * depth / focal
        ks = sorted(track.blobs)
        used, seen = np.isfinite(rates), seen - seen[ks.index(ref)]
        angles = np.zeros(len(knots))  # at the knots
        if (end < 0).any():  # the turn its two ends show, held beyond its sightings
            angles = np.interp(knots, track.times_us, seen)
        elif used.sum() >= mc.turn_min_windows:
            angles = turn_angles(track.times_us[used], rates[used], knots, t_ref)
        poses = data.trajectory.pose(track.times_us.astype(np.float64))
        path = back_project(middle, np.full(len(ks), depth), poses, data.K)
        swept = np.flatnonzero(near_path(means, path, radius) & free)
        share = max(int(mc.fraction * n * areas[k] / areas.sum()), mc.min_gaussians)
        rest = faintest[free[faintest]]
        rest = rest[~np.isin(rest, swept)][: max(share - len(swept), 0)]
        pick = np.concatenate([swept, rest])
        free[pick] = False
        object_id[pick] = first + k
        # On its shape: its reference region's pixels, from its front surface one radius deep.
        mask = shape(track, ks.index(ref), middle, end, seen)
        ys, xs = np.nonzero(mask)
        j = rng.integers(len(xs), size=len(pick))
        uv = np.stack([xs[j], ys[j]], 1) + rng.random((len(pick), 2))
        pose_ref = data.trajectory.pose(float(t_ref))
        placed = back_project(uv, depth + radius * rng.random(len(pick)), pose_ref, data.K)
        volume = mask.sum() * (depth / focal) ** 2 * radius
        backs.append(depth + 2.0 * radius)  # its front surface is at depth, its body one radius
        rows.append(pick)
        points.append(placed)
        spacing.append(np.full(len(pick), (volume / max(len(pick), 1)) ** (1 / 3)))
        centres.append(placed.mean(0))
        radii.append(radius)
        at_ref = hold_path(track.times_us, path, np.array([t_ref]))[0]
        shifts.append(hold_path(track.times_us, path, knots) - at_ref)
        spans.append(span(track, sightings, data.t_start_us, data.t_end_us))
        rotvecs.append(angles[:, None] * pose_ref[:3, 2][None])  # about the viewing axis
        stats |= {
            f"object{first + k}_windows": float(len(ks)),
            f"object{first + k}_ends": 2.0 if (end < 0).any() else 1.0,
            f"object{first + k}_depth": depth,
            f"object{first + k}_radius_px": track.radius,
            f"object{first + k}_gaussians": float(len(pick)),
            f"object{first + k}_turn_windows": float(used.sum()),
            f"object{first + k}_turn_rate": float(np.nanmedian(rates)) if used.any() else 0.0,
        }
    place(
        model,
        optimizer,
        torch.from_numpy(np.concatenate(rows)),
        np.concatenate(points),
        np.concatenate(spacing),
        mc.opacity,
    )
    poses = data.trajectory.pose(sightings.times_us.astype(np.float64))
    if is_still(poses):
        footprint = views.renderer.render(int(sightings.times_us[0]), poses[0]).meta["radii"]
        drawn = footprint.cpu().numpy().reshape(-1) > 0
        z = project(model.means.detach().cpu().numpy().astype(np.float64), poses[0], data.K)[1]
        back = max(max(backs), float(z[object_id >= 0].max()))  # the objects found before too
        moved = behind_objects(model, optimizer, object_id < 0, back, poses[0], data.K, drawn)
        stats["moved_behind"] = float(moved)
    motion = ObjectMotion(
        torch.from_numpy(np.stack(centres)),
        torch.tensor(radii),
        torch.from_numpy(np.stack(shifts)),
        torch.from_numpy(np.stack(rotvecs)),
        torch.tensor(spans),
        fade=1.0 / mc.windows,  # one window spacing
    )
    device = model.means.device
    motion = motion.to(device) if known is None else known[0].joined(motion)
    return Seeded(stats, motion, torch.from_numpy(object_id).to(device))
