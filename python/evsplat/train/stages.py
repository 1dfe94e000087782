"""The three training stages of the paper (§4.6) and which losses each one uses."""

from __future__ import annotations

import enum

from evsplat.config import ScheduleConfig


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
