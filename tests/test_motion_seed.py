"""The objects' seeding on the simulator's scenes, against the ground truth it knows: the ball's
track and its seeded Gaussians' path against the ball's true centre, nothing in `still`, and a
slow card's track under a still camera against its true path."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from evsplat.config import MoverConfig, preset
from evsplat.data.dataset import load_dataset
from evsplat.model.motion import BEHIND
from evsplat.motion.seed import sight
from evsplat.motion.tracks import chain
from evsplat.projection import project
from evsplat.train.loop import Trainer

WARMUP = 200  # the tiny preset's warm-up (10% of 2000 iterations)


def _warmed_up(data_dir, run_dir) -> Trainer:
    cfg = preset("tiny")
    cfg.skips.early_stop = False
    cfg.schedule.grad_norms_every = 0
    trainer = Trainer(load_dataset(data_dir), cfg, run_dir)
    for it in range(WARMUP):
        trainer.step(it)
    return trainer


def _project(points: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    cam = (points - c2w[:3, 3]) @ c2w[:3, :3]
    return (K @ (cam / cam[:, 2:]).T).T[:, :2]


def test_the_balls_seeded_gaussians_follow_its_true_path(tiny_scene, tmp_path):
    trainer = _warmed_up(tiny_scene("ball"), tmp_path / "run")
    logged = trainer.seed_objects()
    assert logged["objects"] >= 1
    renderer, data = trainer.renderer, trainer.data
    ids = renderer.object_id
    assert ids is not None and torch.equal(renderer.static_mask, ids < 0)
    assert float(renderer.motion.behind) == 0.0  # a moving camera: behind it is the scene's
    track = data.track
    errors, nearest, truth_px, times = [], [], [], []
    with torch.no_grad():
        for t in np.linspace(data.t_start_us, data.t_end_us, 25):
            pose = data.trajectory.pose(float(t))
            truth = np.array([np.interp(t, track.times_us, track.centres[:, j]) for j in range(3)])
            uv_true = _project(truth[None], pose, data.K)[0]
            if not (0 <= uv_true[0] < data.width and 0 <= uv_true[1] < data.height):
                continue
            means = renderer.gaussians_at(t)[0].double().numpy()
            # The object drawn there: the one whose Gaussians' median lies nearest the truth.
            off = [
                np.linalg.norm(
                    _project(np.median(means[ids == k], 0)[None], pose, data.K)[0] - uv_true
                )
                for k in range(int(logged["objects"]))
            ]
            errors.append(float(min(off)))
            nearest.append(int(np.argmin(off)))
            truth_px.append(uv_true)
            times.append(t)
    span = float(np.linalg.norm(np.ptp(np.stack(truth_px), axis=0)))
    # The ball (20 px radius) crosses ~60+ px of the image; a model whose Gaussians stood still
    # would be off by tens of pixels.
    assert span > 60.0
    assert float(np.median(errors)) < 6.0, errors
    # The ball is round: it is seeded as a sphere whose outline is the true ball's, the same
    # angle wide from the camera (0.38 m across, scenes.library's ``ball``), whatever depth
    # the warm-up gave it.
    motion, sizes, k = renderer.motion, [], int(np.bincount(nearest).argmax())
    assert logged[f"object{k}_sphere"] == 1.0
    with torch.no_grad():
        for t in times:
            eye = data.trajectory.pose(float(t))[:3, 3]
            truth = np.array([np.interp(t, track.times_us, track.centres[:, j]) for j in range(3)])
            at = (motion.centres[k] + motion.at(renderer.time(t))[1][k]).double().numpy()
            seen = float(motion.radii[k]) / np.linalg.norm(at - eye)
            sizes.append(seen / (0.38 / np.linalg.norm(truth - eye)))
    assert abs(float(np.median(sizes)) - 1.0) < 0.1, sizes
    # Looking again against the objects found: the ball is not found a second time (a new
    # object, if any, is the model's leftover elsewhere), and the objects keep their paths.
    first = renderer.motion.centres.shape[0]
    before = renderer.motion.translations.detach().clone()
    again = trainer.seed_objects(again=True)
    motion = trainer.renderer.motion
    assert motion.centres.shape[0] == first + int(again["objects"])
    assert torch.equal(motion.translations[:first].detach(), before)
    with torch.no_grad():
        for k in range(first, motion.centres.shape[0]):
            off = []
            for t, uv_true in zip(times, truth_px):
                at = motion.centres[k] + motion.at(trainer.renderer.time(t))[1][k]
                pose = data.trajectory.pose(float(t))
                off.append(
                    np.linalg.norm(_project(at.double().numpy()[None], pose, data.K)[0] - uv_true)
                )
            assert np.median(off) > 20.0  # farther than the ball's radius from it


def test_nothing_is_seeded_in_a_static_scene(tiny_scene, tmp_path):
    trainer = _warmed_up(tiny_scene("still"), tmp_path / "run")
    logged = trainer.seed_objects()
    assert logged["objects"] == 0
    assert trainer.renderer.motion is None and trainer.renderer.static_mask is None


def test_a_still_cameras_objects_are_not_veiled_by_the_scene(tiny_scene, tmp_path):
    trainer = _warmed_up(tiny_scene("watch"), tmp_path / "run")
    logged = trainer.seed_objects()
    assert logged["objects"] >= 1 and logged["moved_behind"] > 0
    renderer, data = trainer.renderer, trainer.data
    assert float(renderer.motion.behind) == BEHIND  # no parallax placed what lies behind them
    ids = renderer.object_id.cpu().numpy()
    pose = data.trajectory.pose(float(data.t_start_us))  # the one pose
    _, z = project(renderer.model.means.detach().double().numpy(), pose, data.K)
    with torch.no_grad():
        for k in range(int(logged["objects"])):
            nearer = (ids < 0) & (z < np.median(z[ids == k]))
            for t in np.linspace(data.t_start_us, data.t_end_us, 5):
                # Oracle: the rasterizer's coverage, the object's and that of what lies before it.
                cover = [_alone(renderer, rows, t, pose) for rows in (ids == k, nearer)]
                drawn = cover[0] > 0.5
                if drawn.sum() > 10:
                    assert float(np.quantile(cover[1][drawn], 0.9)) < 0.1, (k, t)


def _alone(renderer, rows: np.ndarray, t: float, pose: np.ndarray) -> np.ndarray:
    """The alpha of the Gaussians ``rows`` (bool [N]) alone at time ``t``."""
    logits = renderer.model.opacity_logits
    kept = logits.clone()
    logits[torch.from_numpy(~rows)] = -30.0
    try:
        return renderer.render(int(t), pose).alpha.numpy()
    finally:
        logits.copy_(kept)


def test_a_slow_card_before_a_still_camera_is_followed(tiny_scene, tmp_path):
    # drawn-115: a still camera and one checkered card sliding at 1.2 px per window spacing and
    # turning; its events make no region in one short window. Held out when the longer window
    # was chosen (docs/experiments/objects.md, "Evidence summed over more time").
    trainer = _warmed_up(tiny_scene("drawn-115"), tmp_path / "run")
    data, mc = trainer.data, trainer.cfg.mover
    (card,) = data.tracks
    pose = data.trajectory.pose(float(data.t_start_us))  # the one pose

    def nearest_track_px(config: MoverConfig) -> float:
        sightings = sight(trainer.views, config)
        assert sightings.still
        off = []
        for track in chain(sightings.blobs, config, sightings.still):
            t = track.times_us
            truth = np.stack([np.interp(t, card.times_us, card.centres[:, j]) for j in range(3)], 1)
            seen = np.linalg.norm(track.centres - _project(truth, pose, data.K), axis=1)
            off.append(float(np.median(seen)))
        return min(off, default=np.inf)

    # Oracle: the simulator's path; the card reaches 12 px from its centre.
    assert nearest_track_px(mc) < 3.0
    assert nearest_track_px(replace(mc, still_window=0.0)) > 10.0
