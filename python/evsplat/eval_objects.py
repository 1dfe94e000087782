"""`evsplat eval` per moving object: each object's PSNR on its own mask beside a flat grey
image's, its tracking (``evsplat.motion_metrics``: region error, Gaussians followed, path
ratio) with its own mask, centre and radius (test/frames.json ``objects``, docs/dataset.md), and
its segmentation: the IoU of its mask with the pixels of the object the run found for it
(``segmentation``).

A dataset with one tracked object (written before per-object ground truth) is one object whose
mask is the moving-object mask, so its numbers are those of the single-object evaluation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from evsplat.data.images import read_exr, read_png
from evsplat.metrics import psnr
from evsplat.motion_metrics import TrackView, object_gaussians, track_object, track_region
from evsplat.object_output import object_count, object_labels

if TYPE_CHECKING:
    from evsplat.data.dataset import Dataset
    from evsplat.data.ground_truth import FrameObject
    from evsplat.render import Renderer


def mask2d(mask: np.ndarray | None) -> np.ndarray | None:
    """A mask as [H,W] bool (a colour PNG mask has one channel per colour)."""
    return mask[..., 0] if mask is not None and mask.ndim == 3 else mask


def object_mask(obj: FrameObject) -> np.ndarray:
    """An object's [H,W] bool mask at a test frame (test/frames.json ``objects``)."""
    return mask2d(read_png(obj.mask_path) > 0.5)


def unscored(data: Dataset) -> str | None:
    """Why the dataset's moving objects cannot be scored, None where they can."""
    frames = data.test_frames
    if not frames or any(not f.objects for f in frames):
        return "the dataset gives no object_centre per test frame (docs/dataset.md)"
    if any(o.mask_path is None for f in frames for o in f.objects):
        return "the dataset gives no moving-object mask per test frame"
    return None


def object_views(
    data: Dataset, drawn_depths: list[np.ndarray] | None = None
) -> tuple[list[tuple[str, list[TrackView]]] | None, str | None]:
    """Per moving object, its name and the test frames as its tracking views (with the model's
    rendered depth of each, when given); or None and why tracking is not reported."""
    why = unscored(data)
    if why is not None:
        return None, why
    frames = data.test_frames
    depths = [read_exr(f.depth_path) for f in frames]
    out = []
    for k, obj in enumerate(frames[0].objects):
        views = [
            TrackView(
                f.time_us,
                f.c2w,
                object_mask(f.objects[k]),
                depth,
                f.objects[k].centre,
                None if drawn_depths is None else drawn_depths[j],
            )
            for j, (f, depth) in enumerate(zip(frames, depths))
        ]
        out.append((obj.name, views))
    return out, None


def pooled_margin(
    ours: list[np.ndarray], flat: list[np.ndarray], gts: list[np.ndarray], masks: list[np.ndarray]
) -> float | None:
    """PSNR of ``ours`` less that of ``flat`` against ``gts``, each over the pixels of ``masks``
    pooled over the frames (one squared error per pixel, every pixel counted once); None where
    no mask holds a pixel."""
    if not any(m.any() for m in masks):
        return None
    truth = np.concatenate([g[m] for g, m in zip(gts, masks)])
    scored = [np.concatenate([im[m] for im, m in zip(ims, masks)]) for ims in (ours, flat)]
    return psnr(scored[0], truth) - psnr(scored[1], truth)


def frame_labels(renderer: Renderer, data: Dataset) -> list[np.ndarray]:
    """The found objects' labels (``object_output.object_labels``) at each test frame: the
    eval's IoU and its picture read the same ones (no render where the run has no objects)."""
    return [object_labels(renderer, f.time_us, f.c2w) for f in data.test_frames]


def segmentation(
    renderer: Renderer, views_by_object: list[list[TrackView]], labels: list[np.ndarray]
) -> list[dict]:
    """Per true object (its test views, each with its mask), the found object it is matched to
    and their IoU per test time it is in view and its mean. A found object's pixels are its
    ``labels`` there (``frame_labels``, one per view); true and found objects are matched one to
    one (Hungarian) on that mean, so a found object that draws two true ones counts for one of
    them, and a true object left without one (``object`` None) scores 0."""
    found = object_count(renderer)
    iou = np.zeros((len(views_by_object), found, len(labels)))
    for j, object_views in enumerate(views_by_object):
        for f, (view, drawn) in enumerate(zip(object_views, labels)):
            for k in range(found):
                mine = drawn == k + 1
                union = (mine | view.mask).sum()
                iou[j, k, f] = (mine & view.mask).sum() / union if union else 0.0
    seen = np.array([[v.mask.any() for v in vs] for vs in views_by_object])  # [J,F]
    # [J,K]: each pair's IoU, mean over the times the true object is in view
    mean = np.stack(
        [iou[j][:, s].mean(axis=1) if s.any() else np.zeros(found) for j, s in enumerate(seen)]
    )
    rows, cols = linear_sum_assignment(mean, maximize=True) if found else ([], [])
    match = {int(j): int(k) for j, k in zip(rows, cols) if mean[j, k] > 0}
    out = []
    for j, object_views in enumerate(views_by_object):
        k = match.get(j)
        per_time = [
            {"time_us": v.time_us, "iou": None if k is None else float(iou[j, k, f])}
            for f, v in enumerate(object_views)
            if seen[j, f]
        ]
        score = 0.0 if k is None else float(mean[j, k])
        out.append({"object": k, "iou_mean": score, "per_time": per_time})
    return out


