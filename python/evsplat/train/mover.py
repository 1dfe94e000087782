"""Gaussians on a fast mover from events alone, and the deformation MLP started on its path.

The paper starts from a point cloud; event data has none, and randomly placed Gaussians are
never near enough to a fast mover for L_e's gradient to pull them along: L_e moves Gaussians
only from within about one object radius of the truth (docs/results.md, session 11). Events
locate the mover instead. After the warm-up, the static model explains the events that the
camera's motion makes over the static scene; in a short window, a moving object leaves its
events unexplained. Per window, the centre of the unexplained event energy is the mover's place
in the image (EMVS in spirit: events located by back-projection against a known scene). The
path is lifted to 3-D at the depth the warm-up model renders there, Gaussians are placed on the
mover at one time, and the MLP is fitted to carry them along the path (and, for a round
mover, to turn them with the spin its events show: ``evsplat.train.spin``). Training then refines
that motion with the paper's losses; the MLP, not time-local opacity, holds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from evsplat.model.deform import DeformationMLP
from evsplat.model.densify import update_params
from evsplat.model.gaussians import T_LOG_SCALE_RANGE, GaussianModel
from evsplat.train.mover_path import interp_rows

EPS = 1e-12  # guards divisions by energies and weights
FIT_TIMES = 8  # times per step of fit_mlp_to_path


@dataclass
class MoverTrack:
    """The mover's 3-D path as its events showed it (the found windows' centres, lifted at the
    mover's depth), kept through training as a soft prior on where its Gaussians are. Without
    it the paper's losses let the mover drift 5-14 px off its path and 0.3-0.8 m deeper after
    the seeding (docs/results.md, session 16): a ball further away and larger draws nearly the
    same events from a small camera orbit."""

    times_us: np.ndarray  # [F] int64, the found windows' middle times
    points: np.ndarray  # [F,3] world centres
    radius: float  # the mover's radius, world units: the loss's length scale
    reach_us: int  # a time further than this from every found window has no target

    def target(self, t_us: int) -> np.ndarray | None:
        """The path's centre at ``t_us`` (linear between found windows), or None away from them."""
        if np.min(np.abs(self.times_us - t_us)) > self.reach_us:
            return None
        return interp_rows(np.array([t_us]), self.times_us, self.points)[0]

    def loss(self, means: Tensor, weights: Tensor, t_us: int) -> Tensor | None:
        """Squared distance, in mover radii, of the ``weights``-weighted centre of the mover's
        deformed ``means`` [M,3] from the path at ``t_us``; None where the path has no target.
        The weights (opacities) are detached: the prior moves Gaussians, it does not fade them."""
        goal = self.target(t_us)
        if goal is None or means.shape[0] == 0:
            return None
        w = weights.detach().reshape(-1, 1)
        centre = (w * means).sum(0) / w.sum().clamp_min(EPS)
        off = centre - torch.as_tensor(goal, dtype=means.dtype)
        return (off**2).sum() / max(self.radius, EPS) ** 2

    def state_dict(self) -> dict:
        return {
            "times_us": self.times_us.tolist(),
            "points": self.points.tolist(),
            "radius": self.radius,
            "reach_us": self.reach_us,
        }

    @classmethod
    def from_state(cls, d: dict) -> MoverTrack:
        return cls(
            np.asarray(d["times_us"], dtype=np.int64),
            np.asarray(d["points"], dtype=np.float64),
            float(d["radius"]),
            int(d["reach_us"]),
        )


def disc_depth(
    depth: Tensor, alpha: Tensor, centre: np.ndarray, radius: float, quantile: float
) -> float | None:
    """The ``quantile`` of the rendered ``depth`` [H,W] over the opaque pixels (alpha > 0.5)
    of the disc around ``centre`` (x, y); None when the disc has none."""
    h, w = depth.shape
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    disc = torch.from_numpy((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2 <= radius**2)
    seen = disc & (alpha > 0.5) & (depth > 0)
    if not bool(seen.any()):
        return None
    return float(torch.quantile(depth[seen].float(), quantile))


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
    turns: Tensor | None,
    centre: np.ndarray,
    steps: int,
    lr: float,
    seed: int,
) -> float:
    """Fit ``mlp`` so the Gaussians at canonical ``means`` [M,3] move as a rigid body: by
    ``offsets`` [T,3] at normalised ``times`` [T], turned by ``turns`` [T,3,3] (None: no turn)
    about ``centre`` [3] (the body's centre in the canonical frame), linear between the times;
    returns the final RMS error of Δx in world units. Only the MLP changes; the Gaussians' own
    orientation and size are fitted not to change."""
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(mlp.parameters(), lr=lr)
    x = means.detach()
    arm = x - torch.as_tensor(centre, dtype=x.dtype)
    flat_turns = None if turns is None else (turns - torch.eye(3)).reshape(-1, 9).numpy()
    batch = min(256, x.shape[0])
    err = torch.zeros(())
    for _ in range(steps):
        t = torch.rand(FIT_TIMES, generator=gen)
        rows = torch.randint(0, x.shape[0], (batch,), generator=gen)
        goal = torch.from_numpy(interp_rows(t.numpy(), times.numpy(), offsets.numpy()))
        goal = goal.to(x.dtype).repeat_interleave(batch, dim=0)  # [FIT_TIMES*batch,3]
        if flat_turns is not None:
            bend = torch.from_numpy(interp_rows(t.numpy(), times.numpy(), flat_turns))
            bend = bend.to(x.dtype).reshape(-1, 3, 3).repeat_interleave(batch, dim=0)
            goal = goal + torch.einsum("nij,nj->ni", bend, arm[rows].repeat(FIT_TIMES, 1))
        # One pass over every (time, Gaussian) pair; the MLP takes a time per row.
        dx, dq, ds = mlp(x[rows].repeat(FIT_TIMES, 1), t.repeat_interleave(batch))
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
