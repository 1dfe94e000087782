"""Each object's path refined against the events by search (docs/motion.md, step 8): the
losses' gradients leave a path where the seeding put it, wrong where the seeding was (an object
cut by the image border), so at each knot the object is moved in the image plane to where the
model's render best explains the events of a short window about the knot. The render is the
whole scene's: the border, occlusions and the other objects are drawn as they are."""

from __future__ import annotations

import time

import numpy as np
import torch

from evsplat.config import MoverConfig
from evsplat.model.motion import ObjectMotion
from evsplat.motion.segment import unexplained
from evsplat.projection import project
from evsplat.train.views import Views

# A shift is kept where it lowers its window's residual by this share: on the demo's trained
# ball (docs/motion.md, "Paths refined by search") the knots where it is out of view or still
# gained 0.000-0.003, those where the border cuts it 0.05-0.56.
GAIN = 0.05


def refine_paths(views: Views, motion: ObjectMotion, mc: MoverConfig) -> dict[str, float]:
    """Move each object's path knots (and the track prior with them) to the image-plane shift
    that best explains the events about each knot; numbers for the log."""
    start = time.perf_counter()
    data, knots = views.data, motion.translations.shape[1]
    duration = data.t_end_us - data.t_start_us
    half = int(min(mc.window, 1.0 / (knots - 1)) * duration) // 2  # within the knot's neighbours
    moved, shifts = 0, []
    for k in range(motion.translations.shape[0]):
        found = {g: _best_shift(views, motion, mc, k, g, half) for g in range(knots)}
        found = {g: v for g, v in found.items() if v is not None}
        with torch.no_grad():
            for g, (axes, _) in found.items():
                # Per knot the median of its and its neighbours' shifts: one window's search can
                # be led off where the object is a sliver at the border (the ball's, 20 px).
                px = np.median([found[j][1] for j in (g - 1, g, g + 1) if j in found], axis=0)
                world = axes @ torch.tensor([px[0], px[1], 0.0], dtype=torch.float32)
                motion.translations[k, g] += world.to(motion.translations.device)
                motion.prior_translations[k, g] += world.to(motion.translations.device)
                shifts.append(float(np.linalg.norm(px)))
                moved += bool(px.any())
    spent = time.perf_counter() - start
    median = float(np.median(shifts)) if shifts else 0.0
    return {"refined_knots": float(moved), "refined_px": median, "refine_seconds": spent}


def _best_shift(
    views: Views, motion: ObjectMotion, mc: MoverConfig, k: int, g: int, half: int
) -> tuple[torch.Tensor, np.ndarray] | None:
    """(the image plane's axes at object ``k``'s depth [3,3] (world per px, the third 0), the
    shift (dx, dy) px that best explains the events) at knot ``g``; 0 where none explains them
    by ``GAIN`` better; None where the object is out of view or the window held out."""
    data, renderer = views.data, views.renderer
    knots = motion.translations.shape[1]
    u = g / (knots - 1)
    if not float(motion.spans[k, 0]) <= u <= float(motion.spans[k, 1]):
        return None
    t_us = data.t_start_us + round(u * (data.t_end_us - data.t_start_us))
    t0, t1 = max(t_us - half, data.t_start_us), min(t_us + half, data.t_end_us)
    if t1 <= t0 or not views.allowed(t0, t1):
        return None
    c2w = views.pose(t_us)
    with torch.no_grad():
        centre = (motion.centres[k] + motion.at(renderer.time(t_us))[1][k]).double().cpu()
    uv, z = project(centre.numpy()[None], c2w, data.K)
    if z[0] <= 0:
        return None
    fx, fy = float(data.K[0, 0]), float(data.K[1, 1])
    radius = float(motion.radii[k]) * fx / float(z[0])
    if not (-radius < uv[0, 0] < data.width + radius and -radius < uv[0, 1] < data.height + radius):
        return None
    esi = views.esi(t0, t1)[0]
    axes = torch.from_numpy(c2w[:3, :3] * np.array([z[0] / fx, z[0] / fy, 0.0])).float()
    rows = renderer.object_id == k
    # The knots about the window (it lies between them) moved alike move the object's Gaussians
    # alike at both ends (the MLP reads canonical means): deformed once, its rows shifted.
    with torch.no_grad():
        ends = [renderer.gaussians_at(t) for t in (t0, t1)]

    scores: dict[tuple[float, float], float] = {}

    def residual(d: np.ndarray) -> float:
        key = (float(d[0]), float(d[1]))
        if key in scores:
            return scores[key]
        shift = (axes @ torch.tensor([d[0], d[1], 0.0], dtype=torch.float32)).to(rows.device)
        drawn = []
        with torch.no_grad():
            for t, (means, quats, scales) in zip((t0, t1), ends):
                moved = torch.where(rows[:, None], means + shift, means)
                drawn.append(renderer.render_async(t, views.pose(t), None, (moved, quats, scales)))
            first, last = (views.log_image(e.result()) for e in drawn)
            scores[key] = float((unexplained(esi, last - first, mc.pool) ** 2).sum())
        return scores[key]

    # Compass search, coarse to fine to half a pixel: a step to the best of the four neighbours
    # while one is better, else a step half as long.
    best, step = np.zeros(2), 2.0 ** max(int(np.log2(max(radius / 2.0, 1.0))), 0)
    compass = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    while step >= 0.5:
        near = min((best + step * c for c in compass), key=residual)
        if residual(near) < residual(best) and np.abs(near).max() <= 2.0 * radius:
            best = near
        else:
            step /= 2.0
    if residual(best) > (1.0 - GAIN) * residual(np.zeros(2)):
        best = np.zeros(2)
    return axes, best
