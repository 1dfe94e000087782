"""Motion segmentation (docs/motion.md, step 1): per short window, the pixels whose events the
static model does not explain, split into moving regions of any number and shape; thresholds in
the residual's own robust spread (nothing here knows a scene's contrast, size or objects)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch.nn.functional as F
from scipy import ndimage
from torch import Tensor

from evsplat.config import MoverConfig

EPS = 1e-12  # guards divisions by energies and spreads
MAD_TO_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation
# A longer window's region this x its and a short region's radii off that one's centre is
# another object, nearer its other edge: `enter_leave` seed 3's slow box is one object at 1.3 px
# with it, two at 8.4 px without (`evsplat bench seeding`, 2026-12-03).
SEPARATE = 2.0


@dataclass
class Blob:
    """One moving region in one window."""

    t_us: int  # the window's middle time
    centre: np.ndarray  # [2] (x, y) px, residual-weighted
    mask: np.ndarray  # [H,W] bool, the closed region
    area: float  # px
    contrast: float  # the region's peak residual above the median, in robust sigmas
    parts: tuple[Blob, ...] = ()  # the pieces ``join`` united into it (none: one piece)

    @property
    def radius(self) -> float:
        """The radius (px) of the disc of the region's area."""
        return float(np.sqrt(self.area / np.pi))


