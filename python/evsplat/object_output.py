"""What a trained run says of its moving objects, for other tools: each object's rigid pose over
time (``object_poses``, written by `evsplat export --tracks`) and, per rendered frame, the pixels
each object draws (``object_labels``, written by `evsplat render --objects`).

An object's pose is the rigid part of its motion (``model.motion.ObjectMotion``): the point it
turns about (its Gaussians' centre when it was seeded) carried along its path, and its rotation
since its reference time. What the deformation MLP adds on top (the non-rigid rest) is not in
it; the labels, rendered from the deformed Gaussians, include it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from evsplat.data.trajectory import Trajectory
from evsplat.motion_metrics import COVER
from evsplat.raster import MAX_FEATURES
from evsplat.render import Renderer

TRACK_COLUMNS = "time_us,object,visible,x,y,z,qw,qx,qy,qz,u,v,depth"


@dataclass
class ObjectPose:
    """One object at one time."""

    time_us: float
    object: int  # its index: label object + 1 in ``object_labels``
    visible: float  # the opacity factor it is drawn with (0 outside the time it was seen)
    position: np.ndarray  # [3] world, the point it turns about
    quaternion: np.ndarray  # [4] (w, x, y, z): its rotation since its reference time, world axes
    pixel: np.ndarray  # [2] (u, v) where ``position`` projects; NaN behind the camera
    depth: float  # ``position``'s depth from the camera (m, along its axis)

    def csv_row(self) -> str:
        numbers = [self.visible, *self.position, *self.quaternion, *self.pixel, self.depth]
        return f"{round(self.time_us)},{self.object}," + ",".join(f"{v:.6g}" for v in numbers)


def object_count(renderer: Renderer) -> int:
    """How many moving objects the run found (0 without the motion module's objects)."""
    motion = renderer.motion
    return 0 if motion is None or renderer.object_id is None else int(motion.centres.shape[0])


@torch.no_grad()
def object_poses(renderer: Renderer, t_us: float, trajectory: Trajectory) -> list[ObjectPose]:
    """Every object's pose at ``t_us``, seen from ``trajectory``'s camera there."""
    k = object_count(renderer)
    if k == 0:
        return []
    motion = renderer.motion
    t = renderer.time(t_us)
    quats, shifts = motion.at(t)
    positions = (motion.centres + shifts).double().cpu().numpy()
    seen = motion.visibility(torch.arange(k, device=motion.centres.device), t).cpu().numpy()
    w2c = np.linalg.inv(trajectory.pose(t_us))
    cam = positions @ w2c[:3, :3].T + w2c[:3, 3]
    K = renderer.K.double().cpu().numpy()
    ahead = cam[:, 2] > 0
    z = np.where(ahead, cam[:, 2], 1.0)  # guards the division behind the camera
    pixels = np.stack([K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]], 1)
    pixels[~ahead] = np.nan
    quats = quats.double().cpu().numpy()
    return [
        ObjectPose(t_us, i, float(seen[i]), positions[i], quats[i], pixels[i], float(cam[i, 2]))
        for i in range(k)
    ]


@torch.no_grad()
def object_labels(renderer: Renderer, t_us: float, c2w: np.ndarray) -> np.ndarray:
    """int32 [H,W]: per pixel, 1 + the index of the object drawn there, 0 for none: the object
    whose Gaussians cover the largest share of it, at least ``COVER`` (the eval's region rule).
    Each object's coverage is rendered through the whole scene, so what hides an object (the
    scene or a nearer object) hides its label too."""
    k = object_count(renderer)
    labels = np.zeros((renderer.height, renderer.width), np.int32)
    if k == 0:
        return labels
    ids = renderer.object_id.to(renderer.K.device)
    per_render = MAX_FEATURES - renderer.model.channels  # extra channels beside the colour
    cover = np.zeros((k, renderer.height, renderer.width))
    for first in range(0, k, per_render):
        which = torch.arange(first, min(first + per_render, k), device=ids.device)
        one_hot = (ids[:, None] == which[None]).float()
        out = renderer.render(t_us, c2w, extra=one_hot)
        cover[first : first + len(which)] = out.shares().permute(2, 0, 1).double().cpu().numpy()
    best = cover.argmax(axis=0)
    return np.where(cover.max(axis=0) >= COVER, best + 1, 0).astype(np.int32)


def tinted(image: np.ndarray, labels: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """[H,W,3] ``image`` ([H,W,C] in [0, 1]) with each object's pixels mixed half with its
    colour (``colours`` [K,3]), for a person to look at."""
    rgb = np.repeat(image, 3, axis=-1) if image.shape[-1] == 1 else image
    out = rgb.astype(np.float64).copy()
    drawn = labels > 0
    out[drawn] = 0.5 * out[drawn] + 0.5 * colours[(labels[drawn] - 1) % len(colours)]
    return out