def evaluate_objects(
    renderer: Renderer,
    data: Dataset,
    fitted: list[np.ndarray],
    flat: list[np.ndarray],
    gts: list[np.ndarray],
    drawn_depths: list[np.ndarray],
    labels: list[np.ndarray] | None = None,
) -> tuple[list[dict], str | None]:
    """Per moving object (test frames' order): PSNR of the colour-fitted renders ``fitted`` and
    of the flat images ``flat`` against ``gts`` on its mask, mean over the test frames where it
    is seen, their margin, the margin with its mask's pixels pooled over those frames (a frame
    where it shows a few pixels at the border counts by its pixels, not as a whole view), its
    tracking and its segmentation (``labels``: ``frame_labels``, rendered here when not given);
    or [] and why tracking is not reported."""
    views_by_object, why = object_views(data, drawn_depths)
    if views_by_object is None:
        return [], why
    radii = {t.name: t.radius for t in data.tracks}
    labels = frame_labels(renderer, data) if labels is None else labels
    segments = segmentation(renderer, [views for _, views in views_by_object], labels)
    out = []
    for (name, views), segment in zip(views_by_object, segments):
        seen = [k for k, v in enumerate(views) if v.mask.any()]
        ours = [psnr(fitted[k], gts[k], views[k].mask) for k in seen]
        theirs = [psnr(flat[k], gts[k], views[k].mask) for k in seen]
        mean, mean_flat = (float(np.mean(v)) if v else None for v in (ours, theirs))
        pooled = pooled_margin(fitted, flat, gts, [v.mask for v in views])
        radius = radii.get(name)
        found = object_gaussians(renderer, views, radius)
        tracking = track_object(renderer, views, found)
        out.append(
            {
                "name": name,
                "in_view": len(seen),
                "psnr_moving": mean,
                "psnr_moving_flat": mean_flat,
                "psnr_moving_margin": None if mean is None else mean - mean_flat,
                "psnr_moving_margin_pooled": pooled,
                "tracking": tracking | {"region": track_region(renderer, views, found)},
                "segmentation": segment,
            }
        )
    return out, None


def _fmt(v: float | None, nd: int, sign: bool = False) -> str:
    if v is None:
        return "missing"
    return f"{v:+.{nd}f}" if sign else f"{v:.{nd}f}"


def object_table(objects: list[dict]) -> list[str]:
    """Markdown: one row per object, its mask PSNR beside the flat image's and the margin (per
    image fit), the margin with the mask's pixels pooled, its region error (median px), test
    times not drawn, its path ratio, the found object matched to it and their mask IoU."""
    lines = [
        "| object | test times in view | PSNR on its mask | flat | margin | margin, pixels pooled "
        "| track err (px) | not drawn | path ratio | found as | mask IoU |",
        "|---" + "|---:" * 10 + "|",
    ]
    for o in objects:
        tr, region = o["tracking"], o["tracking"]["region"]
        cells = [
            o["name"],
            str(o["in_view"]),
            _fmt(o["psnr_moving"], 2),
            _fmt(o["psnr_moving_flat"], 2),
            _fmt(o["psnr_moving_margin"], 2, sign=True),
            _fmt(o["psnr_moving_margin_pooled"], 2, sign=True),
            _fmt(region["error_px_median"], 2),
            str(region["not_drawn"]),
            _fmt(tr["path_ratio"], 3),
            "none" if o["segmentation"]["object"] is None else str(o["segmentation"]["object"]),
            _fmt(o["segmentation"]["iou_mean"], 3),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def worst_object_headline(objects: list[dict]) -> str:
    """One line for several objects: the one with the smallest mask margin over the flat image,
    then each object's region error and path ratio, then its mask IoU with the found object
    matched to it ("none": no found object is left for it)."""
    scored = [o for o in objects if o["psnr_moving_margin"] is not None]
    parts = [f"{len(objects)} moving objects"]
    if scored:
        w = min(scored, key=lambda o: o["psnr_moving_margin"])
        parts.append(
            f"worst on its mask: '{w['name']}' PSNR {w['psnr_moving']:.2f} dB vs "
            f"{w['psnr_moving_flat']:.2f} dB for a flat image ({w['psnr_moving_margin']:+.2f})"
        )
    each = ", ".join(
        f"{o['name']} {_fmt(o['tracking']['region']['error_px_median'], 1)} px / "
        f"{_fmt(o['tracking']['path_ratio'], 2)}"
        for o in objects
    )
    parts.append(f"tracking (region error / path ratio): {each}")
    matched = ", ".join(
        f"{o['name']} {_fmt(o['segmentation']['iou_mean'], 2)}"
        if o["segmentation"]["object"] is not None
        else f"{o['name']} none"
        for o in objects
    )
    parts.append(f"mask IoU with the object found for it: {matched}")
    return "; ".join(parts)
