"""Under a still camera, the scene's Gaussians in front of a moving object are moved behind it.

A camera that never moves sees no depth: the warm-up leaves the scene's Gaussians at whatever
depths they started from, and those that happen to lie in front of where an object moves veil
it (on the `watch` scene, 2,000 of them in front of the objects, alpha 0.4-0.5 over their masks:
the objects were drawn but not seen). Moving a Gaussian along its ray from the camera, its
scales grown in proportion, is a similarity about the camera centre: that camera renders it
exactly as before. So the scene's Gaussians that reach into an object's regions (within the
rasterizer's own footprint, three standard deviations: on the DAVIS346 sample the Gaussians
nearest the camera were tens of pixels wide and veiled the objects from outside their regions)
and lie nearer than its back are moved behind it (shifted in depth, in their own order), and
only the order changes: the object's events say that nothing hides it.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage

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
    masks: list[np.ndarray],
    backs: list[float],
    c2w: np.ndarray,
    K: np.ndarray,
    radii: np.ndarray,
) -> int:
    """Move the ``scene`` rows (bool [N]) that, seen from the still camera ``c2w``, reach into
    object k's ``masks[k]`` ([H,W], its regions' union) nearer than ``backs[k]`` (camera depth)
    behind it along their rays (the nearest to that depth, the others as much deeper as they
    were), their scales grown alike; their optimizer state starts afresh. ``radii`` [N]: the
    rasterizer's footprints from ``c2w`` in pixels (0: not drawn, and so left where it is: a
    culled Gaussian moved could come into view). Returns how many moved."""
    means = model.means.detach().cpu().numpy().astype(np.float64)
    uv, z = project(means, c2w, K)
    factor = np.ones(len(z))
    for mask, back in zip(masks, backs):
        h, w = mask.shape
        on = np.clip(np.floor(uv), 0, [w - 1, h - 1])  # the nearest pixel in the image
        off = np.linalg.norm(uv - on - 0.5, axis=1)
        gap = ndimage.distance_transform_edt(~mask)[on[:, 1].astype(int), on[:, 0].astype(int)]
        ok = scene & (radii > 0) & (z < back) & (gap + off <= radii + 1.0)
        if ok.any():  # shifted in depth, not flattened onto one: their own order is kept
            to = back + z[ok] - z[ok].min()
            factor[ok] = np.maximum(factor[ok], to / np.maximum(z[ok], 1e-9))
    rows = np.flatnonzero(factor > 1.0)
    if rows.size == 0:
        return 0
    means, log_scales = model.means.detach(), model.log_scales.detach()
    idx = torch.from_numpy(rows).to(means.device)
    f = torch.from_numpy(factor[rows]).to(means)
    eye = torch.from_numpy(c2w[:3, 3]).to(means)
    moved = {"means": eye + (means[idx] - eye) * f[:, None]}
    set_rows(model, optimizer, idx, moved | {"log_scales": log_scales[idx] + torch.log(f)[:, None]})
    return int(rows.size)
