"""Paths refined by search (``evsplat.motion.refine``) against the simulator's truth: the ball's
Gaussians are back-projected from its true render and moved along its true path, which is then
pushed off in the image; the search must bring each knot back where its window's events say."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from test_train_oracle_motion import _back_project

from evsplat.config import preset
from evsplat.data.dataset import load_dataset
from evsplat.model.gaussians import SH_C0
from evsplat.model.motion import ObjectMotion
from evsplat.motion.refine import refine_paths
from evsplat.projection import project
from evsplat.scenes import get_scene
from evsplat.train.loop import Trainer

HORIZON_US = 72_000  # the ball moves ~25 px and turns under a radian: its first view holds
KNOTS = 7  # 12 ms apart
PUSH = np.array([4.0, -3.0])  # px, the error put on the path


def _true_scene(data_dir, run_dir) -> tuple[Trainer, np.ndarray]:
    """A trainer whose model is the ball's true surface and the room, the ball moved by its true
    rigid path on ``KNOTS`` knots; and the knots' times (µs)."""
    scene = get_scene("ball", tiny=True, samples=1)
    data = load_dataset(data_dir)
    data = dataclasses.replace(data, t_end_us=data.t_start_us + HORIZON_US)
    K, t0 = data.K, data.t_start_us
    ball = _back_project(scene, t0, K, moving=True)
    room = _back_project(scene, t0, K, moving=False)
    points, colours, depth = (np.concatenate([ball[k], room[k]]) for k in range(3))
    cfg = preset("tiny")
    cfg.num_gaussians = len(points)
    cfg.mover.window = 0.125  # 9 ms windows, as the tiny preset's over the whole sequence
    trainer = Trainer(data, cfg, run_dir)
    model = trainer.model
    with torch.no_grad():
        model.means.copy_(torch.from_numpy(points.astype(np.float32)))
        model.sh[:, 0, :] = torch.from_numpy(((colours - 0.5) / SH_C0).astype(np.float32))
        size = torch.from_numpy(np.log(depth / K[0, 0]).astype(np.float32))
        model.log_scales.copy_(size[:, None])
        model.opacity_logits.fill_(math.log(0.8 / 0.2))
    times = np.linspace(t0, data.t_end_us, KNOTS).astype(np.int64)
    pose = scene.primitives[-1].pose  # seconds -> [4,4]
    first = pose(t0 * 1e-6)
    translations = np.stack([pose(t * 1e-6)[:3, 3] - first[:3, 3] for t in times])
    turns = [pose(t * 1e-6)[:3, :3] @ first[:3, :3].T for t in times]
    rotvecs = Rotation.from_matrix(np.stack(turns)).as_rotvec()
    as_t = lambda a: torch.tensor(a[None], dtype=torch.float32)  # noqa: E731
    radius = torch.tensor([0.38])  # the ball's (scenes.library)
    motion = ObjectMotion(as_t(first[:3, 3]), radius, as_t(translations), as_t(rotvecs))
    object_id = torch.full((len(points),), -1, dtype=torch.long)
    object_id[: len(ball[0])] = 0
    renderer = trainer.renderer
    renderer.motion, renderer.object_id, renderer.mlp = motion, object_id, None
    return trainer, times


def _centres_px(trainer: Trainer, times: np.ndarray) -> np.ndarray:
    motion, data = trainer.renderer.motion, trainer.data
    with torch.no_grad():
        world = (motion.centres[0] + motion.translations[0]).double().numpy()
    poses = [data.trajectory.pose(float(t)) for t in times]
    return np.stack([project(w[None], c2w, data.K)[0][0] for w, c2w in zip(world, poses)])


def _push(trainer: Trainer, times: np.ndarray, knots: range, px: np.ndarray) -> None:
    """Move ``knots`` of the path by ``px`` in the image at the ball's depth."""
    motion, data = trainer.renderer.motion, trainer.data
    for g in knots:
        c2w = data.trajectory.pose(float(times[g]))
        with torch.no_grad():
            centre = (motion.centres[0] + motion.translations[0, g]).double().numpy()
        z = project(centre[None], c2w, data.K)[1][0]
        step = c2w[:3, :3] @ np.array([px[0] * z / data.K[0, 0], px[1] * z / data.K[1, 1], 0.0])
        with torch.no_grad():
            motion.translations[0, g] += torch.from_numpy(step).float()


def test_a_path_pushed_off_is_brought_back_where_the_events_are(tiny_scene, tmp_path):
    trainer, times = _true_scene(tiny_scene("ball"), tmp_path / "run")
    truth = _centres_px(trainer, times)
    _push(trainer, times, range(KNOTS), PUSH)
    # A held-out window is never read: its knot keeps the error.
    held = int(times[3])
    trainer.views.heldout = [(held - 1000, held + 1000)]
    motion = trainer.renderer.motion
    path, prior = motion.translations.detach().clone(), motion.prior_translations.clone()
    logged = refine_paths(trainer.views, motion, trainer.cfg.mover)
    error = np.linalg.norm(_centres_px(trainer, times) - truth, axis=1)
    assert logged["refined_knots"] == KNOTS - 1, logged
    # Back within a pixel (the search's last step is half a pixel) where the events are read.
    assert abs(error[3] - float(np.linalg.norm(PUSH))) < 1e-3, error
    assert np.all(np.delete(error, 3) < 1.0), error
    # The track prior moves with the path.
    moved = motion.translations.detach() - path
    assert torch.allclose(motion.prior_translations - prior, moved, atol=1e-7)
