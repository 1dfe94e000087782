"""A trainer's ``RunState``: taken for each checkpoint, restored to resume."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from evsplat.errors import EvsplatError
from evsplat.model.gaussians import GaussianModel
from evsplat.model.motion import ObjectMotion
from evsplat.run_state import Camera, Poses, RunState

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
        objects=None
        if t.renderer.motion is None
        else {"motion": t.renderer.motion.state(), "object_id": t.renderer.object_id},
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
    device = t.device  # where this run trains, whatever the checkpoint's run trained on
    t.model = GaussianModel.from_checkpoint(state.gaussians).to(device)
    t.renderer.model = t.model
    t.mlp.load_state_dict(state.mlp)
    t.optimizer = t.gaussians_adam()  # over the restored model's parameters
    t.optimizer.load_state_dict(state.optimizer)
    objects = state.objects
    if objects is None:
        t.renderer.motion = t.renderer.object_id = None
    else:
        t.renderer.motion = ObjectMotion.from_state(objects["motion"]).to(device)
        t.renderer.object_id = objects["object_id"].to(device)
    t.mlp_optimizer = t.mlp_adam(t.renderer.motion)  # with the restored paths, if any
    t.mlp_optimizer.load_state_dict(state.mlp_optimizer)
    t.densifier.load_state_dict(state.densifier, device)
    static = state.static_mask
    t.renderer.static_mask = None if static is None else static.to(device)
    t.static_scene = state.static_scene
    t.progress.plateau.load_state_dict(state.early_stop)
    stats = t.progress.stats
    stats.skipped_nonfinite = state.skipped_nonfinite
    stats.skipped_empty = state.skipped_empty
    stats.seconds = state.seconds
    stats.history = list(state.history)
    t.start_iteration = state.iteration
