"""The mover's seeding after the warm-up (not in the paper): its path from the events the
static model leaves unexplained, or from the events' counts where those see it in clearly more
windows (``evsplat.train.mover_path``), its depth from the static model's
render, its spin from its own events (``evsplat.train.spin``); Gaussians placed on it and the
deformation MLP fitted to carry them. See ``seed_mover``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from evsplat.config import MoverConfig, TrainConfig
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel
from evsplat.train.mover import (
    MoverTrack,
    disc_depth,
    fit_mlp_to_path,
    lift,
    near_path,
    place_on_mover,
)
from evsplat.train.mover_path import (
    MoverPath,
    disc_inside,
    find_path,
    interp_rows,
    pooled,
    unexplained,
)
from evsplat.train.spin import SpinSettings, event_labels, find_spin, integrate
from evsplat.train.views import Views

FIT_GRID = 121  # times on which the MLP is fitted to the mover's path and turn
#: Most events a spin window reads, evenly thinned past it: the window is 5% of the recording
#: (25 M events of a 500 M-event file, and the spin places a pose on each: 128 B an event),
#: while the spin uses a few thousand on the mover; the tiny ball's hold ~34 000 on average.
SPIN_WINDOW_EVENTS = 1_000_000
#: How much larger a share of the windows the event counts must see a mover in than the static
#: model's residual, to be its evidence (camo: 0.21-0.36 more at 2000 and 4000 iterations; the
#: other built-in scenes: 0 to 0.31 less).
COUNTS_MARGIN = 0.1


def seen(path: MoverPath, mc: MoverConfig) -> float:
    """The share of the path's windows whose blob passes the contrast test."""
    return float((path.contrast >= mc.min_contrast).mean())


@dataclass
class Seeding:
    """What the seeding did: numbers for the log, whether it placed a mover (then the MLP was
    fitted, and its optimizer's moments are stale), and the track prior it leaves."""

    stats: dict[str, float]
    seeded: bool
    track: MoverTrack | None


