"""Does the model move its Gaussians with the moving object? Tracking error in pixels.

Image metrics cannot tell a model that moves its Gaussians along with the object from one that
draws the object with different Gaussians at different times (time-local opacity makes that
easy). This module follows the Gaussians themselves, using the simulator's ground-truth object
centre g(t) (``object_centre`` in test/frames.json, docs/dataset.md).

**The object's Gaussians.** Each test frame k in turn is the reference. The object set of k are
the Gaussians whose deformed centre at t_k

- projects (GT pose and intrinsics of frame k) into a pixel of the GT moving-object mask,
- lies in front of or at the object there: camera depth z <= GT depth at that pixel + the
  object's radius (test/track.json; ``DEPTH_TOLERANCE`` x GT depth when the radius is unknown),
  which drops the background seen through the mask's pixels; or in front of or at what the
  model itself draws there (``TrackView.drawn_depth``, its rendered depth, + ``DEPTH_TOLERANCE``
  of it), so that a mover drawn from the wrong depth counts (one moving camera cannot see a
  mover's depth: `camo`'s seeded sphere sits at 4.1 m for a true 3.0, before a wall at 5; the
  following error and path ratio below then carry that depth error, as its world path scales
  with its depth, and the region error measures where it is drawn),
- and has opacity >= ``OPACITY_MIN`` at t_k (time-local factor included: drawn at t_k).

Where the model does not draw the object at t_k, its drawn depth there is the background's, and
the background's Gaussians seen through the mask would pass the second test. So a Gaussian that
only the drawn depth admits (behind the true object + radius), in the set of one test time
alone, that holds still (its centre moves under ``STILL_PX`` over the test times, seen from the
mean camera) and is drawn at another test time off the object, is the background the object
passed in front of, not the object: it is left out of every set. Unions of the sets (the region
below) took it as the object at every time (`pair`'s bar, not drawn at 0.005 s: 48 of the
wall's Gaussians, which put its region 4-14 px off at the five times it is drawn in place).

**Error.** That same set is followed over every test time t_j. Its centre c(t_j) is the
per-coordinate median of its deformed 3-D centres weighted by peak opacity (not the time-local
one, so a set whose members fade in and out does not jump). The median, not the mean: it says
where most of the set's weight goes, and a minority of members that do not move with the object
(static Gaussians left over the object's place, floaters in front of it) cannot drag it; a set
drawn mostly by such Gaussians still scores their standstill. Its offset from the object at
the reference, c(t_k) - g(t_k), is removed, so a set that covers only the visible surface is
not biased: p_k(t_j) = c(t_j) - (c(t_k) - g(t_k)). The error is the pixel distance between
p_k(t_j) and g(t_j), both projected with frame j's GT pose and K (off the image too: a test
time where the object has left the view still counts). The pair j = k is 0 by construction and
left out. Per test time: the median over references; overall: median and mean over all pairs.

**Rigid error.** The offset removal above assumes the set translates with the object. A
spinning object turns its visible surface about its centre (the tiny ball: 10 rad/s, so a cap
seen at t_k is on the far side 0.3 s later), and the set's median then leaves the centre even
when every Gaussian moves exactly with the object. So the true centre g(t_k) is also carried
through time by the set's weighted least-squares rigid motion (Kabsch: rotation and
translation of the set from t_k to t_j, weights the peak opacities), and its pixel distance from
g(t_j) is reported beside the first (``rigid_error_px_median``). Least squares is not robust
to static members of the set, which the median above is: the two are read together.

**Path ratio.** The length of p_k's path through the test times over the length of g's path,
both projected with one fixed camera (the mean test pose: mean position, rotation the nearest
rotation to the mean matrix), so camera motion adds nothing; the median over references. A model
whose object Gaussians stay put scores 0 and an error equal to the object's own displacement;
one that moves them exactly with the object scores 1 and error 0.

**Region error (the headline).** The two errors above follow a set chosen at one reference, so
they also score how the set is arranged (a turning cap's median leaves the centre, a sliding
surface breaks the rigid fit). Where the model draws the object is measured directly: the object
Gaussians (the union of the reference sets) are rendered at every test time with the object in
view, with feature 1 (0 for all others) through the full scene (what covers them, covers them).
The pixels they cover to at least one half are the object's region in the picture; the pixel
distance between its centroid and the GT mask's is the error. Both are cut by the image border
alike. A time whose region is under ``REGION_MIN_COVER`` of the mask's area has the object not
drawn: its error is infinite (the median is None when that is most of them). It does not follow
Gaussians, so a model that draws the object with different Gaussians at different times (time-
local opacity) is not caught here but by the errors above. On a sphere of Gaussians moving and
turning exactly with the ball it reads 0.1-0.6 px, 1.1-1.6 px where the ball is cut by the
border (tests/test_eval.py).

**|Δx|.** Each Gaussian's largest displacement from its time-mean position over the test times,
projected to pixels with the mean camera: percentiles inside the object set (union over
references) and outside it (Gaussians in front of the mean camera with peak opacity
>= ``OPACITY_MIN``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from evsplat.projection import world_to_camera

if TYPE_CHECKING:
    from evsplat.render import Renderer

OPACITY_MIN = 0.05  # a Gaussian fainter than this at t_k does not draw the object there
DEPTH_TOLERANCE = 0.1  # behind-the-surface tolerance as a fraction of depth, radius unknown
MIN_DEPTH = 1e-6  # camera z floor, so points behind a camera project finitely
PERCENTILES = (50, 90, 99)
#: A pixel is in what a set of Gaussians draws where they cover at least this share of it.
COVER = 0.5
REGION_MIN_COVER = 0.25  # the object set must cover this share of the mask's area to be drawn
STILL_PX = 1.0  # a Gaussian whose centre moves less than a pixel over the test times holds still


@dataclass
class TrackView:
    """A ground-truth test view of the tracked object."""

    time_us: int
    c2w: np.ndarray  # [4,4] camera-to-world
    mask: np.ndarray  # [H,W] bool, moving-object pixels
    depth: np.ndarray  # [H,W] camera z of the first hit (0 = nothing)
    centre: np.ndarray  # [3] world position of the object
    drawn_depth: np.ndarray | None = None  # [H,W] the model's rendered depth (0 = nothing)


def to_camera(points: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """World points ``[...,3]`` in the camera frame of ``c2w``."""
    w2c = world_to_camera(c2w)
    return points @ w2c[:3, :3].T + w2c[:3, 3]


def to_pixels(cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel coordinates ``[...,2]`` (x, y; pixel centres at +0.5) of camera points."""
    z = np.maximum(cam[..., 2:3], MIN_DEPTH)
    return cam[..., :2] / z * K[[0, 1], [0, 1]] + K[[0, 1], [2, 2]]


