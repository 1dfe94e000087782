"""Event flow loss L_ef (paper eq. 10-13): linearised event model with camera + Gaussian flow."""

from __future__ import annotations

import torch
from torch import Tensor

from evsplat.losses.event import masked_mean

MIN_DEPTH = 1e-6  # guard: depth at or below this is "nothing there" (flow 0) / clamped
NORM_EPS = 1e-10  # guard: mean square floor of eq. 13 (RMS 1e-5, far below a real change)


def _project(cam: Tensor, K: Tensor) -> Tensor:
    """Pixel coordinates [...,2] of camera-frame points [...,3] (z clamped to MIN_DEPTH)."""
    z = cam[..., 2:3].clamp_min(MIN_DEPTH)
    uv = cam[..., :2] / z
    return uv * torch.stack([K[0, 0], K[1, 1]]) + torch.stack([K[0, 2], K[1, 2]])


def camera_flow(depth: Tensor, K: Tensor, w2c_a: Tensor, w2c_b: Tensor) -> Tensor:
    """Flow [H,W,2] (x, y pixels) of a static scene from view a to view b (eq. 10-11).

    Each pixel centre (j+.5, i+.5) is lifted with its z-depth ``depth [H,W]`` in camera a,
    moved into camera b and projected. Pixels with depth <= 1e-6 (nothing rendered) or whose
    point falls behind camera b get flow 0.
    """
    h, w = depth.shape
    kw = {"dtype": depth.dtype, "device": depth.device}
    ys, xs = torch.meshgrid(torch.arange(h, **kw) + 0.5, torch.arange(w, **kw) + 0.5, indexing="ij")
    pix = torch.stack([xs, ys], dim=-1)  # [H,W,2]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    valid_a = depth > MIN_DEPTH
    d = torch.where(valid_a, depth, torch.ones_like(depth))
    cam_a = torch.stack([(xs - cx) / fx * d, (ys - cy) / fy * d, d], dim=-1)
    # a -> b: w2c_b · c2w_a, with the rigid inverse of w2c_a written out.
    r_a, t_a = w2c_a[:3, :3], w2c_a[:3, 3]
    rel_r = w2c_b[:3, :3] @ r_a.T
    rel_t = w2c_b[:3, 3] - rel_r @ t_a
    cam_b = cam_a @ rel_r.T + rel_t
    valid = valid_a & (cam_b[..., 2] > MIN_DEPTH)
    flow = _project(cam_b, K) - pix
    return torch.where(valid[..., None], flow, torch.zeros_like(flow))


def gaussian_flow_features(means_t: Tensor, means_t2: Tensor, viewmat: Tensor, K: Tensor) -> Tensor:
    """[N,2] pixel motion of each Gaussian from ``means_t`` to ``means_t2`` seen from one fixed
    pose ``viewmat`` (world-to-camera): the Gaussian flow F^G, rendered as 2 extra channels."""
    r, t = viewmat[:3, :3], viewmat[:3, 3]
    return _project(means_t2 @ r.T + t, K) - _project(means_t @ r.T + t, K)


def _central_diff(x: Tensor, dim: int) -> Tensor:
    """Derivative along ``dim``: central differences inside, one-sided at the borders (0 for a
    single sample), like numpy.gradient."""
    n = x.shape[dim]
    if n < 2:
        return torch.zeros_like(x)
    first = x.narrow(dim, 1, 1) - x.narrow(dim, 0, 1)
    last = x.narrow(dim, n - 1, 1) - x.narrow(dim, n - 2, 1)
    inner = (x.narrow(dim, 2, n - 2) - x.narrow(dim, 0, n - 2)) / 2.0
    return torch.cat([first, inner, last], dim=dim)


def linearized_brightness_change(log_img: Tensor, flow: Tensor) -> Tensor:
    """ΔÎ ≈ -∇L · F (eq. 3 / 13) for log image ``log_img [H,W]`` (or ``[C,H,W]``, one flow for
    every channel) and ``flow [H,W,2]`` in pixels over the whole interval Δτ (so no extra Δτ
    factor)."""
    gx = _central_diff(log_img, -1)
    gy = _central_diff(log_img, -2)
    return -(gx * flow[..., 0] + gy * flow[..., 1])


def _unit_rms(x: Tensor, mask: Tensor | None) -> Tensor:
    """x / RMS(x) over the mask; an all-zero map stays zero (finite gradient)."""
    ms = masked_mean(x * x, mask)
    return x / torch.sqrt(ms + NORM_EPS)


def event_flow_loss(
    delta_obs_short: Tensor, delta_pred_lin: Tensor, mask: Tensor | None = None
) -> Tensor:
    """L_ef (eq. 13): mean |ΔI'/‖ΔI'‖ - ΔÎ/‖ΔÎ‖| over the (masked) pixels, both [H,W].

    Each map is divided by its root mean square, i.e. its L2 norm / sqrt(#pixels): this is
    eq. 13 up to the constant sqrt(#pixels), so the value lies in [0, 2] at any resolution and
    does not depend on Δτ or the contrast threshold.
    """
    if delta_obs_short.shape != delta_pred_lin.shape:
        raise ValueError(
            f"event_flow_loss: ESI {tuple(delta_obs_short.shape)} vs "
            f"prediction {tuple(delta_pred_lin.shape)}"
        )
    diff = _unit_rms(delta_obs_short, mask) - _unit_rms(delta_pred_lin, mask)
    return masked_mean(diff.abs(), mask)
