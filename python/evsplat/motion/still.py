"""Under a still camera, the scene's Gaussians go behind the moving objects (docs/motion.md,
step 6). A camera that never moves sees no depth, and scene Gaussians left in front of where an
object moves veil it. Moving a Gaussian along its ray, its scales grown in proportion, is a
similarity about the camera centre that the camera renders exactly as before: only the depth
order changes, which the objects' events say (nothing hides them).
"""

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
    """Move the ``scene`` rows (bool [N]) that the still camera ``c2w`` draws (``drawn``, bool
    [N]: the rasterizer's footprint is not empty; a culled Gaussian moved could come into view)
    nearer than ``back`` (camera depth) behind it along their rays (the nearest to that depth,
    the others as much deeper as they were), their scales grown alike; their optimizer state
    starts afresh. Returns how many moved."""
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
