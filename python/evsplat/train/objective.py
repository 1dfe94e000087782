"""The objective's terms beyond L_e, assembled per step by the training loop: the motion
losses (L_ef, L_m; paper §4.2-4.3), the refinement losses (L_d, L_ne, L_sp; §4.4) and the
objects' track prior (not in the paper; ``model.motion.ObjectMotion.prior_loss``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from evsplat.config import LossConfig, TrainConfig
from evsplat.data.dataset import Dataset
from evsplat.losses.depth import silog
from evsplat.losses.flow import camera_flow, event_flow_loss
from evsplat.losses.patch import patch_motion_loss, select_visible
from evsplat.losses.reg import non_event_loss, spatial_gradient_loss
from evsplat.model.deform import DeformationMLP, deformed_means
from evsplat.model.gaussians import GaussianModel
from evsplat.projection import project_points, viewmat
from evsplat.render import Renderer, RenderOut
from evsplat.train.depth_prior import DepthPrior
from evsplat.train.views import Views


def loss_weights(cfg: TrainConfig) -> dict[str, float]:
    """Each term's weight in the step's total (L_e's is 1)."""
    lc = cfg.loss
    return {
        "e": 1.0,
        "ef": lc.w_flow,
        "m": lc.w_motion,
        "d": lc.w_depth,
        "ne": lc.w_non_event,
        "sp": lc.w_spatial,
        "tr": cfg.mover.track_weight,
    }


@dataclass
class MotionEvents:
    """The events the motion losses at ``t1`` compare against (``motion_events``): read while
    the step's renders are drawn, as they need none of them."""

    flow: tuple[torch.Tensor, torch.Tensor, int] | None  # L_ef's window after t1; None: no L_ef
    patch_window: tuple[int, int] | None  # L_m's events by index; None: no L_m
    frames: torch.Tensor | None  # [m,H,W] ESI of its m equal-count sub-windows (enough events)
    frame_times: list[float]  # their middle times (µs)


def motion_events(views: Views, lc: LossConfig, t1: int, dtau: int, coarse: bool) -> MotionEvents:
    """The event windows of L_ef (eq. 13: [t1, t1 + dtau]) and L_m (§4.3: m equal-count
    sub-windows of ``lc.motion_window`` from t1) at ``t1``."""
    data = views.data
    flow = views.esi(t1, t1 + dtau, coarse) if lc.w_flow > 0 else None
    if lc.w_motion <= 0:
        return MotionEvents(flow, None, None, [])
    span = int(lc.motion_window * (data.t_end_us - data.t_start_us))
    # By event index, each sub-window's ESI streamed: the window is 2% of the recording.
    store = data.events
    i0, i1 = store.window(t1, min(t1 + span, data.t_end_us))
    if i1 - i0 < lc.patch_m:
        return MotionEvents(flow, (i0, i1), None, [])
    bounds = store.split_equal_count(i0, i1, lc.patch_m)
    frames, times = [], []
    for j in range(lc.patch_m):
        a, b = int(bounds[j]), int(bounds[j + 1])
        frames.append(views.accumulate(a, b)[0])
        times.append(0.5 * (store.time_at(a) + store.time_at(max(b - 1, a))))
    return MotionEvents(flow, (i0, i1), torch.stack(frames), times)


def motion_losses(
    views: Views,
    view: Renderer,
    model: GaussianModel,
    mlp: DeformationMLP,
    lc: LossConfig,
    t1: int,
    dtau: int,
    pose1: np.ndarray,
    out1: RenderOut,
    events: MotionEvents,
    rng: np.random.Generator,
) -> dict[str, torch.Tensor]:
    """L_ef and L_m for the render ``out1`` that ``view`` (full or coarse) made at ``t1``,
    against ``events`` (``motion_events`` at ``t1``)."""
    renderer = views.renderer
    coarse = view is not renderer
    out: dict[str, torch.Tensor] = {}
    # L_ef (eq. 13): linearised event model over [t1, t1 + dtau].
    short, _, count = events.flow or (None, None, 0)
    if count > 0:
        device = out1.depth.device
        w2c1, w2c2 = viewmat(pose1, device), viewmat(views.pose(t1 + dtau), device)
        flow_cam = camera_flow(out1.depth, view.K, w2c1, w2c2)
        pred = views.linearized_change(out1, flow_cam + out1.extra, coarse)
        out["ef"] = event_flow_loss(short, pred)
    # L_m (eq. 15): patches of m equal-count sub-windows around the moving centres.
    if events.patch_window is None:
        return out
    i0, i1 = events.patch_window
    if i1 - i0 >= lc.patch_m:
        gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
        idx = select_visible(
            out1.meta["means2d"],
            out1.meta["depths"],
            out1.depth.detach(),
            lc.patch_n,
            lc.depth_tolerance,
            gen,
        )
        if idx.numel() > 0:
            centres = []
            for t_mid in events.frame_times:
                means = deformed_means(
                    model,
                    mlp,
                    renderer.time(t_mid),
                    idx,
                    renderer.static_mask,
                    renderer.motion,
                    renderer.object_id,
                )
                w2c = viewmat(views.pose(t_mid), means.device)
                centres.append(project_points(means, w2c, renderer.K))
            out["m"] = patch_motion_loss(events.frames, torch.stack(centres, dim=1), lc.patch_side)
    return out


def refine_losses(
    data: Dataset,
    lc: LossConfig,
    depth_prior: DepthPrior | None,
    t1: int,
    out1: RenderOut,
    delta: torch.Tensor,
    mask: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """L_ne and L_sp (eq. 17-18) on the render ``out1`` at ``t1`` and its window's predicted
    log change ``delta`` against the event ``mask``, and L_d (eq. 16) where a depth prior
    exists."""
    out = {}
    if lc.w_non_event > 0:
        out["ne"] = non_event_loss(delta, mask, min(data.c_pos, data.c_neg))
    if lc.w_spatial > 0:
        out["sp"] = spatial_gradient_loss(out1.image)
    if depth_prior is not None and lc.w_depth > 0:
        prior = depth_prior.depth(t1, out1.image.detach())
        if prior is not None:
            valid = (prior > 0) & (out1.alpha.detach() > lc.depth_min_alpha)
            if bool(valid.any()):
                out["d"] = silog(out1.depth, prior, valid)
    return out
