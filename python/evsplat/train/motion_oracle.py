"""The simulator's true motion for the objects the seeding found (``mover.oracle``): for the
built-in synthetic scenes only, an upper bound that tells the motion module's errors from the
losses' (docs/experiments/objects.md, "The true motion as an oracle"). Each found object is
matched to the true object nearest its centre at its reference time; its turn, its path or both
are then that object's from the reference time on. A run's config.json says whether it was
used."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from evsplat.errors import EvsplatError
from evsplat.model.motion import ObjectMotion, knot_times_us
from evsplat.projection import project
from evsplat.train.depth_prior import simulated_scene

if TYPE_CHECKING:
    from evsplat.scenes import Scene

MODES = ("none", "turn", "path", "both")
UNWRAP = 3  # full turns tried either way when a rotation vector is unwrapped


def true_scene(mode: str, dataset) -> Scene | None:
    """The built-in scene whose motion ``mode`` asks for (None for "none"); a one-line error for
    a mode not in ``MODES``, or an oracle asked of other data."""
    if mode not in MODES:
        raise EvsplatError(f"--set mover.oracle={mode}: expected one of {', '.join(MODES)}")
    if mode == "none":
        return None
    scene = simulated_scene(dataset)
    if scene is None:
        raise EvsplatError(
            f"{dataset.root}: mover.oracle={mode} needs a built-in synthetic scene (meta.json "
            "'scene'); leave mover.oracle=none on other data"
        )
    return scene


def _unwrapped(rotvecs: np.ndarray, start: int) -> np.ndarray:
    """Rotation vectors [G,3] made continuous from knot ``start`` outwards: each the one of its
    rotation's equivalents (whole turns added about its axis) nearest its neighbour's."""
    out = rotvecs.copy()
    order = [*range(start + 1, len(out)), *range(start - 1, -1, -1)]
    for g in order:
        near = out[g - 1] if g > start else out[g + 1]
        angle = float(np.linalg.norm(out[g]))
        if angle > 0.0:
            turns = angle + 2 * np.pi * np.arange(-UNWRAP, UNWRAP + 1)
            options = out[g] / angle * turns[:, None]
            out[g] = options[np.argmin(np.linalg.norm(options - near, axis=1))]
    return out


@torch.no_grad()
def apply_oracle(
    motion: ObjectMotion, refs_us: dict[int, int], mode: str, scene: Scene, dataset
) -> dict:
    """Give the objects ``refs_us`` names (id -> reference time, µs; ``Seeded.references_us``)
    the true ``mode`` motion of the ``scene`` object each is matched to, as parameters and as
    their track prior. Numbers for the log: per object, the true object's index and how far (px)
    their centres lay apart at the reference time."""
    g = motion.translations.shape[1]
    knots = knot_times_us(dataset.t_start_us, dataset.t_end_us, g)
    stats = {}
    for k, t_ref in refs_us.items():
        centre = motion.centres[k].double().cpu().numpy()
        seen_from = dataset.trajectory.pose(float(t_ref))
        truths = np.stack([scene.object_centre(t_ref, i) for i in range(len(scene.objects))])
        at = project(np.vstack([centre[None], truths]), seen_from, dataset.K)[0]
        apart = np.linalg.norm(at[1:] - at[0], axis=1)
        match = int(np.argmin(apart))
        ref = scene.object_pose(t_ref, match)
        poses = np.stack([scene.object_pose(t, match) for t in knots])
        turned = poses[:, :3, :3] @ ref[:3, :3].T  # [G,3,3] from the reference time
        if mode in ("turn", "both"):
            start = int(np.argmin(np.abs(knots - t_ref)))
            rotvecs = _unwrapped(Rotation.from_matrix(turned).as_rotvec(), start)
            for p in (motion.rotvecs, motion.prior_rotvecs):
                p[k] = torch.as_tensor(rotvecs, dtype=p.dtype, device=p.device)
        if mode in ("path", "both"):  # the centre carried as the true object carries it
            shifts = turned @ (centre - ref[:3, 3]) + poses[:, :3, 3] - centre
            for p in (motion.translations, motion.prior_translations):
                p[k] = torch.as_tensor(shifts, dtype=p.dtype, device=p.device)
        stats[f"object{k}_oracle_match"] = float(match)
        stats[f"object{k}_oracle_px"] = float(apart[match])
    return stats
