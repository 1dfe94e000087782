"""The mover's spin from its own events, by contrast maximisation (not in the paper).

A ball whose texture turns is drawn right only if its Gaussians turn with it: placed at its
true place, its texture held still or averaged over time scores no better than a flat image on
the ball's mask (docs/results.md, session 16). Its path says nothing about the turning, but the
events inside its disc do. Each event is back-projected onto the mover's sphere (centre and
radius from the found path), the surface points are turned back to the window's middle time by
a candidate angular velocity, and the velocity that makes the warped events' images sharpest
(largest variance) is the spin (Gallego and Scaramuzza, "Accurate angular velocity estimation
with an event camera", RA-L 2017; Gallego et al., "A unifying contrast maximization framework",
CVPR 2018). Angular velocities are in world coordinates, radians per second.

Each event carries a label, and each label's events make their own image, the variances
summed. Labelled by colour channel of the sensor's Bayer filter and polarity (``event_labels``):
a multi-colour texture's edges differ per channel, and the two signs of one edge land side by
side, so in a single image they blur each other (given `camo`'s true path, its sphere of colour
noise passes the gain test in 17 of 20 windows instead of none; docs/results.md, session 29).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

EPS = 1e-9
# Warped events are splatted bilinearly and blurred by this many pixels (sigma) before the
# variance is taken: the contrast is then smooth in the angular velocity.
BLUR_PX = 1.0
MIN_EVENTS = 200  # on the mover in a window, for an estimate
STEP_US = 1000  # integration step of the turn
GRID_EVENTS = 1000  # events the coarse grid search looks at (the refinement sees them all)


def _gaussian_taps(sigma: float) -> Tensor:
    """Normalised 1-D Gaussian taps out to 3 sigma (float64), built once for ``contrast``."""
    radius = int(np.ceil(3 * sigma))
    taps = torch.exp(
        -(torch.arange(-radius, radius + 1, dtype=torch.float64) ** 2) / (2 * sigma**2)
    )
    return taps / taps.sum()


BLUR_KERNEL = _gaussian_taps(BLUR_PX)


@dataclass
class SpinWindow:
    """The events of one window that fall on the mover, as points on its sphere."""

    time_us: int  # the window's middle: warped events land at this time
    offsets: Tensor  # [N,3] surface points relative to the mover's centre (world, metres)
    dt: Tensor  # [N] seconds from ``time_us``
    labels: Tensor  # [N] int64: which image an event goes to (``event_labels``)
    c2w: np.ndarray  # [4,4] camera at ``time_us``
    centre: np.ndarray  # [3] the mover's centre at ``time_us``


def event_labels(channel: np.ndarray, polarity: np.ndarray) -> np.ndarray:
    """Each event's image in ``contrast``: its pixel's colour channel (0-2; 0 for a mono sensor)
    and its polarity (+1 or -1)."""
    return channel.astype(np.int64) * 2 + (polarity > 0)


def rotation(omega: Tensor) -> Tensor:
    """Rotation matrices ``[...,3,3]`` of rotation vectors ``omega`` ``[...,3]`` (Rodrigues);
    exact at zero."""
    theta = omega.norm(dim=-1, keepdim=True)
    k = omega / theta.clamp_min(EPS)
    kx = torch.zeros(*omega.shape[:-1], 3, 3, dtype=omega.dtype)
    kx[..., 0, 1], kx[..., 0, 2] = -k[..., 2], k[..., 1]
    kx[..., 1, 0], kx[..., 1, 2] = k[..., 2], -k[..., 0]
    kx[..., 2, 0], kx[..., 2, 1] = -k[..., 1], k[..., 0]
    s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
    return torch.eye(3, dtype=omega.dtype) + s * kx + (1.0 - c) * (kx @ kx)


def sphere_hits(
    uv: np.ndarray, c2w: np.ndarray, K: np.ndarray, centre: np.ndarray, radius: float, rim: float
) -> tuple[np.ndarray, np.ndarray]:
    """Front-surface points of the sphere (``centre`` [N,3], ``radius``) seen at pixels ``uv``
    [N,2] from cameras ``c2w`` [N,4,4]: (offsets from the centre [M,3], kept [N] bool). Only rays
    that pass within ``rim`` radii of the centre are kept: at the outline, events come from the
    background being covered, not from the mover's texture."""
    cam = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], 1)
    d = np.einsum("nij,nj->ni", c2w[:, :3, :3], np.concatenate([cam, np.ones((len(uv), 1))], 1))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), EPS)
    oc = c2w[:, :3, 3] - centre
    b = (d * oc).sum(1)
    closest = (oc * oc).sum(1) - b * b  # squared distance of the ray from the centre
    keep = (closest < (rim * radius) ** 2) & (b < 0)  # the centre in front of the camera
    s = -b - np.sqrt(np.maximum(radius**2 - closest, 0.0))
    hits = c2w[:, :3, 3] + s[:, None] * d - centre
    return hits[keep], keep


