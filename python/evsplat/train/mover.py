"""Gaussians on a fast mover from events alone, and the deformation MLP started on its path.

The paper starts from a point cloud; event data has none, and randomly placed Gaussians are
never near enough to a fast mover for L_e's gradient to pull them along: L_e moves Gaussians
only from within about one object radius of the truth (docs/results.md, session 11). Events
locate the mover instead. After the warm-up, the static model explains the events that the
camera's motion makes over the static scene; in a short window, a moving object leaves its
events unexplained. Per window, the centre of the unexplained event energy is the mover's place
in the image (EMVS in spirit: events located by back-projection against a known scene). The
path is lifted to 3-D at the depth the warm-up model renders there, Gaussians are placed on the
mover at one time, and the MLP is fitted to carry them along the path. Training then refines
that motion with the paper's losses; the MLP, not time-local opacity, holds it.
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
from evsplat.model.deform import DeformationMLP
from evsplat.model.densify import update_params
from evsplat.model.gaussians import T_LOG_SCALE_RANGE, GaussianModel

EPS = 1e-12  # guards divisions by energies and weights
CAP_QUANTILE = 0.95  # see locate
FIT_TIMES = 8  # times per step of fit_mlp_to_path


@dataclass
class MoverPath:
    """The mover's image path: per window middle time, its pixel centre and disc radius."""

    times_us: np.ndarray  # [K] int64
    uv: np.ndarray  # [K,2] float64, pixel centres (x, y)
    radius_px: np.ndarray  # [K]
    contrast: np.ndarray  # [K] unexplained energy inside the disc over the image's mean
    found: np.ndarray  # [K] bool: contrast >= min_contrast

    def at(self, t_us: np.ndarray) -> np.ndarray:
        """[T,2] pixel centres at ``t_us``, linear between the found windows (held at ends)."""
        return interp_rows(t_us, self.times_us[self.found], self.uv[self.found])

    def reference(self, width: int, height: int) -> int:
        """The window to place the mover at: the clearest found one whose disc lies inside the
        image (a mover cut by the border looks smaller and off-centre), else the clearest."""
        r, (u, v) = self.radius_px, self.uv.T
        inside = (u - r >= 0) & (v - r >= 0) & (u + r <= width) & (v + r <= height)
        pick = self.found & inside if bool((self.found & inside).any()) else self.found
        return int(np.argmax(np.where(pick, self.contrast, -np.inf)))