def project(points: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel coordinates of world points seen from ``c2w``."""
    return to_pixels(to_camera(points, c2w), K)


def mean_pose(c2ws: Sequence[np.ndarray]) -> np.ndarray:
    """Mean camera: mean position, and the rotation nearest (Frobenius) to the mean matrix."""
    stack = np.asarray(c2ws, dtype=np.float64)
    u, _, vt = np.linalg.svd(stack[:, :3, :3].mean(axis=0))
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])  # a rotation, not a reflection
    out = np.eye(4)
    out[:3, :3] = u @ fix @ vt
    out[:3, 3] = stack[:, :3, 3].mean(axis=0)
    return out


@dataclass
class ObjectGaussians:
    """The Gaussians at the test times and which of them draw one object (``object_gaussians``)."""

    means: np.ndarray  # [J,N,3] deformed centres at each test time
    peak: np.ndarray  # [N] peak opacities
    camera: np.ndarray  # [4,4] the mean test camera (``mean_pose``)
    moves: np.ndarray  # [N] ``max_displacement_px`` from ``camera``
    sets: np.ndarray  # [J,N] bool: each test time's object set (``object_sets``)
    radius: float | None  # the true object's (m) the sets were chosen with


@torch.no_grad()
def object_gaussians(
    renderer: Renderer, views: Sequence[TrackView], radius: float | None
) -> ObjectGaussians:
    """The Gaussians at ``views``' times and each time's object set, computed once for both the
    following errors (``track_object``) and the region error (``track_region``)."""
    K = renderer.K.double().numpy()
    means = np.stack([renderer.gaussians_at(v.time_us)[0].double().numpy() for v in views])
    opac = np.stack([renderer.opacities(v.time_us).detach().double().numpy() for v in views])
    camera = mean_pose([v.c2w for v in views])
    moves = max_displacement_px(means, camera, K)
    sets = object_sets(means, opac, moves, views, K, radius)
    peak = renderer.model.opacities().double().numpy()
    return ObjectGaussians(means, peak, camera, moves, sets, radius)


def object_set(
    means: np.ndarray, opacity: np.ndarray, view: TrackView, K: np.ndarray, radius: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """(Bool [N]: the Gaussians that draw the object in ``view`` (module docstring); bool [N]:
    those of them behind the true object, which only the model's drawn depth admits)."""
    cam = to_camera(means, view.c2w)
    px = np.floor(to_pixels(cam, K)).astype(np.int64)
    h, w = view.mask.shape
    inside = (cam[:, 2] > MIN_DEPTH) & (px[:, 0] >= 0) & (px[:, 0] < w)
    inside &= (px[:, 1] >= 0) & (px[:, 1] < h)
    rows, cols = np.where(inside, px[:, 1], 0), np.where(inside, px[:, 0], 0)
    gt_depth = view.depth[rows, cols]
    tolerance = radius if radius is not None else DEPTH_TOLERANCE * gt_depth
    near = cam[:, 2] <= gt_depth + tolerance
    deepest = gt_depth + tolerance
    if view.drawn_depth is not None:
        deepest = np.maximum(deepest, (1 + DEPTH_TOLERANCE) * view.drawn_depth[rows, cols])
    on_object = view.mask[rows, cols] & (gt_depth > 0) & (cam[:, 2] <= deepest)
    chosen = inside & on_object & (opacity >= OPACITY_MIN)
    return chosen, chosen & ~near


def object_sets(
    means: np.ndarray,
    opac: np.ndarray,
    moves: np.ndarray,
    views: Sequence[TrackView],
    K: np.ndarray,
    radius: float | None,
) -> np.ndarray:
    """Bool [J,N]: each test time's object set (``object_set``), less the background that the
    object passed in front of (module docstring, "The object's Gaussians"); ``moves`` [N] is
    ``max_displacement_px`` from the mean test camera."""
    found = [object_set(means[k], opac[k], view, K, radius) for k, view in enumerate(views)]
    sets, behind = (np.stack(f) for f in zip(*found))
    seen = np.array([bool(v.mask.any()) for v in views])
    still = moves < STILL_PX
    drawn_off = ((opac >= OPACITY_MIN) & seen[:, None] & ~sets).any(axis=0)
    passed = behind.any(axis=0) & (sets.sum(axis=0) == 1) & still & drawn_off
    return sets & ~passed


def centroid(mask: np.ndarray) -> np.ndarray:
    """Centroid (x, y; pixel centres at +0.5) of a non-empty bool image ``[H,W]``."""
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean() + 0.5, rows.mean() + 0.5])