def contrast(window: SpinWindow, omega: Tensor, K: np.ndarray, size: tuple[int, int]) -> Tensor:
    """Variance ``[B]`` of the images of the window's events (one per label, variances summed)
    warped to its middle time by each angular velocity ``omega`` [B,3] (blurred by
    ``BLUR_PX``); differentiable in ``omega``."""
    w, h = size
    groups = int(window.labels.max()) + 1 if len(window.labels) else 1
    dtype = omega.dtype
    turn = rotation(-omega[:, None, :] * window.dt.to(dtype)[None, :, None])  # [B,N,3,3]
    points = torch.einsum("bnij,nj->bni", turn, window.offsets.to(dtype))
    w2c = torch.as_tensor(np.linalg.inv(window.c2w), dtype=dtype)
    cam = (points + torch.as_tensor(window.centre, dtype=dtype)) @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[..., 2].clamp_min(EPS)
    u = K[0, 0] * cam[..., 0] / z + K[0, 2] - 0.5  # pixel centres at integers
    v = K[1, 1] * cam[..., 1] / z + K[1, 2] - 0.5
    image = torch.zeros(omega.shape[0], groups * h * w, dtype=dtype)
    base = window.labels[None, :] * (h * w)
    u0, v0 = u.floor(), v.floor()
    for du in (0.0, 1.0):
        for dv in (0.0, 1.0):
            uu, vv = u0 + du, v0 + dv
            weight = (1.0 - (u - uu).abs()) * (1.0 - (v - vv).abs())
            inside = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            index = base + (vv.clamp(0, h - 1) * w + uu.clamp(0, w - 1)).long()
            image.scatter_add_(1, index, weight * inside)
    kernel = BLUR_KERNEL.to(dtype)
    radius = len(kernel) // 2
    image = image.view(-1, 1, h, w)
    image = torch.nn.functional.conv2d(image, kernel.view(1, 1, 1, -1), padding=(0, radius))
    image = torch.nn.functional.conv2d(image, kernel.view(1, 1, -1, 1), padding=(radius, 0))
    return image.view(omega.shape[0], groups, h * w).var(dim=2).sum(dim=1)


def estimate_spin(
    window: SpinWindow,
    K: np.ndarray,
    size: tuple[int, int],
    start: np.ndarray | None,
    max_rate: float,
    steps: int,
) -> tuple[np.ndarray, float]:
    """The angular velocity [3] (rad/s) that maximises the window's contrast, and its contrast
    gain over no spin at all (0.1: 10% more variance). Without a ``start``, a coarse grid over
    ``|ω_i| <= max_rate`` on a subset of the events picks one (the contrast has local maxima);
    then Adam refines it on all of them."""
    dtype = torch.float64
    if start is None:
        axis = torch.linspace(-max_rate, max_rate, 7, dtype=dtype)
        grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        few = SpinWindow(
            window.time_us,
            window.offsets[:GRID_EVENTS],
            window.dt[:GRID_EVENTS],
            window.labels[:GRID_EVENTS],
            window.c2w,
            window.centre,
        )
        with torch.no_grad():
            scores = torch.cat([contrast(few, g, K, size) for g in grid.split(64)])
        start = grid[int(scores.argmax())].numpy()
    omega = torch.tensor(start, dtype=dtype, requires_grad=True)
    opt = torch.optim.Adam([omega], lr=0.05 * max_rate)
    for _ in range(steps):
        opt.zero_grad()
        (-contrast(window, omega[None], K, size)[0]).backward()
        opt.step()
    with torch.no_grad():
        best = contrast(window, omega.detach()[None], K, size)[0]
        still = contrast(window, torch.zeros(1, 3, dtype=dtype), K, size)[0]
    return omega.detach().numpy(), float(best / still.clamp_min(EPS) - 1.0)