def interp_rows(q: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` [T,D] linear in sorted ``t`` [T] at ``q`` -> [Q,D], held beyond the ends."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    t = np.asarray(t, dtype=np.float64)
    return np.stack([np.interp(q, t, values[:, k]) for k in range(values.shape[1])], axis=1)


def disc_depth(
    depth: Tensor, alpha: Tensor, centre: np.ndarray, radius: float, fallback: float
) -> float:
    """Median rendered ``depth`` [H,W] over the opaque pixels (alpha > 0.5) of the disc around
    ``centre`` (x, y); over all rendered pixels when the disc has none; ``fallback`` when
    nothing was rendered."""
    h, w = depth.shape
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    disc = torch.from_numpy((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2 <= radius**2)
    seen = disc & (alpha > 0.5) & (depth > 0)
    depths = depth[seen] if bool(seen.any()) else depth[depth > 0]
    return float(depths.median()) if depths.numel() else fallback


def unexplained(esi: Tensor, pred: Tensor, pool: int) -> Tensor:
    """[H,W] residual |ESI - predicted log change| of the static model, both first averaged over
    ``pool`` px boxes (stride 1) so the ESI's steps of C average out. A [C,H,W] input sums its
    channels."""
    diff = (esi - pred).double().reshape(-1, 1, *esi.shape[-2:])
    smooth = F.avg_pool2d(diff, pool, stride=1, padding=pool // 2, count_include_pad=False)
    return smooth.abs().sum((0, 1))[: esi.shape[-2], : esi.shape[-1]]


def locate(energy: Tensor, iterations: int = 8) -> tuple[np.ndarray, float, float]:
    """(centre [2] (x, y) in pixel coordinates, radius px, contrast) of the main blob of
    ``energy [H,W]``: mean shift from its strongest region, with a radius that grows or shrinks
    to hold the blob's energy (the radius of gyration of a disc's mass is r/√2, of a ring r).
    Contrast is the mean (capped) energy inside the disc over the image's mean."""
    h, w = energy.shape
    e = energy.double().clamp_min(0.0)
    side = max(3, (min(h, w) // 8) | 1)
    coarse = F.avg_pool2d(e[None, None], side, stride=1, padding=side // 2)[0, 0][:h, :w]
    k = int(torch.argmax(coarse))
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64) + 0.5,
        torch.arange(w, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    cx, cy = k % w + 0.5, k // w + 0.5
    radius = float(side)
    # Energy above the image's median, capped at a high quantile so a mover's few strongest
    # edges (a seam of saturated colours) do not pull the centre off its outline.
    floor, cap = (
        float(q) for q in torch.quantile(e.float().reshape(-1), torch.tensor([0.5, CAP_QUANTILE]))
    )
    weight = (e - floor).clamp(0.0, max(cap - floor, EPS))
    for _ in range(iterations):
        d2 = (xs - cx) ** 2 + (ys - cy) ** 2
        inside = weight * (d2 <= (1.5 * radius) ** 2)
        total = float(inside.sum())
        if total <= EPS:
            break
        cx = float((inside * xs).sum()) / total
        cy = float((inside * ys).sum()) / total
        gyration = math.sqrt(float((inside * d2).sum()) / total)
        radius = min(max(1.2 * gyration, 2.0), 0.5 * min(h, w))
    d2 = (xs - cx) ** 2 + (ys - cy) ** 2
    disc = d2 <= radius**2
    contrast = float(weight[disc].mean()) / max(float(weight.mean()), EPS)
    return np.array([cx, cy]), radius, contrast


def find_path(
    residual_of: Callable[[int, int], Tensor],
    t_start_us: int,
    t_end_us: int,
    cfg: MoverConfig,
) -> MoverPath:
    """The mover's path from ``cfg.windows`` evenly spread windows of ``cfg.window`` of the
    sequence; ``residual_of(t0, t1)`` is the unexplained event energy [H,W] of [t0, t1)."""
    duration = t_end_us - t_start_us
    length = max(int(cfg.window * duration), 1)
    starts = np.linspace(t_start_us, t_end_us - length, cfg.windows).astype(np.int64)
    maps = torch.stack([residual_of(int(t0), int(t0) + length) for t0 in starts])
    # What the static model misses at a pixel in most windows is the model's own error, not a
    # mover (a mover passes by): the per-pixel median over the windows is taken away.
    maps = (maps - maps.median(dim=0).values).clamp_min(0.0)
    uv, radius, contrast = [], [], []
    for energy in maps:
        centre, r, c = locate(energy)
        uv.append(centre)
        radius.append(r)
        contrast.append(c)
    contrast_arr = np.array(contrast)
    return MoverPath(
        times_us=starts + length // 2,
        uv=np.stack(uv),
        radius_px=np.array(radius),
        contrast=contrast_arr,
        found=contrast_arr >= cfg.min_contrast,
    )


def lift(uv: np.ndarray, depth: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """World points [T,3] at camera ``depth`` [T] (z) along the rays of pixels ``uv`` [T,2]
    seen from ``c2w`` [T,4,4]."""
    rays = np.stack(
        [(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))], 1
    )
    cam = rays * depth[:, None]
    return np.einsum("tij,tj->ti", c2w[:, :3, :3], cam) + c2w[:, :3, 3]


def near_path(points: Tensor, path: np.ndarray, radius: float) -> Tensor:
    """Bool [N]: ``points`` [N,3] within ``radius`` of the polyline through ``path`` [T,3] (a
    single point when T = 1): the volume the mover sweeps."""
    ends = torch.as_tensor(np.concatenate([path[:1], path]), dtype=points.dtype)
    a, b = ends[:-1], ends[1:]  # the first segment is the first point alone
    seg = b - a  # [S,3]
    rel = points[:, None, :] - a[None]  # [N,S,3]
    u = (rel * seg).sum(-1) / (seg * seg).sum(-1).clamp_min(EPS)
    closest = a[None] + u.clamp(0.0, 1.0)[..., None] * seg[None]
    return (points[:, None, :] - closest).norm(dim=-1).min(dim=1).values <= radius


def fit_mlp_to_path(
    mlp: DeformationMLP,
    means: Tensor,
    times: Tensor,
    offsets: Tensor,
    steps: int,
    lr: float,
    seed: int,
) -> float:
    """Fit ``mlp`` so the Gaussians at canonical ``means`` [M,3] move by ``offsets`` [T,3] at
    normalised ``times`` [T] (linear between them) without turning or scaling; returns the final
    RMS error of Δx in world units. Only the MLP changes."""
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(mlp.parameters(), lr=lr)
    x = means.detach()
    batch = min(256, x.shape[0])
    err = torch.zeros(())
    for _ in range(steps):
        t = torch.rand(FIT_TIMES, generator=gen)
        rows = torch.randint(0, x.shape[0], (batch,), generator=gen)
        goal = torch.from_numpy(interp_rows(t.numpy(), times.numpy(), offsets.numpy()))
        # One pass over every (time, Gaussian) pair; the MLP takes a time per row.
        dx, dq, ds = mlp(x[rows].repeat(FIT_TIMES, 1), t.repeat_interleave(batch))
        goal = goal.to(dx.dtype).repeat_interleave(batch, dim=0)
        loss = ((dx - goal) ** 2).sum(-1).mean() + (dq**2).sum(-1).mean() + (ds**2).sum(-1).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        err = loss.detach()
    return float(err.sqrt())


def place_on_mover(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    rows: Tensor,
    centre: np.ndarray,
    radius: float,
    opacity: float,
    seed: int,
) -> None:
    """Re-place the Gaussians ``rows`` uniformly in the ball of ``radius`` (world units) around
    ``centre``: isotropic at their mean spacing, identity rotation, grey, ``opacity``, shown at
    all times; their optimizer state starts afresh."""
    gen = torch.Generator().manual_seed(seed)
    m = int(rows.numel())
    direction = torch.randn(m, 3, generator=gen)
    direction = direction / direction.norm(dim=1, keepdim=True).clamp_min(EPS)
    dist = radius * torch.rand(m, 1, generator=gen) ** (1.0 / 3.0)
    spacing = radius * (4.0 / 3.0 * math.pi / max(m, 1)) ** (1.0 / 3.0)
    o = min(max(opacity, 1e-4), 1.0 - 1e-4)
    values = {
        "means": torch.as_tensor(centre, dtype=torch.float32) + direction * dist,
        "log_scales": math.log(max(spacing, EPS)),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]),
        "opacity_logits": math.log(o / (1.0 - o)),
        "sh": 0.0,
        "t_mean": 0.5,
        "t_log_scale": T_LOG_SCALE_RANGE[1],
    }

    def transform(name: str, old: Tensor, is_state: bool) -> Tensor:
        new = old.clone()
        new[rows] = 0.0 if is_state else values[name]
        return new

    update_params(model, optimizer, transform)
