"""Under a still camera, the scene's Gaussians go behind the moving objects (docs/motion.md,
step 6): it sees no depth, and scene Gaussians in front of an object veil it. Moved along its
ray with its scales grown alike, a Gaussian renders as before; only the depth order changes."""

from __future__ import annotations

import numpy as np
import torch

from evsplat.model.densify import set_rows
from evsplat.model.gaussians import GaussianModel
from evsplat.projection import project

STILL = 1e-9  # largest spread of the poses' entries of a camera that stands still


def is_still(poses: np.ndarray) -> bool:
    """Whether camera-to-world ``poses`` [T,4,4] are all one pose."""
    return bool(np.ptp(poses, axis=0).max() <= STILL)


def behind_objects(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    scene: np.ndarray,
    back: float,
    c2w: np.ndarray,
    K: np.ndarray,
    drawn: np.ndarray,
) -> int:
    """Move the ``scene`` rows (bool [N]) that the still camera ``c2w`` draws (``drawn`` [N]; a
    culled one moved could come into view) nearer than camera depth ``back`` behind it along
    their rays (the nearest to it, the others as much deeper), scales grown alike, optimizer
    state afresh. Returns how many moved."""
    means = model.means.detach()
    _, z = project(means.cpu().numpy().astype(np.float64), c2w, K)
    rows = np.flatnonzero(scene & drawn & (z < back))
    if rows.size == 0:
        return 0
    factor = (back + z[rows] - z[rows].min()) / np.maximum(z[rows], 1e-9)
    idx = torch.from_numpy(rows).to(means.device)
    f = torch.from_numpy(factor).to(means)
    eye = torch.from_numpy(c2w[:3, 3]).to(means)
    moved = {"means": eye + (means[idx] - eye) * f[:, None]}
    log_scales = model.log_scales.detach()[idx] + torch.log(f)[:, None]
    set_rows(model, optimizer, idx, moved | {"log_scales": log_scales})
    return int(rows.size)