def integrate(
    times_us: np.ndarray,
    omegas: np.ndarray,
    t_ref: int,
    query_us: np.ndarray,
    step_us: int = STEP_US,
) -> np.ndarray:
    """Rotations [Q,3,3] that take the mover's orientation at ``t_ref`` to each ``query_us``
    time, integrating dR/dt = [ω(t)]x R with ω linear between the estimates ``omegas`` [T,3] at
    ``times_us`` [T] (held constant beyond them), in steps of ``step_us``."""
    lo = min(int(query_us.min()), t_ref)
    hi = max(int(query_us.max()), t_ref)
    grid = np.arange(lo, hi + step_us, step_us, dtype=np.int64)
    rates = np.stack([np.interp(grid, times_us, omegas[:, i]) for i in range(3)], 1)
    steps = rotation(torch.from_numpy(rates * step_us * 1e-6)).numpy()  # [G,3,3]
    base = int(np.searchsorted(grid, t_ref))
    grid[base] = t_ref  # the reference sits on the grid
    turns = np.empty((len(grid), 3, 3))
    turns[base] = np.eye(3)
    for g in range(base + 1, len(grid)):
        turns[g] = steps[g - 1] @ turns[g - 1]
    for g in range(base - 1, -1, -1):
        turns[g] = steps[g].T @ turns[g + 1]
    index = np.clip(np.searchsorted(grid, query_us), 0, len(grid) - 1)
    return turns[index]


def find_spin(
    events_in: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]],
    centre_at: Callable[[np.ndarray], np.ndarray],
    pose_at: Callable[[np.ndarray], np.ndarray],
    radius: float,
    K: np.ndarray,
    size: tuple[int, int],
    times_us: np.ndarray,
    half_window_us: int,
    cfg: SpinSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Angular velocities [T,3] at ``times_us`` and each window's contrast gain [T] (NaN where
    too few events fell on the mover):
    each window [t - half, t + half) of events (``events_in`` gives pixel centres [N,2], times
    [N] and ``event_labels`` [N]) on the mover's sphere, started from the last found window's
    estimate. A window with too few events on the mover or too little contrast gain keeps the
    last estimate (the mover out of view, or cut by the image's border)."""
    rng = np.random.default_rng(cfg.seed)
    out, gains, previous = np.zeros((len(times_us), 3)), np.full(len(times_us), np.nan), None
    for k, t in enumerate(times_us):
        uv, t_ev, labels = events_in(int(t) - half_window_us, int(t) + half_window_us)
        offsets, keep = sphere_hits(uv, pose_at(t_ev), K, centre_at(t_ev), radius, cfg.rim)
        if len(offsets) < MIN_EVENTS:
            out[k] = previous if previous is not None else 0.0
            continue
        pick = rng.permutation(len(offsets))[: cfg.max_events]
        window = SpinWindow(
            int(t),
            torch.from_numpy(offsets[pick]),
            torch.from_numpy((t_ev[keep][pick] - t) * 1e-6),
            torch.from_numpy(labels[keep][pick]),
            pose_at(np.array([t]))[0],
            centre_at(np.array([t]))[0],
        )
        steps = cfg.steps if previous is None else cfg.steps // 2
        omega, gains[k] = estimate_spin(window, K, size, previous, cfg.max_rate, steps)
        if gains[k] >= cfg.min_gain:
            previous = omega
        out[k] = previous if previous is not None else 0.0
    return out, gains


@dataclass
class SpinSettings:
    """Knobs of ``find_spin`` (the values come from ``MoverConfig``)."""

    rim: float
    max_events: int
    max_rate: float
    min_gain: float
    steps: int
    seed: int
