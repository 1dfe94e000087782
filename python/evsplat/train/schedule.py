"""The learning-rate schedule: exponential decay of the position and MLP rates (3DGS /
Deformable-3DGS)."""

from __future__ import annotations

import torch

from evsplat.config import TrainConfig

MOTION_GROUPS = ("paths", "turns")  # the ObjectMotion's groups in the MLP's optimizer


def decay_learning_rates(
    optimizer: torch.optim.Optimizer,
    mlp_optimizer: torch.optim.Optimizer,
    cfg: TrainConfig,
    extent: float,
    iteration: int,
) -> None:
    """Set the rates for the step after ``iteration``: the means' decays from ``means_lr`` x
    ``extent`` to ``means_lr_final`` x ``extent`` over the run.

    The MLP's rate decays from iteration 0 over ``mlp_lr_span`` times the run, as the authors'
    code does (40k iterations of a 30k run): at the run's end the rate is ~1% of its start,
    small enough for the motion to settle (docs/experiments/motion.md, "The MLP's rate"). The
    objects' rigid paths keep the constant rates of ``MoverConfig``.
    """
    mc, sc = cfg.model, cfg.schedule
    frac = min(iteration / max(sc.iterations, 1), 1.0)
    for group in optimizer.param_groups:
        if group.get("name") == "means":
            start = mc.means_lr * extent
            group["lr"] = start * (mc.means_lr_final / mc.means_lr) ** frac
    frac_mlp = min(iteration / max(mc.mlp_lr_span * sc.iterations, 1.0), 1.0)
    for group in mlp_optimizer.param_groups:
        if group.get("name") not in MOTION_GROUPS:  # the objects' paths keep their own rates
            group["lr"] = mc.mlp_lr * (mc.mlp_lr_final / mc.mlp_lr) ** frac_mlp
