"""The mover's image path from the events the static model leaves unexplained (not in the
paper): per short window, the centre of the unexplained event energy (a blob) and the circle its
outline draws, chained into one path over the sequence (see ``find_path``). ``evsplat.train.mover``
lifts it to 3-D and places Gaussians on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from evsplat.config import MoverConfig

EPS = 1e-12  # guards divisions by energies
CAP_QUANTILE = 0.95  # see locate
RING_WIDTH = 1.0  # px, half-width of the rings of fit_rings
RING_COVER = 0.4  # least share of a ring inside the image (a mover cut by the border)
# The border fit (``ring_scores(border=True)``): a ring needs only this share inside the image
# and scores by its visible length, so a mover mostly outside the image is fitted where its
# arc is (the cover-0.4 fit pushed it 15-40 px inwards; docs/results.md, session 17).
BORDER_COVER = 0.2
RING_RADII = 25  # radii tried by fit_rings
RING_CAP = 0.98  # measured: 0.9 and 0.95 let the radius run away in some seeds (results.md)
# Adjacent windows agree when their centres lie within this many mover radii: the tiny ball
# moves up to 0.4 radii per window, and the fits that miss it land 0.7-2 radii off.
AGREE = 0.5
# The circle agrees with the blob within this many blob radii: measured, on the ball in 81-89%
# of the windows, on the butterfly 19%, on the duck none (docs/results.md).
RING_AGREE = 0.75
LOCATE_STEPS = 8  # mean-shift steps of a blob (on the ball, more drift into the background)
CONVERGED = 50  # mean-shift steps of a blob that is not round: converged by 30 (results.md)
BIWEIGHT = 4.685  # smooth_track's outlier scale in robust sigmas (Tukey's biweight constant)


@dataclass
class MoverPath:
    """The mover's image path: per window middle time, its pixel centre and disc radius."""

    times_us: np.ndarray  # [K] int64
    uv: np.ndarray  # [K,2] float64, pixel centres (x, y)
    radius_px: np.ndarray  # [K]
    contrast: np.ndarray  # [K] unexplained energy inside the disc over the image's mean
    found: np.ndarray  # [K] bool: seen (prefer_ring) and an adjacent window agrees (connected)
    round: bool = False  # the path is the circles' (prefer_ring): the mover looks like a disc

    def at(self, t_us: np.ndarray) -> np.ndarray:
        """[T,2] pixel centres at ``t_us``, linear between the found windows (held at ends)."""
        return interp_rows(t_us, self.times_us[self.found], self.uv[self.found])

    def reference(self, width: int, height: int) -> int:
        """The window to place the mover at: the clearest found one whose disc, at the found
        windows' median radius, lies inside the image, else the clearest. A mover cut by the
        border looks smaller and off-centre, so its own shrunken radius would pass the test
        (the corner window of the demo did: a mover of 13 px for a 20-px ball)."""
        r = float(np.median(self.radius_px[self.found])) if self.found.any() else 0.0
        inside = disc_inside(self.uv, r, width, height)
        pick = self.found & inside if bool((self.found & inside).any()) else self.found
        return int(np.argmax(np.where(pick, self.contrast, -np.inf)))


def disc_inside(uv: np.ndarray, radius: float, width: int, height: int) -> np.ndarray:
    """Bool [K]: the discs of ``radius`` px at pixel centres ``uv`` [K,2] lie inside the image."""
    u, v = uv.T
    return (u - radius >= 0) & (v - radius >= 0) & (u + radius <= width) & (v + radius <= height)


