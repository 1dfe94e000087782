"""The three training stages of the paper (§4.6) and which losses each one uses."""

from __future__ import annotations

import enum

from evsplat.config import ScheduleConfig, TrainConfig


class Stage(enum.Enum):
    WARMUP = "warm-up"  # static Gaussians, no MLP, L_e only
    MOTION = "motion"  # deformation MLP on, + L_ef + L_m
    REFINE = "refine"  # + L_d (when a depth prior exists), L_ne, L_sp


def stage_at(iteration: int, schedule: ScheduleConfig) -> Stage:
    """The stage that ``iteration`` (0-based) belongs to."""
    if iteration < schedule.warmup_end:
        return Stage.WARMUP
    if iteration < schedule.refine_start:
        return Stage.MOTION
    return Stage.REFINE


def look_again_at(cfg: TrainConfig) -> int:
    """The iteration at which the objects are looked for once more (``MoverConfig.again``);
    -1 for never (off, no first look without a warm-up, or not after the first look)."""
    at = int(round(cfg.mover.again * cfg.schedule.iterations))
    first = cfg.schedule.warmup_end
    return at if cfg.mover.again > 0 and first > 0 and at > first else -1