@torch.no_grad()
def track_region(renderer: Renderer, views: Sequence[TrackView], found: ObjectGaussians) -> dict:
    """The region error (module docstring): per test time, the pixel distance between the
    centroid of what the object Gaussians (``found``'s sets' union) draw and the GT mask's
    centroid (None: object out of view; inf: not drawn), and the median over the times with the
    object in view."""
    members = found.sets.any(axis=0)
    feature = torch.from_numpy(members.astype(np.float32))[:, None]
    per_time = []
    for view in views:
        area = float(view.mask.sum())
        error = None
        if area > 0:
            out = renderer.render(view.time_us, view.c2w, extra=feature)
            region = out.shares()[..., 0].double().numpy() >= COVER
            drawn = region.sum() >= REGION_MIN_COVER * area
            truth = centroid(view.mask)
            error = float(np.linalg.norm(centroid(region) - truth)) if drawn else np.inf
        per_time.append({"time_us": view.time_us, "error_px": error})
    errors = np.array([p["error_px"] for p in per_time if p["error_px"] is not None])
    median = float(np.median(errors)) if errors.size else np.inf
    for p in per_time:  # JSON has no infinity: not drawn is written as such
        if p["error_px"] == np.inf:
            p["error_px"], p["not_drawn"] = None, True
    return {
        "per_time": per_time,
        "error_px_median": median if np.isfinite(median) else None,
        "in_view": int(errors.size),
        "not_drawn": int(np.isinf(errors).sum()),
        "members": int(members.sum()),
    }


def path_length(px: np.ndarray) -> float:
    """Length in pixels of a polyline ``[J,2]``."""
    return float(np.linalg.norm(np.diff(px, axis=0), axis=-1).sum())


def percentiles(values: np.ndarray) -> dict:
    """{"n", "p50", "p90", "p99"} of ``values`` (None for each when empty)."""
    out: dict = {"n": int(values.size)}
    for q in PERCENTILES:
        out[f"p{q}"] = float(np.percentile(values, q)) if values.size else None
    return out


