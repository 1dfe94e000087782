"""Dense numpy reference for the event core: obviously correct, slow, written from the
definitions (np.add.at scatter, explicit loops over samples) without sharing code with
evsplat. Results are float64; callers compare with a tolerance."""

from __future__ import annotations

import numpy as np

_TILES = {
    "RGGB": [[0, 1], [1, 2]],
    "BGGR": [[2, 1], [1, 0]],
    "GRBG": [[1, 0], [2, 1]],
    "GBRG": [[1, 2], [0, 1]],
}


def _per_pixel(c, h: int, w: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(c, np.float64), (h, w))


def esi(x, y, p, w: int, h: int, c_pos, c_neg) -> np.ndarray:
    """Sum over events of C+ (p > 0) or -C- (p < 0) at their pixel."""
    cp, cn = _per_pixel(c_pos, h, w), _per_pixel(c_neg, h, w)
    x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
    val = np.where(np.asarray(p) > 0, cp[y, x], -cn[y, x])
    out = np.zeros((h, w))
    np.add.at(out, (y, x), val)
    return out


def count(x, y, w: int, h: int) -> np.ndarray:
    out = np.zeros((h, w), np.int64)
    np.add.at(out, (np.asarray(y, np.int64), np.asarray(x, np.int64)), 1)
    return out


def bayer_map(pattern: str, w: int, h: int) -> np.ndarray:
    if pattern == "mono":
        return np.zeros((h, w), np.int64)
    tile = np.array(_TILES[pattern])
    rows, cols = np.mgrid[0:h, 0:w]
    return tile[rows % 2, cols % 2]


def esi_by_channel(x, y, p, w: int, h: int, c_pos, c_neg, pattern: str) -> np.ndarray:
    img = esi(x, y, p, w, h, c_pos, c_neg)
    chan = bayer_map(pattern, w, h)
    channels = 1 if pattern == "mono" else 3
    return np.stack([np.where(chan == c, img, 0.0) for c in range(channels)])


def split_bounds(i0: int, i1: int, m: int) -> np.ndarray:
    """Boundaries of m sub-windows of equal count: i0 + floor(k n / m)."""
    return np.array([i0 + (k * (i1 - i0)) // m for k in range(m + 1)], np.int64)


def sample(img: np.ndarray, sx: float, sy: float, mode: str) -> float | None:
    """Image value at pixel coordinates (sx, sy); None outside. Bilinear weights on pixel
    centres (j + .5, i + .5) with edge pixels repeated past the border."""
    h, w = img.shape
    if not (0 <= sx < w and 0 <= sy < h):
        return None
    if mode == "nearest":
        return float(img[int(np.floor(sy)), int(np.floor(sx))])
    u, v = sx - 0.5, sy - 0.5
    j, i = int(np.floor(u)), int(np.floor(v))
    ax, ay = u - j, v - i
    total = 0.0
    for di, wy in ((0, 1 - ay), (1, ay)):
        for dj, wx in ((0, 1 - ax), (1, ax)):
            ii, jj = min(max(i + di, 0), h - 1), min(max(j + dj, 0), w - 1)
            total += wy * wx * img[ii, jj]
    return total


def patches(x, y, p, w, h, centres, bounds, side, c_pos, c_neg, mode):
    """(n, m, side, side) values and validity, one sample at a time."""
    centres = np.asarray(centres, np.float64)
    m = len(bounds) - 1
    n = len(centres)
    values = np.zeros((n, m, side, side))
    valid = np.zeros((n, m, side, side), bool)
    half = (side - 1) / 2
    for k in range(m):
        a, b = bounds[k], bounds[k + 1]
        img = esi(x[a:b], y[a:b], p[a:b], w, h, c_pos, c_neg).astype(np.float32)
        for c in range(n):
            cx, cy = centres[c, k] if centres.ndim == 3 else centres[c]
            for r in range(side):
                for q in range(side):
                    s = sample(img.astype(np.float64), cx + (q - half), cy + (r - half), mode)
                    if s is not None:
                        values[c, k, r, q] = s
                        valid[c, k, r, q] = True
    return values, valid


def voxel_grid(x, y, t, p, w: int, h: int, bins: int) -> np.ndarray:
    """Each event adds p * max(0, 1 - |tn - b|) to every bin b, tn in [0, bins-1]."""
    out = np.zeros((bins, h, w))
    if len(t) == 0:
        return out
    t = np.asarray(t, np.int64)
    rel = (t - t[0]).astype(np.float64)
    span = float(t[-1] - t[0])
    tn = rel * (bins - 1) / span if span > 0 else np.zeros_like(rel)
    pol = np.where(np.asarray(p) > 0, 1.0, -1.0)
    for b in range(bins):
        wgt = np.maximum(0.0, 1.0 - np.abs(tn - b))
        np.add.at(out[b], (np.asarray(y, np.int64), np.asarray(x, np.int64)), pol * wgt)
    return out
