"""A trainer's ``RunState``: taken for each checkpoint, restored to resume."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from evsplat.errors import EvsplatError
from evsplat.model.gaussians import GaussianModel
from evsplat.run_state import Camera, Poses, RunState
from evsplat.train.mover import MoverTrack

if TYPE_CHECKING:
    from evsplat.train.loop import Trainer


def snapshot(trainer: Trainer, iteration: int) -> RunState:
    """Everything needed to resume ``trainer`` at ``iteration`` or to render its result."""
    t, data, stats = trainer, trainer.data, trainer.progress.stats
    return RunState(
        iteration=iteration,
        config=t.cfg,
        camera=Camera(
            K=data.K,
            width=data.width,
            height=data.height,
            t_start_us=data.t_start_us,
            t_end_us=data.t_end_us,
            channels=t.channels,
            bayer=data.bayer,
        ),
        poses=Poses(*t.pose_samples),
        dataset=str(data.root),
        gaussians=t.model.state_for_checkpoint(),
        mlp=t.mlp.state_dict(),
        mlp_active=t.mlp_active(iteration),
        optimizer=t.optimizer.state_dict(),
        mlp_optimizer=t.mlp_optimizer.state_dict(),
        densifier=t.densifier.state_dict(),
        static_mask=t.renderer.static_mask,
        static_scene=t.static_scene,
        mover_track=None if t.mover_track is None else t.mover_track.state_dict(),
        early_stop=t.progress.plateau.state_dict(),
        skipped_nonfinite=stats.skipped_nonfinite,
        skipped_empty=stats.skipped_empty,
        seconds=stats.seconds,
        history=stats.history,
        heldout=list(t.heldout),
    )


def restore(trainer: Trainer, state: RunState, path: Path) -> None:
    """Continue ``trainer`` from ``state`` (read from ``path``), a run of the same dataset and
    configuration shape."""
    t, cam = trainer, state.camera
    if (cam.width, cam.height) != (t.data.width, t.data.height):
        raise EvsplatError(
            f"{path}: checkpoint is for a {cam.width}x{cam.height} sensor but the data is "
            f"{t.data.width}x{t.data.height}; resume with the dataset it was trained on"
        )
    t.model = GaussianModel.from_checkpoint(state.gaussians)
    t.renderer.model = t.model
    t.mlp.load_state_dict(state.mlp)
    t.optimizer = t.gaussians_adam()  # over the restored model's parameters
    t.optimizer.load_state_dict(state.optimizer)
    t.mlp_optimizer.load_state_dict(state.mlp_optimizer)
    t.densifier.load_state_dict(state.densifier)
    t.renderer.static_mask = state.static_mask
    t.static_scene = state.static_scene
    t.mover_track = None if state.mover_track is None else MoverTrack.from_state(state.mover_track)
    t.progress.plateau.load_state_dict(state.early_stop)
    stats = t.progress.stats
    stats.skipped_nonfinite = state.skipped_nonfinite
    stats.skipped_empty = state.skipped_empty
    stats.seconds = state.seconds
    stats.history = list(state.history)
    t.start_iteration = state.iteration