def max_displacement_px(means: np.ndarray, camera: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Per Gaussian [N]: the largest pixel distance, seen from ``camera``, between its centre at
    a test time and its time-mean centre."""
    centre = means.mean(axis=0)
    offsets = project(means, camera, K) - project(centre, camera, K)[None]
    return np.linalg.norm(offsets, axis=-1).max(axis=0)


def follow(
    k: int, chosen: np.ndarray, means: np.ndarray, peak: np.ndarray, views: Sequence[TrackView]
) -> tuple[np.ndarray, np.ndarray] | None:
    """(the predicted object path p_k [J,3] of reference ``k``'s object set ``chosen`` [N]
    bool; the path by the set's rigid motion [J,3]), or None when the set is weightless."""
    weights = peak[chosen]
    if float(weights.sum()) <= 0.0:
        return None
    centres = weighted_median(means[:, chosen], weights)
    rigid = rigid_transport(means[:, chosen], weights, k, views[k].centre)
    return centres - (centres[k] - views[k].centre), rigid


def rigid_transport(
    means: np.ndarray, weights: np.ndarray, k: int, start: np.ndarray
) -> np.ndarray:
    """The point ``start`` [3] carried from time ``k`` through every time by the weighted
    least-squares rigid motion (Kabsch) of the set ``means`` [J,M,3], weights [M]: [J,3]. A
    set with fewer than three members only translates (its weighted mean)."""
    w = weights / weights.sum()
    mu = np.einsum("m,jmc->jc", w, means)
    if means.shape[1] < 3:
        return start - mu[k] + mu
    a = means[k] - mu[k]
    out = np.empty_like(mu)
    for j in range(len(means)):
        cov = (w[:, None] * (means[j] - mu[j])).T @ a  # [3,3], target x source
        u, _, vt = np.linalg.svd(cov)
        fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])  # a rotation, no reflection
        out[j] = u @ fix @ vt @ (start - mu[k]) + mu[j]
    return out


def weighted_median(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-coordinate weighted median ``[J,3]`` of ``points`` ``[J,M,3]`` with ``weights``
    ``[M]`` (positive total): the smallest value whose cumulative weight reaches half."""
    order = np.argsort(points, axis=1, kind="stable")
    cumulative = np.cumsum(weights[order], axis=1)
    half = 0.5 * cumulative[:, -1:, :]
    first = np.argmax(cumulative >= half, axis=1)[:, None, :]
    return np.take_along_axis(np.take_along_axis(points, order, axis=1), first, axis=1)[:, 0]


def track_object(renderer: Renderer, views: Sequence[TrackView], found: ObjectGaussians) -> dict:
    """Tracking error, path ratio and |Δx| distribution (module docstring) as a JSON-able dict,
    of the object sets ``found``.

    ``paths`` holds each reference's predicted object path p_k(t_j) (world, metres) for plots;
    a reference whose object set is empty (object out of view, nothing drawn there) has n = 0
    and takes no part.
    """
    K = renderer.K.double().numpy()
    times = [v.time_us for v in views]
    gt = np.stack([v.centre for v in views])
    means, peak, camera, moves = found.means, found.peak, found.camera, found.moves
    sets = found.sets
    gt_path = path_length(project(gt, camera, K))
    errors = np.full((len(views), len(views)), np.nan)  # [reference k, time j]
    rigid_errors = errors.copy()
    paths, pred_paths = [], []
    for k, view in enumerate(views):
        followed = follow(k, sets[k], means, peak, views)
        if followed is None:
            paths.append({"reference_us": view.time_us, "n": 0, "centres": None})
            continue
        pred, rigid = followed
        for j, other in enumerate(views):
            if j != k:
                truth = project(gt[j], other.c2w, K)
                errors[k, j] = float(np.linalg.norm(project(pred[j], other.c2w, K) - truth))
                rigid_errors[k, j] = float(np.linalg.norm(project(rigid[j], other.c2w, K) - truth))
        pred_paths.append(path_length(project(pred, camera, K)))
        paths.append(
            {"reference_us": view.time_us, "n": int(sets[k].sum()), "centres": pred.tolist()}
        )
    in_object = sets.any(axis=0)
    visible = (to_camera(means.mean(axis=0), camera)[:, 2] > MIN_DEPTH) & (peak >= OPACITY_MIN)
    pairs = errors[np.isfinite(errors)]
    rigid_pairs = rigid_errors[np.isfinite(rigid_errors)]
    pred_path = float(np.median(pred_paths)) if pred_paths else None
    return {
        "per_time": [
            {"time_us": t, "error_px": _nan_median(errors[:, j]), "centre": gt[j].tolist()}
            for j, t in enumerate(times)
        ],
        "error_px_median": float(np.median(pairs)) if pairs.size else None,
        "error_px_mean": float(np.mean(pairs)) if pairs.size else None,
        "rigid_error_px_median": float(np.median(rigid_pairs)) if rigid_pairs.size else None,
        "gt_path_px": gt_path,
        "pred_path_px": pred_path,
        "path_ratio": pred_path / gt_path if pred_path is not None and gt_path > 0 else None,
        "dx_px": {
            "object": percentiles(moves[in_object]),
            "other": percentiles(moves[visible & ~in_object]),
        },
        "radius": found.radius,
        "paths": paths,
    }


def _nan_median(values: np.ndarray) -> float | None:
    """Median of the finite entries, None when there is none."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else None