def pooled(x: Tensor, pool: int) -> np.ndarray:
    """[H,W] float64 magnitude of ``x`` after ``pool`` px box averaging (stride 1); of [C,H,W],
    the sum of the channels' magnitudes. Of ESI - predicted log change: the residual."""
    x = x.double().reshape(-1, 1, *x.shape[-2:])
    smooth = F.avg_pool2d(x, pool, stride=1, padding=pool // 2, count_include_pad=False)
    return smooth.abs().sum((0, 1))[: x.shape[-2], : x.shape[-1]].cpu().numpy()


def made_by_events(
    blobs: list[Blob], esi: Tensor, predicted: Tensor, pool: int, share: float
) -> list[Blob]:
    """The ``blobs`` over which the ``esi``'s magnitude (``pooled``) sums to at least ``share`` of
    the ``predicted`` log change's: a change the render draws where no event fired is the model's
    own error, which training mends, not a mover."""
    if not blobs:
        return blobs
    events, drawn = pooled(esi, pool), pooled(predicted, pool)
    return [b for b in blobs if events[b.mask].sum() >= share * drawn[b.mask].sum()]


def apart(more: list[Blob], found: list[Blob]) -> list[Blob]:
    """The regions ``more`` (a longer window's) that overlap none of ``found`` (the short
    window's about the same middle, before ``made_by_events``) and lie over ``SEPARATE`` x the two
    radii from each one's centre: what only the longer window shows, as over it an object smears
    and a slow one fires at both edges where the short window sees one. Two of them within that
    of each other are such edges of one object, united."""
    out: list[Blob] = []
    for b in more:
        if any((b.mask & f.mask).any() or _near(b, f) for f in found):
            continue
        j = next((j for j, o in enumerate(out) if _near(b, o)), None)
        if j is None:
            out.append(b)
        else:
            out[j] = union(out[j], b)
    return out


def _near(a: Blob, b: Blob) -> bool:
    """Whether ``a``'s and ``b``'s centres lie within ``SEPARATE`` x their summed radii."""
    return bool(np.hypot(*(a.centre - b.centre)) <= SEPARATE * (a.radius + b.radius))


def union(a: Blob, b: Blob) -> Blob:
    """One region of two pieces of one object in one window."""
    centre = (a.area * a.centre + b.area * b.centre) / (a.area + b.area)
    return Blob(a.t_us, centre, a.mask | b.mask, a.area + b.area, max(a.contrast, b.contrast))


def robust(x: np.ndarray) -> tuple[float, float]:
    """(median, robust sigma) of ``x``: the sigma from the median absolute deviation, which a
    few wild values do not move."""
    median = float(np.median(x))
    return median, MAD_TO_SIGMA * float(np.median(np.abs(x - median)))


def floor(c_pos: float, c_neg: float, pool: int) -> float:
    """The least robust sigma the residual is measured in: one event's log step over a ``pool``
    px box (under a still camera the background's MAD is zero, and any trace of an event would
    pass the thresholds)."""
    return 0.5 * (c_pos + c_neg) / pool**2


def blurred(residual: np.ndarray, blur_px: float) -> np.ndarray:
    """The residual with an object's edge events spread over its body (Gaussian, ``blur_px``
    sigma; none at 0)."""
    return ndimage.gaussian_filter(residual, blur_px) if blur_px > 0 else residual


def regions(residual: np.ndarray, t_us: int, s: MoverConfig, least: float = 0.0) -> list[Blob]:
    """The moving regions of one window's ``residual`` [H,W], largest first; ``least``: the
    least robust sigma (``floor``)."""
    energy = blurred(residual, s.blur_px)
    med, spread = robust(energy)
    sigma = max(spread, EPS, least)
    hot = energy > med + s.low * sigma
    if s.close_px > 0:
        pad = s.close_px  # padded so regions touching the border are not eroded away
        r = np.arange(-pad, pad + 1)
        disc = (r[:, None] ** 2 + r[None, :] ** 2) <= pad**2
        grown = ndimage.binary_closing(np.pad(hot, pad, mode="edge"), structure=disc)
        hot = ndimage.binary_fill_holes(grown)[pad:-pad, pad:-pad]
    labels, count = ndimage.label(hot, structure=np.ones((3, 3), dtype=bool))
    peak = np.full(count + 1, -np.inf)  # per label, in one pass (ndimage.maximum sorts the image)
    np.maximum.at(peak, labels.ravel(), energy.ravel())
    area = np.bincount(labels.ravel(), minlength=count + 1)
    kept = [
        (labels == k, float((peak[k] - med) / sigma))
        for k in range(1, count + 1)
        if area[k] >= s.min_area_px and peak[k] >= med + s.high * sigma
    ]
    blobs = []
    for mask, c, pieces in _joined(kept, s.join):
        parts = tuple(_blob(m, energy * m, t_us, pc) for m, pc in pieces) if len(pieces) > 1 else ()
        blobs.append(replace(_blob(mask, energy * mask, t_us, c), parts=parts))
    return sorted(blobs, key=lambda b: -b.area)


def _joined(pieces: list[tuple[np.ndarray, float]], join: float) -> list[tuple]:
    """The pieces (mask, contrast) with those of one object united (a sparse texture's events
    fall apart): two are one where their gap is under ``join`` x the larger one's radius; each
    (mask, contrast, the pieces united in it)."""
    parts, i = [(m, c, [(m, c)]) for m, c in pieces], 0
    while i < len(parts):
        mask = parts[i][0]
        reach = ndimage.distance_transform_edt(~mask)
        gap = [reach[m].min() / np.sqrt(max(mask.sum(), m.sum()) / np.pi) for m, _, _ in parts]
        j = next((j for j in range(i + 1, len(parts)) if gap[j] <= join), None)
        if j is None:
            i += 1
            continue
        merged = (mask | parts[j][0], max(parts[i][1], parts[j][1]), parts[i][2] + parts[j][2])
        parts, i = [p for k, p in enumerate(parts) if k not in (i, j)] + [merged], 0
    return parts


def _blob(mask: np.ndarray, weight: np.ndarray, t_us: int, contrast: float) -> Blob:
    """The region ``mask`` as a Blob, its centre weighted by the residual ``weight``."""
    ys, xs = np.nonzero(mask)
    w = weight[ys, xs] / max(float(weight[ys, xs].sum()), EPS)
    centre = np.array([float((w * (xs + 0.5)).sum()), float((w * (ys + 0.5)).sum())])
    return Blob(t_us, centre, mask, float(mask.sum()), contrast)
