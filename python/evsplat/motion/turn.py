"""An object's in-plane turn rate from its own events by contrast maximisation (Gallego et al.,
CVPR 2018; docs/motion.md, step 4): the rate whose image of warped events is sharpest."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import stats

from evsplat.motion.segment import robust

EPS = 1e-12  # guards the variance ratio
GRID = 41  # turn rates tried between -max and +max; refined by a parabola
MEDIAN_SE = 1.2533  # a normal sample median's standard error per sigma / sqrt(n)
STEADY_P = 0.05  # the test's level (rates of no turn pass in 4-19% of draws: N, their tails)
# A region's long axis is its orientation where its variance is this x the short one's
# (docs/motion.md, "Tuning numbers").
ELONGATED = 2.0
# Most the axes may scatter (MAD sigma) about a steady turn; a tumbling silhouette's scatter far
# more (docs/motion.md, "Tuning numbers").
AXIS_SPREAD = np.radians(10.0)


@dataclass
class WindowEvents:
    """One object's events in one window: pixel centres [E,2], seconds from the middle [E],
    polarity [E] (+1/-1)."""

    xy: np.ndarray
    dt: np.ndarray
    p: np.ndarray


def iwe_variance(
    ev: WindowEvents,
    centre: np.ndarray,
    velocity: np.ndarray,
    rates: np.ndarray,
    shape: tuple[int, int],
) -> np.ndarray:
    """Variance of the IWE [R] for each turn rate ``rates`` [R] (rad/s, x towards y), events
    ``carried_back`` by the image ``velocity`` [2] (px/s) and the turn about ``centre``."""
    return warped_variance(*carried_back(ev, centre, velocity, rates), ev.p, shape)


def carried_back(
    ev: WindowEvents, centre: np.ndarray, velocity: np.ndarray, rates: np.ndarray
) -> tuple[torch.Tensor, torch.Tensor]:
    """(x, y) [R,E] px (pixel centres at whole numbers) of the events carried back to dt = 0 by
    the image ``velocity`` [2] (px/s) and each turn rate of ``rates`` [R] (rad/s) about
    ``centre``."""
    xy = torch.from_numpy(ev.xy - centre - velocity[None] * ev.dt[:, None])  # [E,2]
    angle = -torch.from_numpy(rates)[:, None] * torch.from_numpy(ev.dt)[None]  # [R,E]
    cos, sin = torch.cos(angle), torch.sin(angle)
    x = cos * xy[:, 0] - sin * xy[:, 1] + float(centre[0]) - 0.5
    y = sin * xy[:, 0] + cos * xy[:, 1] + float(centre[1]) - 0.5
    return x, y


def warped_variance(x: torch.Tensor, y: torch.Tensor, p: np.ndarray, shape: tuple) -> np.ndarray:
    """Variance [R] of each of R images of warped events at (``x``, ``y``) [R,E] (px, pixel
    centres at whole numbers), polarity ``p`` [E]: one image per polarity (an edge's two signs
    would cancel), bilinear votes."""
    h, w = shape
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    channel = torch.from_numpy((p > 0).astype(np.int64))
    r = x.shape[0]
    # Only the box the votes fall in is drawn (an object's events cover a small part of a
    # sensor); the whole images' variance follows from its sums, the rest of them being zeros.
    left, top = max(int(x0.min()), 0), max(int(y0.min()), 0)
    bw, bh = max(min(int(x0.max()) + 2, w) - left, 0), max(min(int(y0.max()) + 2, h) - top, 0)
    images = torch.zeros(r, 2, bh + 2, bw + 2, dtype=x.dtype)
    flat = images.view(r, -1)
    for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                           (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
        # A one-pixel frame takes the votes that fall off the box, so off the image.
        xi = (x0 + dx + 1 - left).clamp(0, bw + 1).long()
        yi = (y0 + dy + 1 - top).clamp(0, bh + 1).long()
        flat.scatter_add_(1, channel[None] * (bh + 2) * (bw + 2) + yi * (bw + 2) + xi, weight)
    inside = images[:, :, 1:-1, 1:-1].double()
    n = 2 * h * w
    total, squares = inside.sum((1, 2, 3)), (inside * inside).sum((1, 2, 3))
    return ((squares - total * total / n) / max(n - 1, 1)).numpy()


def vertex(line: np.ndarray, i: int) -> float:
    """The offset (samples, within ±0.5) from ``i``, ``line``'s maximum, of the top of the
    parabola through samples i - 1, i, i + 1; 0 at an end or on a flat top."""
    if not 0 < i < len(line) - 1:
        return 0.0
    a, b, c = line[i - 1], line[i], line[i + 1]
    bend = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / bend, -0.5, 0.5)) if bend < -EPS else 0.0


def turn_rate(
    ev: WindowEvents,
    centre: np.ndarray,
    velocity: np.ndarray,
    max_rate: float,
    shape: tuple[int, int],
) -> tuple[float, float]:
    """(turn rate rad/s, gain) of one window: the rate in [-max_rate, max_rate] whose IWE is
    sharpest, and how much sharper than no turn (variance ratio - 1)."""
    if len(ev.dt) == 0 or max_rate <= 0:
        return 0.0, 0.0
    rates = np.linspace(-max_rate, max_rate, GRID)
    rates[GRID // 2] = 0.0
    score = iwe_variance(ev, centre, velocity, rates, shape)
    k = int(np.argmax(score))
    best = float(rates[k]) + vertex(score, k) * (rates[1] - rates[0])
    top = float(iwe_variance(ev, centre, velocity, np.array([best]), shape)[0])
    return best, max(top, float(score[k])) / max(float(score[GRID // 2]), EPS) - 1.0


def steady(rates: np.ndarray, least: int) -> bool:
    """Whether the turn ``rates`` [N] (rad/s) of the windows that show one are one turn: at least
    ``least`` of them, their median over Student's t at ``STEADY_P`` (N - 1 degrees) standard
    errors off zero, the spread from their median absolute deviation (a few rates stray wildly).
    An object turning out of the image plane or growing nearer sharpens some windows by a
    spurious in-plane turn of either sign (docs/experiments/objects.md, "The longer window's
    other edge, and a turn whose windows disagree")."""
    if len(rates) < max(least, 2):
        return False
    median, spread = robust(rates)
    error = MEDIAN_SE * spread / np.sqrt(len(rates))
    return abs(median) > float(stats.t.ppf(1.0 - STEADY_P / 2, len(rates) - 1)) * error


def long_axis(mask: np.ndarray) -> tuple[float, float]:
    """(angle of the long axis, rad in [-pi/2, pi/2], x towards y; its variance over the short
    one's, >= 1) of a region's pixels."""
    ys, xs = np.nonzero(mask)
    if len(xs) < 2:
        return 0.0, 1.0
    cov = np.cov(np.stack([xs, ys]).astype(np.float64))
    low, high = np.linalg.eigvalsh(cov)
    angle = 0.5 * np.arctan2(2.0 * cov[0, 1], cov[0, 0] - cov[1, 1])
    return float(angle), float(high / max(low, EPS))


def axis_rate(
    times_us: np.ndarray, masks: list[np.ndarray], least: int, top: float
) -> float | None:
    """A steady in-plane turn (rad/s) from the long axes of an object's clear regions ``masks``
    at ``times_us`` [F], or None: a long shape shows a turn its events in a short window may not.
    Of the regions ``ELONGATED`` (most of them, at least ``least`` per half of their times), the
    axes (modulo pi) about the rate in [-top, top] that lines them up best (a degree over the
    track apart): their Theil-Sen slope, where they lie within ``AXIS_SPREAD`` of that line and
    each half's slope has a (1 - STEADY_P) interval off zero on the same side (a steady turn)."""
    axes = np.array([long_axis(m) for m in masks])
    used = axes[:, 1] >= ELONGATED
    if used.sum() < max(2 * least, 4, (len(masks) + 1) // 2):
        return None
    t = (times_us[used] - times_us[used][0]) * 1e-6
    angle = axes[used, 0]
    rates = np.linspace(-top, top, 2 * int(np.ceil(top * float(t[-1]) / np.radians(1.0))) + 1)
    pull = np.abs(np.exp(2j * (angle[None] - rates[:, None] * t[None])).mean(axis=1))
    rate = float(rates[int(np.argmax(pull))])
    phase = 0.5 * np.angle(np.exp(2j * (angle - rate * t)).mean())
    line = rate * t + phase
    off = (angle - line + 0.5 * np.pi) % np.pi - 0.5 * np.pi  # about the line
    if robust(off)[1] > AXIS_SPREAD:
        return None
    unwrapped = line + off
    return float(stats.theilslopes(unwrapped, t)[0]) if one_way(unwrapped, t) else None


def one_way(angles: np.ndarray, t: np.ndarray) -> bool:
    """Whether unwrapped ``angles`` [F] (rad) at times ``t`` [F] (s) turn steadily one way: each
    half's Theil-Sen slope has a (1 - ``STEADY_P``) interval off zero on the same side."""
    half = len(t) // 2
    bounds = [  # each half's slope interval (low, high)
        stats.theilslopes(angles[part], t[part], alpha=1.0 - STEADY_P)[2:]
        for part in (slice(None, half), slice(half, None))
    ]
    return all(low > 0 for low, _ in bounds) or all(high < 0 for _, high in bounds)
