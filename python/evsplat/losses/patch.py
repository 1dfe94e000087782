"""Local patch motion loss L_m (paper eq. 14-15) and the visible-Gaussian sampling it uses."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

PATCH_EPS = 1e-12  # total event magnitude below which a Gaussian's patches count as empty


def extract_patches(frames: Tensor, centres: Tensor, side: int) -> Tensor:
    """Bilinear ``side``x``side`` patches ``[n,m,side,side]`` of ``frames [m,H,W]``: patch (i, j)
    is cut from frame j around ``centres[i, j]`` (x, y pixels, pixel (r, c) centred at
    (c+.5, r+.5)); samples are spaced one pixel apart and outside the sensor read 0.
    Differentiable with respect to the centres."""
    m, h, w = frames.shape
    n = centres.shape[0]
    offs = torch.arange(side, dtype=centres.dtype, device=centres.device) - (side - 1) / 2.0
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    # [m, n, side, side] sample positions; grid_sample's align_corners=False maps x in [0, W]
    # onto [-1, 1], which is exactly the pixel-centre convention above.
    cx = centres[..., 0].T[:, :, None, None] + ox
    cy = centres[..., 1].T[:, :, None, None] + oy
    grid = torch.stack([2.0 * cx / w - 1.0, 2.0 * cy / h - 1.0], dim=-1)
    grid = grid.reshape(m, n * side, side, 2)
    out = F.grid_sample(
        frames[:, None], grid, mode="bilinear", padding_mode="zeros", align_corners=False
    )
    return out.reshape(m, n, side, side).transpose(0, 1)


def patch_motion_loss(esi_frames: Tensor, centres: Tensor, side: int) -> Tensor:
    """L_m (eq. 15): how much consecutive event patches that follow each Gaussian disagree.

    ``esi_frames [m,H,W]`` are the ESIs of m equal-count sub-windows, ``centres [n,m,2]`` the
    projected deformed centre of each sampled Gaussian at each sub-window's time. Patch j of
    Gaussian i is cut from frame j around centre (i, j). Per Gaussian, eq. 15's L1 between
    consecutive patches is divided by the patches' total event magnitude, and the loss is the
    mean over Gaussians: 0 when each patch repeats the last (the Gaussian moves with its
    edge), 1 when they share nothing. A Gaussian whose patches hold no events scores 1: an
    empty neighbourhood is not agreement (with the plain L1 it scored a perfect 0, so drifting
    into an event-free region was rewarded).
    """
    m = esi_frames.shape[0]
    if centres.dim() != 3 or centres.shape[1] != m or centres.shape[2] != 2:
        raise ValueError(
            f"patch_motion_loss: centres {tuple(centres.shape)} for {m} frames; need [n,{m},2]"
        )
    if m < 2 or centres.shape[0] == 0:
        return (esi_frames.sum() + centres.sum()) * 0.0
    patches = extract_patches(esi_frames, centres, side)
    a, b = patches[:, 1:], patches[:, :-1]
    diff = (a - b).abs().sum((1, 2, 3))
    energy = (a.abs() + b.abs()).sum((1, 2, 3))
    empty = energy <= PATCH_EPS
    ratio = diff / torch.where(empty, torch.ones_like(energy), energy)
    return torch.where(empty, torch.ones_like(ratio), ratio).mean()


def select_visible(
    means2d: Tensor,
    depths: Tensor,
    rendered_depth: Tensor,
    n: int,
    rel_tol: float,
    generator: torch.Generator | None,
) -> Tensor:
    """Indices (sorted, at most ``n``) of a random sample of unoccluded Gaussians.

    A Gaussian qualifies when its projected centre ``means2d [N,2]`` (x, y pixels) lies on the
    sensor, its camera depth is positive, and it is not behind the rendered (expected) depth of
    its pixel by more than ``rel_tol`` of that depth; pixels where nothing was rendered
    (depth <= 0) hide nothing and show nothing, so they qualify no one. The rasterizer gives
    culled Gaussians depth 0, so one too faint to draw at the render's time (time-local
    opacity) does not qualify: it is in front of nothing, the events around it are another's.
    """
    h, w = rendered_depth.shape
    with torch.no_grad():
        x, y = means2d[:, 0], means2d[:, 1]
        finite = torch.isfinite(x) & torch.isfinite(y) & torch.isfinite(depths)
        inside = finite & (x >= 0) & (x < w) & (y >= 0) & (y < h) & (depths > 0)
        col = torch.where(inside, x, torch.zeros_like(x)).long().clamp(0, w - 1)
        row = torch.where(inside, y, torch.zeros_like(y)).long().clamp(0, h - 1)
        surface = rendered_depth[row, col]
        visible = inside & (surface > 0) & (depths <= surface * (1.0 + rel_tol))
        candidates = torch.nonzero(visible, as_tuple=False).reshape(-1)
        # Drawn on the CPU (the generator's device): every device samples the same Gaussians.
        pick = torch.randperm(candidates.numel(), generator=generator)[: max(n, 0)]
        pick = pick.to(candidates.device)
        return candidates[pick].sort().values