def seed_mover(
    views: Views,
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    mlp: DeformationMLP,
    cfg: TrainConfig,
    depth_range: tuple[float, float],
) -> Seeding:
    """After the warm-up: find a fast mover from the events the static model leaves
    unexplained (or their counts: above), re-place on it (at the time it is seen best) the
    Gaussians that smear it along its path and then the faintest, fit the MLP to carry them
    along its path (turning them with the spin its events show), and
    mark every other Gaussian static (the background's gradients drowned the mover's in a
    shared MLP: docs/results.md, session 11). Nothing changes when no mover is found, except
    that the renderer draws the static model."""
    mc, data, renderer = cfg.mover, views.data, views.renderer
    renderer.mlp = None  # the warm-up's static model

    def residual_of(t0: int, t1: int) -> torch.Tensor:
        esi = views.esi(t0, t1)[0]
        return unexplained(esi, views.log_image_at(t1) - views.log_image_at(t0), mc.pool)

    def counts_of(t0: int, t1: int) -> torch.Tensor:
        ev = data.events.read(t0, t1, most=SPIN_WINDOW_EVENTS)  # thinned evenly: same shape
        return pooled(torch.from_numpy(ev.event_count(0, len(ev)).astype(np.float64)), mc.pool)

    with torch.no_grad():
        span = (data.t_start_us, data.t_end_us)
        path = find_path(residual_of, *span, mc, allowed=views.allowed)
        # A mover whose texture is finer than its motion in a window fires events of both
        # signs at each pixel: they cancel in the ESI, and the static model, which cannot draw
        # that texture either, leaves no residual there. Their number does not cancel. Where
        # the residual sees the mover it places it better (it knows the static scene), so the
        # counts take over only where they see it in clearly more windows (docs/results.md,
        # session 27: camo 67% against 31-46%; on every other built-in scene at most as often).
        # (Not computed where the residual leaves the counts no room to win: the windows'
        # reads and ring fits cost seconds at 400x400.)
        found, by_counts = seen(path, mc), False
        if found + COUNTS_MARGIN < 1.0:
            counted = find_path(counts_of, *span, mc, converge=False, allowed=views.allowed)
            counted_found = seen(counted, mc)
            by_counts = counted_found > found + COUNTS_MARGIN
            if by_counts:
                path, found = counted, counted_found
    # Whether there is a mover: the windows that saw one (contrast); its path: the found
    # windows, fewer (mover_path.prefer_ring and mover_path.connected drop the fits that disagree).
    if found < mc.min_found or not path.found.any():
        return Seeding({"mover_found": found}, seeded=False, track=None)
    # The reference: the clearest window well inside the image, with its own radius (the
    # median radius placed a mover twice as large that the model did not move: session 12).
    k = path.reference(data.width, data.height)
    radius_px = float(path.radius_px[k])
    times = path.times_us[path.found]
    depth = mover_depth(views, path, mc.depth_quantile, depth_range)
    poses = data.trajectory.pose(times.astype(np.float64))
    points = lift(path.uv[path.found], np.full(len(times), depth), poses, data.K)
    ref = points[int(np.count_nonzero(path.found[:k]))]  # k is a found window
    radius = radius_px * depth / float(data.K[0, 0])
    n = model.num_gaussians
    # The warm-up drew the mover as a static smear along its path: those Gaussians go on
    # the mover first (they would keep drawing it where it is not), then the faintest.
    swept = near_path(model.means.detach(), points, radius)
    faintest = torch.argsort(model.opacities().detach())
    faintest = faintest[~swept[faintest]]
    m = max(1, int(mc.fraction * n), int(swept.sum()))
    rows = torch.cat([torch.nonzero(swept).reshape(-1), faintest[: m - int(swept.sum())]])
    place_on_mover(model, optimizer, rows, ref, radius, mc.opacity, cfg.seed)
    # The fit follows the path on a grid of times (the spin needs more than the windows).
    grid = np.linspace(data.t_start_us, data.t_end_us, FIT_GRID).astype(np.int64)
    t_ref = int(path.times_us[k])
    turns, spin = mover_spin(views, cfg, path, by_counts, times, points, radius, t_ref, grid)
    t_norm = torch.tensor([renderer.time(int(t)) for t in grid], dtype=torch.float32)
    offsets = torch.from_numpy((interp_rows(grid, times, points) - ref).astype(np.float32))
    rms = fit_mlp_to_path(
        mlp,
        model.means[rows],
        t_norm,
        offsets,
        None if turns is None else torch.from_numpy(turns.astype(np.float32)),
        ref,
        mc.fit_steps,
        mc.fit_lr,
        cfg.seed,
    )
    track = None
    # Only a circle's path: a blob's centre is the centre of the unexplained events, which on
    # the butterfly and the duck lies 4-13 px off the body, and holding the Gaussians there
    # cost 2.1-2.8 dB on their masks (docs/results.md, session 26).
    if mc.track_weight > 0 and path.round:
        reach = int(mc.track_reach * (data.t_end_us - data.t_start_us))
        track = MoverTrack(times, points, radius, reach)
    static = torch.ones(n, dtype=torch.bool)
    static[rows] = False
    renderer.static_mask = static
    stats = {
        "mover_found": found,
        "mover_by_counts": float(by_counts),
        "mover_depth": depth,
        "mover_radius_px": radius_px,
        "mover_fit_rms": rms,
        "mover_gaussians": float(m),
        "mover_swept": float(swept.sum()),
    } | spin
    return Seeding(stats, seeded=True, track=track)


