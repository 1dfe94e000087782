"""A round object's turn about all three axes (docs/motion.md, step 4): its outline from the
events, then contrast maximisation with its events put on a sphere's front. The in-plane turn
(``turn``) sees only the part about the viewing axis; a ball also rolls towards the camera."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from evsplat.model.gaussians import quat_to_rotmat
from evsplat.model.motion import rotvec_to_quat
from evsplat.motion.turn import warped_variance

BIN_PX = 0.5  # the ring fit's radius step
RING_PX = 1.0  # an event within this of the ring is on it; the next 2 px each side are its sides
RADII = (0.8, 1.8)  # the ring's radius, in the region's radii: the region is the ball's lit part
#: An object is round where its ring (its outline) moves at most this many px between sightings
#: and stands out this many times from its sides (medians; docs/motion.md, "Tuning numbers").
STEADY_PX = 1.5
CONTRAST = 2.5
EPS = 1e-12  # guards the contrast's ratio
REACH = RADII[1] + 0.5  # events within this many region radii can be on the ring
#: A cut outline's circle places the object only where this much of it is in view (an arc) and
#: it stands out this many times from its sides: one off the object stands out less
#: (docs/motion.md, "Tuning numbers").
SEEN = 0.25
CUT_CONTRAST = 2.0
FRONT = 0.9  # of the ring's radius: events nearer its outline have no one depth on the sphere
MAX_EVENTS = 1500  # the turn's contrast and a cut outline read at most this many events
GRIDS = ((8.0, 4), (24.0, 2), (72.0, 2))  # nested grids: step (top rate / this), half width
STEP_US = 1000  # the turn's integration step
# The ring search's centres at a time: whole, a large object's [centres, events] arrays outgrow
# the caches (docs/experiments/objects.md, "The seeding's searches drawn over their events").
BLOCK = 64


def distances(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """[C,E] distances of ``points`` [E,2] from ``centres`` [C,2]: ``np.linalg.norm``'s values (the
    same sums of squares) without its [C,E,2] array."""
    dx = np.subtract.outer(centres[:, 0], np.ascontiguousarray(points[:, 0]))
    dy = np.subtract.outer(centres[:, 1], np.ascontiguousarray(points[:, 1]))
    dx *= dx
    dy *= dy
    dx += dy
    return np.sqrt(dx, out=dx)


def ring(off: np.ndarray, radius: float) -> tuple[np.ndarray, float, float] | None:
    """(centre [2], radius px, contrast) of the circle that the events at ``off`` [E,2] (px
    from the region's centre, carried back by its velocity) pile up on: a ball's outline, where
    its events stack up. Centres within half the region's ``radius``; the contrast is the
    ring's events per px² over its sides' (1: no ring). None where the best radius is at the
    search's end (no ring there)."""
    reach = int(np.ceil(0.5 * radius))
    shifts = np.arange(-reach, reach + 1, dtype=np.float64)
    centres = np.stack(np.meshgrid(shifts, shifts), -1).reshape(-1, 2)  # [C,2]
    radii = np.arange(*(np.round(np.array(RADII) * radius / BIN_PX)), dtype=np.int64)  # bins
    edge = radii[-1] + int(3 * RING_PX / BIN_PX) + 1
    counts = histograms(off, centres, int(edge))  # [C,bins]
    below = np.concatenate([np.zeros((len(centres), 1)), np.cumsum(counts, 1)], 1)  # d < bin

    def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # events a <= d/BIN_PX < b
        return below[:, np.clip(b, 0, edge)] - below[:, np.clip(a, 0, edge)]

    on, side = int(RING_PX / BIN_PX), int(3 * RING_PX / BIN_PX)
    length = 2 * np.pi * radii * BIN_PX  # [R] px of ring
    on_ring = between(radii - on, radii + on) / (2 * length)  # per px², [C,R]
    sides = (between(radii - side, radii - on) + between(radii + on, radii + side)) / (4 * length)
    c, r = np.unravel_index(int(np.argmax(on_ring - 0.5 * sides)), on_ring.shape)
    if r in (0, len(radii) - 1):
        return None
    return centres[c], float(radii[r] * BIN_PX), float(on_ring[c, r] / max(sides[c, r], EPS))


def histograms(off: np.ndarray, centres: np.ndarray, edge: int) -> np.ndarray:
    """[C, edge + 1] counts of the events at ``off`` [E,2] by their distance from each of
    ``centres`` [C,2], in ``BIN_PX`` bins, the last one all beyond; ``BLOCK`` centres at a time."""
    out = []
    for block in np.split(centres, range(BLOCK, len(centres), BLOCK)):
        scaled = distances(off, block)
        scaled /= BIN_PX
        bins = np.minimum(scaled, edge, out=scaled).astype(np.int64)
        bins += np.arange(len(block))[:, None] * (edge + 1)  # one histogram per centre, at once
        out.append(np.bincount(bins.ravel(), minlength=len(block) * (edge + 1)))
    return np.concatenate(out).reshape(len(centres), edge + 1)


def _thinned(n: int) -> np.ndarray:
    """Indices of at most ``MAX_EVENTS`` of ``n`` events, evenly spread over them."""
    return np.linspace(0, n - 1, min(n, MAX_EVENTS)).astype(np.int64)


def on_outline(
    off: np.ndarray, rho: float, lo: np.ndarray, hi: np.ndarray, reach: float
) -> np.ndarray | None:
    """[2] px: the centre within ``reach`` px of 0 of the circle of radius ``rho`` that the
    events at ``off`` [E,2] pile up on most, per px of it inside the image (``lo`` to ``hi``
    [2], px in ``off``'s frame), less its sides as in ``ring``: a ball's outline where the
    border cuts it. None where less than ``SEEN`` of every such circle is in the image, or
    where the best stands out from its sides less than ``CUT_CONTRAST`` times."""
    off = off[_thinned(len(off))]
    angles = np.linspace(0.0, 2 * np.pi, 90, endpoint=False)
    rim = rho * np.stack([np.cos(angles), np.sin(angles)], 1)  # [A,2]
    best = np.zeros(2)
    for step, half in ((1.0, reach), (0.25, 1.0)):  # whole pixels, then quarters about the best
        shifts = np.arange(-half, half + 1e-9, step)
        centres = best + np.stack(np.meshgrid(shifts, shifts), -1).reshape(-1, 2)  # [C,2]
        points = centres[:, None] + rim[None]
        seen = ((points >= lo) & (points < hi)).all(-1).mean(1)  # [C] of the circle in view
        gap = np.abs(distances(off, centres) - rho)  # [C,E]
        on = (gap < RING_PX).sum(1) / (2 * RING_PX)
        sides = ((gap >= RING_PX) & (gap < 3 * RING_PX)).sum(1) / (4 * RING_PX)
        score = np.where(seen >= SEEN, (on - 0.5 * sides) / np.maximum(seen, EPS), -np.inf)
        if not np.isfinite(score).any():
            return None
        c = int(np.argmax(score))
        best = centres[c]
    return best if on[c] > CUT_CONTRAST * sides[c] else None


def is_round(centres: list[np.ndarray], contrasts: list[float]) -> bool:
    """Whether an object's rings, their ``centres`` (px from its regions' centres, in
    sighting order) and ``contrasts``, show a round object: they stand out from their sides
    and hold still on its regions."""
    step = np.linalg.norm(np.diff(np.array(centres), axis=0), axis=1)
    if not step.size:
        return False
    return float(np.median(contrasts)) >= CONTRAST and float(np.median(step)) <= STEADY_PX


def turned(points: torch.Tensor, omegas: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """``points`` [E,3] turned back by ``omegas`` [B,3] (rad/s) over ``dt`` [E] s: [B,E,3]."""
    turn = quat_to_rotmat(rotvec_to_quat(-omegas[:, None, :] * dt[None, :, None]))  # [B,E,3,3]
    return torch.einsum("beij,ej->bei", turn, points)


def sphere_rate(
    off: np.ndarray, dt: np.ndarray, p: np.ndarray, centre: np.ndarray, radius: float,
    top: float, shape: tuple[int, int],
) -> np.ndarray:  # fmt: skip
    """Angular velocity [3] (rad/s, camera frame: x right, y down, z forward) of a sphere of
    ``radius`` px at image ``centre`` [2] whose events ``off`` [E,2] (px from its centre,
    carried back), ``dt`` [E] s and ``p`` [E] lie on its front: the one in nested grids up to
    ``top`` / 2 whose warped events are sharpest (orthographic, a ball a few degrees wide)."""
    keep = _thinned(len(off))
    off, dt, p = off[keep], dt[keep], p[keep]
    depth = -np.sqrt(np.maximum(radius**2 - (off**2).sum(1), 0.0))  # its front faces the camera
    points = torch.from_numpy(np.concatenate([off, depth[:, None]], 1)).float()
    dt_t, best = torch.from_numpy(dt).float(), torch.zeros(3)
    shift = torch.from_numpy(centre - 0.5).float()  # to pixel units, centres at whole numbers
    for fraction, half in GRIDS:
        steps = torch.arange(-half, half + 1, dtype=torch.float32) * top / fraction
        grid = torch.stack(torch.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)
        grid = grid + best
        score = np.concatenate([
            warped_variance(*(q[..., :2] + shift).unbind(-1), p, shape)
            for q in (turned(points, g, dt_t) for g in grid.split(128))
        ])  # fmt: skip
        best = grid[int(np.argmax(score))]
    return best.double().numpy()


def rotvecs(times_us: np.ndarray, omegas: np.ndarray, knots: np.ndarray, t_ref: int) -> np.ndarray:
    """Rotation vectors [G,3] at ``knots`` [G] µs from ``t_ref``: the angular velocities
    ``omegas`` [F,3] (rad/s, world frame) measured at ``times_us`` [F], linear between them and
    held beyond, integrated; each the nearest to the last of its turns by whole 2π."""
    knots = np.asarray(knots, dtype=np.float64)
    grid = np.union1d(np.arange(knots[0], knots[-1], STEP_US), np.append(knots, float(t_ref)))
    mid = 0.5 * (grid[1:] + grid[:-1])  # each step turns at its middle's rate
    rate = np.stack([np.interp(mid, times_us, omegas[:, j]) for j in range(3)], 1)
    steps = Rotation.from_rotvec(rate * np.diff(grid)[:, None] * 1e-6)
    at = [Rotation.identity()]
    for step in steps:
        at.append(step * at[-1])
    ref = at[int(np.searchsorted(grid, float(t_ref)))].inv()
    out, last = [], np.zeros(3)
    for i in np.searchsorted(grid, knots):
        v = (at[i] * ref).as_rotvec()
        angle = np.linalg.norm(v)
        if angle > 1e-9:  # the same turn by 2π more or less: the one that carries on
            v = min((v * (1 + 2 * np.pi * m / angle) for m in range(-3, 4)),
                    key=lambda c: np.linalg.norm(c - last))  # fmt: skip
        out.append(v)
        last = v
    return np.array(out)