def interp_rows(q: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` [T,D] linear in sorted ``t`` [T] at ``q`` -> [Q,D], held beyond the ends."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    t = np.asarray(t, dtype=np.float64)
    return np.stack([np.interp(q, t, values[:, k]) for k in range(values.shape[1])], axis=1)


def pooled(energy: Tensor, pool: int) -> Tensor:
    """[H,W]: ``energy`` averaged over ``pool`` px boxes (stride 1), then its magnitude; a
    [C,H,W] input sums its channels."""
    x = energy.double().reshape(-1, 1, *energy.shape[-2:])
    smooth = F.avg_pool2d(x, pool, stride=1, padding=pool // 2, count_include_pad=False)
    return smooth.abs().sum((0, 1))[: energy.shape[-2], : energy.shape[-1]]


def unexplained(esi: Tensor, pred: Tensor, pool: int) -> Tensor:
    """[H,W] residual |ESI - predicted log change| of the static model, both first averaged over
    ``pool`` px boxes (stride 1) so the ESI's steps of C average out (``pooled``)."""
    return pooled(esi - pred, pool)


@dataclass
class _Blob:
    """A mean shift in progress on one energy map (``locate``): its centre (x, y) and radius in
    pixels, and the map's median and high quantile (the weights' floor and cap)."""

    cx: float
    cy: float
    radius: float
    floor: float
    cap: float


def _blob_start(e: Tensor) -> _Blob:
    """The mean shift's start on ``e`` [H,W] (float64, >= 0): its strongest region."""
    h, w = e.shape
    side = max(3, (min(h, w) // 8) | 1)
    k = int(torch.argmax(_box_sums(e, side)))
    # Energy above the image's median, capped at a high quantile so a mover's few strongest
    # edges (a seam of saturated colours) do not pull the centre off its outline.
    floor, cap = (
        float(q) for q in torch.quantile(e.float().reshape(-1), torch.tensor([0.5, CAP_QUANTILE]))
    )
    return _Blob(k % w + 0.5, k // w + 0.5, float(side), floor, cap)


def _box_sums(e: Tensor, side: int) -> Tensor:
    """[H,W]: the sum of ``e`` [H,W] over the ``side`` x ``side`` square (odd ``side``) around
    each pixel, zero outside the image, from one summed-area table (a direct box filter cost
    0.32 s a window at 400x400 with side 51: 16 s of the mover's 114 s seeding there)."""
    r = side // 2
    table = F.pad(e, (r + 1, r, r + 1, r)).cumsum(0).cumsum(1)
    return table[side:, side:] - table[:-side, side:] - table[side:, :-side] + table[:-side, :-side]


def _blob_weight(e: Tensor, b: _Blob) -> Tensor:
    return (e - b.floor).clamp(0.0, max(b.cap - b.floor, EPS))


def _pixel_centres(h: int, w: int) -> tuple[Tensor, Tensor]:
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64) + 0.5,
        torch.arange(w, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    return xs, ys


def _shift(e: Tensor, b: _Blob, iterations: int) -> None:
    """``iterations`` more mean-shift steps of ``b`` on ``e``, the radius following the
    energy's radius of gyration."""
    h, w = e.shape
    xs, ys = _pixel_centres(h, w)
    weight = _blob_weight(e, b)
    for _ in range(iterations):
        d2 = (xs - b.cx) ** 2 + (ys - b.cy) ** 2
        inside = weight * (d2 <= (1.5 * b.radius) ** 2)
        total = float(inside.sum())
        if total <= EPS:
            break
        b.cx = float((inside * xs).sum()) / total
        b.cy = float((inside * ys).sum()) / total
        gyration = math.sqrt(float((inside * d2).sum()) / total)
        b.radius = min(max(1.2 * gyration, 2.0), 0.5 * min(h, w))


def _blob_found(e: Tensor, b: _Blob) -> tuple[np.ndarray, float, float]:
    """``locate``'s answer for ``b`` on ``e``: centre, radius and contrast."""
    xs, ys = _pixel_centres(*e.shape)
    weight = _blob_weight(e, b)
    disc = (xs - b.cx) ** 2 + (ys - b.cy) ** 2 <= b.radius**2
    contrast = float(weight[disc].mean()) / max(float(weight.mean()), EPS)
    return np.array([b.cx, b.cy]), b.radius, contrast


def locate(energy: Tensor, iterations: int = LOCATE_STEPS) -> tuple[np.ndarray, float, float]:
    """(centre [2] (x, y) in pixel coordinates, radius px, contrast) of the main blob of
    ``energy [H,W]``: mean shift from its strongest region, with a radius that grows or shrinks
    to hold the blob's energy (the radius of gyration of a disc's mass is r/√2, of a ring r).
    Contrast is the mean (capped) energy inside the disc over the image's mean."""
    e = energy.double().clamp_min(0.0)
    b = _blob_start(e)
    _shift(e, b, iterations)
    return _blob_found(e, b)


def find_path(
    residual_of: Callable[[int, int], Tensor],
    t_start_us: int,
    t_end_us: int,
    cfg: MoverConfig,
    converge: bool = True,
    allowed: Callable[[int, int], bool] = lambda t0, t1: True,
) -> MoverPath:
    """The mover's path from ``cfg.windows`` evenly spread windows of ``cfg.window`` of the
    sequence; ``residual_of(t0, t1)`` is the unexplained event energy [H,W] of [t0, t1).
    ``converge``: a mover that is not round takes its blobs' converged centres (below); False
    keeps their first steps' (raw event counts, where a longer run drifts into the
    background's own events).

    Each window's blob (``locate``) says whether the mover is there (its contrast); its place
    and size come from the circle its outline draws (``fit_rings``, one radius for the whole
    sequence) when the mover is round (``prefer_ring``):
    the blob's centre of energy is pulled off a round mover by its strongest seams and by the
    background's leftovers, and a mover cut by the border has its visible part's centre
    (docs/results.md, session 15). Otherwise the blobs' centres, their mean shift run to
    convergence and the path smoothed in time (``smooth_track``, session 26)."""
    duration = t_end_us - t_start_us
    length = max(int(cfg.window * duration), 1)
    starts = np.linspace(t_start_us, t_end_us - length, cfg.windows).astype(np.int64)
    starts = starts[[allowed(int(t0), int(t0) + length) for t0 in starts]]  # held out: unread
    maps = torch.stack([residual_of(int(t0), int(t0) + length) for t0 in starts])
    # What the static model misses at a pixel in most windows is the model's own error, not a
    # mover (a mover passes by): the per-pixel median over the windows is taken away.
    maps = (maps - maps.median(dim=0).values).clamp_min(0.0).double()
    blobs = [_blob_start(e) for e in maps]
    for e, b in zip(maps, blobs):
        _shift(e, b, LOCATE_STEPS)
    blob_uv, sizes, contrast = (
        np.array(v) for v in zip(*(_blob_found(e, b) for e, b in zip(maps, blobs)))
    )
    seen = contrast >= cfg.min_contrast
    blob_radius = float(np.median(sizes[seen] if seen.any() else sizes))
    ring_uv, ring_radius, border_uv = fit_rings(maps, blob_radius, seen)
    uv, radius, seen, is_round = prefer_ring(ring_uv, ring_radius, blob_uv, blob_radius, seen)
    step = AGREE * float(radius[0])
    if is_round:
        uv, found = chain_circles(np.stack([ring_uv, border_uv], axis=1), seen, step)
    else:
        # Not round: each blob's mean shift run to convergence. Its first steps stop on the
        # strongest part (one wing of the butterfly, 12 px off its body); on the ball, whose
        # circle is used instead, the longer run drifts into the background's leftovers.
        if converge:
            for e, b in zip(maps, blobs):
                _shift(e, b, CONVERGED - LOCATE_STEPS)
        uv = np.array([[b.cx, b.cy] for b in blobs])
        found = connected(uv, seen, step)
        if cfg.smooth > 0 and found.any():
            uv = smooth_track(starts + length // 2, uv, found, cfg.smooth * duration)
    return MoverPath(
        times_us=starts + length // 2,
        uv=uv,
        radius_px=radius,
        contrast=contrast,
        found=found,
        round=is_round,
    )


def smooth_track(
    t: np.ndarray, uv: np.ndarray, found: np.ndarray, sigma: float, rounds: int = 3
) -> np.ndarray:
    """[K,2]: the ``found`` rows of ``uv`` [K,2] at times ``t`` [K] smoothed by a local linear
    fit (Gaussian weights of ``sigma`` in time), evaluated at every ``t``, with ``rounds`` of
    biweight reweighting so a lone jump does not bend the path. A blob is the centre of the
    unexplained events, not of the mover: an articulated mover (the butterfly's flapping wings)
    moves it by ±10 px a half-beat while the body moves by 2 (docs/results.md, session 26)."""
    ts, ys = t[found].astype(np.float64), uv[found].astype(np.float64)
    dt = ts[None, :] - t.astype(np.float64)[:, None]  # [K,F]
    kernel = np.exp(-0.5 * (dt / max(sigma, EPS)) ** 2)
    weight = np.ones(len(ts))
    for r in range(rounds + 1):
        w = kernel * weight[None, :]
        s0, s1, s2 = w.sum(1), (w * dt).sum(1), (w * dt * dt).sum(1)
        m0, m1 = w @ ys, (w * dt) @ ys  # [K,2]
        det = s0 * s2 - s1 * s1
        ok = det > EPS * np.maximum(s0 * s2, EPS)
        # The local line's value at dt = 0; where the line is not determined, the weighted
        # mean, and the blob itself where no found window weighs in.
        line = (s2[:, None] * m0 - s1[:, None] * m1) / np.where(ok, det, 1.0)[:, None]
        mean = np.where((s0 > EPS)[:, None], m0 / np.maximum(s0, EPS)[:, None], uv)
        fit = np.where(ok[:, None], line, mean)
        if r == rounds:
            break
        miss = np.hypot(*(ys - fit[found]).T)
        scale = BIWEIGHT * max(1.4826 * float(np.median(miss)), 1.0)
        weight = np.clip(1.0 - (miss / scale) ** 2, 0.0, None) ** 2
    return fit


def prefer_ring(
    ring_uv: np.ndarray,
    ring_radius: float,
    blob_uv: np.ndarray,
    blob_radius: float,
    seen: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(centres [N,2], radii [N], seen [N], whether circles were taken): the circles when in
    most ``seen`` windows the circle's centre lies within ``RING_AGREE`` blob radii of the
    blob's (a round mover), the
    windows where they disagree then unseen (the circle took a seam; the blob there is the
    visible part's centre at the image border); else the blobs, as seen. On movers that are no
    circle the fits land 13-25 px off, twice the blob's error (duck, butterfly)."""
    agree = np.hypot(*(ring_uv - blob_uv).T) <= RING_AGREE * blob_radius
    if seen.any() and float(agree[seen].mean()) >= 0.5:
        return ring_uv, np.full(len(ring_uv), ring_radius), seen & agree, True
    return blob_uv, np.full(len(blob_uv), blob_radius), seen, False


def ring_scores(energy: Tensor, radius: float, border: bool = False) -> tuple[Tensor, np.ndarray]:
    """Circle-Hough scores of ``energy`` [N,H,W] for one ``radius``: per window, the best
    score and its centre [N,2] (x, y), centres searched up to one radius outside the image.
    A circle's score is its ring's mean energy over the ring's part inside the image, times
    the square root of the ring's length (the mean alone prefers small circles hugging one
    strong seam, the sum large ones collecting background); a circle with less than
    ``RING_COVER`` of its ring inside the image scores 0. ``border``: the square root of the
    visible length instead, and ``BORDER_COVER`` (see there)."""
    return _best_circles(_ring_sums(energy, radius), border)


@dataclass(frozen=True)
class _RingSums:
    """Every circle's ring sums of one radius: of the energy [N,H',W'], of the image's inside
    (``cover``, [1,H',W']), the full ring's length and the centres' offset ``pad``."""

    total: Tensor
    cover: Tensor
    length: float
    pad: int


def _ring_sums(energy: Tensor, radius: float) -> _RingSums:
    h, w = energy.shape[-2:]
    pad = int(math.ceil(radius)) + 2
    side = 2 * pad + 1
    ys, xs = np.mgrid[0:side, 0:side] - pad
    ring = torch.from_numpy((np.abs(np.hypot(xs, ys) - radius) <= RING_WIDTH).astype(np.float64))
    size = (h + 2 * side, w + 2 * side)  # no wrap-around of the circular convolution
    k = ring.new_zeros(size)
    k[:side, :side] = ring
    ring_hat = torch.fft.rfft2(k)  # shared by the energy's and the cover's convolutions

    def convolve(img: Tensor) -> Tensor:
        a = img.new_zeros(img.shape[0], *size)
        a[:, side : side + h, side : side + w] = img
        out = torch.fft.irfft2(torch.fft.rfft2(a) * ring_hat, s=size)
        # out[side + pad + y] sums the ring around image row y (pad: the kernel's centre).
        return out[:, side : side + h + 2 * pad, side : side + w + 2 * pad]

    cover = convolve(torch.ones(1, h, w, dtype=torch.float64))
    return _RingSums(convolve(energy.double()), cover, float(ring.sum()), pad)


def _best_circles(sums: _RingSums, border: bool) -> tuple[Tensor, np.ndarray]:
    """``ring_scores``' best score and centre per window, from its ring sums."""
    total, cover, length = sums.total, sums.cover, sums.length
    least, scale = RING_COVER, math.sqrt(length)
    if border:
        least, scale = BORDER_COVER, cover.clamp_min(0.0).sqrt()
    score = torch.where(
        cover >= least * length, total / cover.clamp_min(EPS) * scale, torch.zeros_like(total)
    )
    best, k = score.reshape(len(total), -1).max(dim=1)
    cols = score.shape[-1]
    k = k.numpy()
    centre = np.stack([k % cols - sums.pad + 0.5, k // cols - sums.pad + 0.5], axis=1)
    return best, centre


def fit_rings(
    maps: Tensor, blob_radius: float, seen: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray]:
    """(centres [N,2], radius px, border centres [N,2]) of the mover's outline in each of
    ``maps`` [N,H,W], each capped at its ``RING_CAP`` quantile (a seam's few brightest pixels
    would outweigh the outline): the radius best over the windows ``seen`` (median of each
    one's best, radii from 0.3 to 1.5 x the blobs' ``blob_radius``), then each window's best
    centre at that radius, and its best by the border fit (``ring_scores(border=True)``).
    Only the windows seen are searched over radii (each window's scores are its own)."""
    h, w = maps.shape[-2:]
    flat = maps.reshape(len(maps), -1).float()
    cap = torch.quantile(flat, RING_CAP, dim=1).to(maps.dtype)[:, None, None]
    maps = torch.minimum(maps, cap)
    hi = min(1.5 * blob_radius, 0.5 * max(h, w))
    radii = np.linspace(max(0.3 * blob_radius, 2.0), max(hi, 2.0), RING_RADII)
    rows = seen if seen.any() else np.ones(len(maps), dtype=bool)
    searched = maps[torch.from_numpy(rows)]
    scores = torch.stack([ring_scores(searched, float(r))[0] for r in radii], dim=1)  # [S,R]
    radius = float(np.median(radii[scores.argmax(dim=1).numpy()]))
    sums = _ring_sums(maps, radius)
    return _best_circles(sums, False)[1], radius, _best_circles(sums, True)[1]


def chain_circles(
    candidates: np.ndarray, seen: np.ndarray, step: float, min_windows: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """(centres [K,2], found [K]) of a round mover from per-window ``candidates`` [K,C,2]
    (circle fits) by chains: runs of consecutive windows whose chosen centres move by at most
    ``step`` px per window, or by at most ``step`` px from the chain's constant-velocity
    prediction. The longest chain is taken first (ties: the smoothest, least
    change of velocity), its windows removed, and so on; a chain counts when it is at least
    ``min_windows`` long and holds a window ``seen`` by its contrast. This keeps the windows
    whose contrast is low but whose circle continues the path (the ball near its apex, or
    half out of the image), and drops a lone fit to the background's leftovers or a corner
    fit squeezed inside the image by its cover (docs/results.md, session 17)."""
    k_n, c_n = candidates.shape[:2]
    free = np.ones(k_n, dtype=bool)
    uv = candidates[:, 0].copy()
    found = np.zeros(k_n, dtype=bool)
    while True:
        length = np.zeros((k_n, c_n), dtype=np.int64)
        bend = np.zeros((k_n, c_n))
        back = np.full((k_n, c_n), -1, dtype=np.int64)
        for k in range(k_n):
            if not free[k]:
                continue
            length[k] = 1
            if k == 0 or not free[k - 1]:
                continue
            for c in range(c_n):
                for b in range(c_n):
                    move = candidates[k, c] - candidates[k - 1, b]
                    a = back[k - 1, b]
                    # A link moves by at most `step`, or continues the chain's velocity to
                    # within `step` (a fast mover moves more than `step` a window).
                    turn = 0.0
                    if a >= 0:
                        vel = candidates[k - 1, b] - candidates[k - 2, a]
                        turn = float(np.hypot(*(move - vel)))
                    if np.hypot(*move) > step and (a < 0 or turn > step):
                        continue
                    key = (length[k - 1, b] + 1, -(bend[k - 1, b] + turn))
                    if key > (length[k, c], -bend[k, c]) or back[k, c] < 0:
                        length[k, c], bend[k, c], back[k, c] = key[0], -key[1], b
        order = np.lexsort((bend.ravel(), -length.ravel()))
        best = next(
            (i for i in order if length.flat[i] >= min_windows and _holds_seen(i, back, seen)),
            None,
        )
        if best is None:
            return uv, found
        k, c = divmod(int(best), c_n)
        while c >= 0:
            uv[k], found[k], free[k] = candidates[k, c], True, False
            k, c = k - 1, back[k, c]


def _holds_seen(index: int, back: np.ndarray, seen: np.ndarray) -> bool:
    """Whether the chain ending at flat ``index`` of ``back`` [K,C] holds a ``seen`` window."""
    k, c = divmod(index, back.shape[1])
    while c >= 0:
        if seen[k]:
            return True
        k, c = k - 1, back[k, c]
    return False


def connected(uv: np.ndarray, found: np.ndarray, step: float) -> np.ndarray:
    """``found`` [K] less the windows whose centre ``uv`` no adjacent found window's agrees
    with (within ``step`` px): a mover moves continuously, and a lone fit to the background's
    leftovers (or to a blob of unexplained events while the mover is out of view) would drag
    the fitted path across the image."""
    near = np.hypot(*(uv[1:] - uv[:-1]).T) <= step
    linked = found[1:] & found[:-1] & near
    keep = np.zeros_like(found)
    keep[:-1] |= linked
    keep[1:] |= linked
    return keep