def mover_spin(
    views: Views,
    cfg: TrainConfig,
    path: MoverPath,
    by_counts: bool,
    times: np.ndarray,
    points: np.ndarray,
    radius: float,
    t_ref: int,
    grid: np.ndarray,
) -> tuple[np.ndarray | None, dict[str, float]]:
    """The mover's turn from ``t_ref`` to each ``grid`` time [G,3,3], from the angular
    velocities its events show (``evsplat.train.spin``) in the windows where its disc is
    inside the image; None when it is off, no window shows a spin, or the mover is neither
    round nor found by its counts and its windows' median gain is under
    ``spin_body_gain``. Every mover is treated as a sphere, whatever its shape: a body that is
    no sphere gets a turn that the training then reshapes. Measured over three seeds against
    turning only a round mover or one found by its counts (docs/results.md, session 31): the
    duck's mask +1.0 dB, a textured sphere that the static model's residual sees on a blob
    path (`camo` at a coarser lattice) +1.9, the shaking clock 0.25 dB lower; the butterfly,
    whose windows sharpen least, 0.8 dB lower over five seeds, hence the gate. Numbers for
    the log."""
    mc, data = cfg.mover, views.data
    if not mc.spin:
        return None, {}
    duration = data.t_end_us - data.t_start_us
    half = max(int(mc.spin_window * duration) // 2, 1)
    centres = np.arange(data.t_start_us + half, data.t_end_us - half + 1, 2 * half)
    centres = centres[(centres >= times[0]) & (centres <= times[-1])]
    r_px = float(np.median(path.radius_px[path.found]))
    centres = centres[disc_inside(path.at(centres), r_px, data.width, data.height)]
    centres = centres[[views.allowed(int(c) - half, int(c) + half) for c in centres]]
    if len(centres) == 0:
        return None, {"spin_windows": 0.0}

    # One contrast image per colour channel and polarity for a mover that is not round, whose
    # texture one image of all its events does not sharpen (`camo`, given its true path: 17 of
    # 20 windows found instead of none); one image for a round mover, whose broad segments it
    # sharpens (the ball: 14 of 14 windows either way), where six sparser images once found
    # 12.9 rad/s for a true 10.3 and cost a run 2.9 dB on its mask (docs/results.md, session 29).
    split = by_counts or not path.round
    on_blobs = not (path.round or by_counts)  # the mover ``spin_body_gain`` gates
    cmap = None if views.channel_map is None else views.channel_map.numpy()

    def events_in(t0: int, t1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ev = data.events.read(t0, t1, most=SPIN_WINDOW_EVENTS)
        uv = np.stack([ev.x, ev.y], 1).astype(np.float64) + 0.5
        if not split:
            return uv, ev.t, np.zeros(len(ev), dtype=np.int64)
        channel = np.zeros(len(ev), dtype=np.int64) if cmap is None else cmap[ev.y, ev.x]
        return uv, ev.t, event_labels(channel, ev.p)

    settings = SpinSettings(
        mc.spin_rim,
        mc.spin_events,
        mc.spin_max_rate,
        mc.spin_min_gain,
        mc.spin_steps,
        cfg.seed,
    )
    omegas, gains = find_spin(
        events_in,
        lambda t: interp_rows(t, times, points),
        lambda t: data.trajectory.pose(np.asarray(t, dtype=np.float64)),
        radius,
        data.K,
        (data.width, data.height),
        centres,
        half,
        settings,
    )
    used = gains >= mc.spin_min_gain
    stats = {"spin_windows": float(used.sum()), "spin_gain": float(np.nanmedian(gains))}
    if not used.any():
        return None, stats
    if on_blobs and stats["spin_gain"] < mc.spin_body_gain:
        return None, stats
    rate = np.linalg.norm(omegas[used], axis=1)
    stats["spin_rate"] = float(np.median(rate))
    turns = integrate(centres[used], omegas[used], t_ref, grid)
    return turns, stats


@torch.no_grad()
def mover_depth(
    views: Views, path: MoverPath, quantile: float, depth_range: tuple[float, float]
) -> float:
    """The mover's camera depth: per found window, a near quantile of the static model's
    rendered depth in the mover's disc (the warm-up drew the mover there as a smear, partly
    in front of the background it passes), then the median over the windows. One window's
    median depth lay up to 1.1 m behind the ball and put the mover behind the wall
    (docs/results.md, session 14). It reads the mover's front surface, not its centre;
    placing the centre one radius further made training drift the mover deeper still
    (session 15). The depth range's middle when no disc was drawn."""
    found = []
    for k in np.flatnonzero(path.found):
        t = int(path.times_us[k])
        out = views.renderer.render(t, views.pose(t))
        d = disc_depth(
            out.depth,
            out.alpha,
            path.uv[k],
            float(path.radius_px[k]),
            quantile,
        )
        if d is not None:
            found.append(d)
    return float(np.median(found)) if found else float(np.mean(depth_range))
