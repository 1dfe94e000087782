"""Event photometric loss L_e (paper eq. 7-9) and the log intensity every loss shares."""

from __future__ import annotations

import torch
from torch import Tensor

from evsplat.intensity import LOG_EPS
from evsplat.losses.ssim import ssim


def log_render(img: Tensor, eps: float = LOG_EPS) -> Tensor:
    """log(max(img, 0) + eps) of a rendered image, differentiable: the log brightness an event
    sensor responds to (the simulator's numpy counterpart is ``sensor_log_image``)."""
    return torch.log(img.clamp_min(0.0) + eps)


def masked_mean(x: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``x`` over the pixels where ``mask`` ([H,W], broadcast over leading channel
    axes) is set; 0 (still connected to the graph) when the mask is empty."""
    if mask is None:
        return x.mean()
    m = mask.to(x.dtype).expand_as(x)
    return (x * m).sum() / m.sum().clamp_min(1.0)


def event_loss(
    delta_pred: Tensor, delta_obs: Tensor, mask: Tensor | None, lambda_ssim: float
) -> Tensor:
    """L_e = (1-λ)·mean_mask |ΔÎ - ΔI| + λ·(1 - SSIM(ΔÎ, ΔI)) / 2 (eq. 8-9).

    ``delta_pred`` ΔÎ = log Î(t_k) - log Î(t_k - Δt_k) and ``delta_obs`` ΔI the ESI of the
    window, both [H,W] or [C,H,W]. ``mask`` [H,W] marks pixels with events (eq. 8's m); the
    D-SSIM term compares the whole images since structure includes the event-free areas.
    """
    if delta_pred.shape != delta_obs.shape:
        raise ValueError(
            f"event_loss: prediction {tuple(delta_pred.shape)} vs ESI {tuple(delta_obs.shape)}"
        )
    l1 = masked_mean((delta_pred - delta_obs).abs(), mask)
    if lambda_ssim == 0:
        return l1
    d_ssim = (1.0 - ssim(delta_pred, delta_obs)) / 2.0
    return (1.0 - lambda_ssim) * l1 + lambda_ssim * d_ssim


def bayer_select(img: Tensor, channel_map: Tensor) -> Tensor:
    """``img [H,W,3]`` -> ``[H,W]``: each pixel keeps the colour channel its Bayer filter passes
    (``channel_map [H,W]`` of 0/1/2), so a colour event sensor is compared pixel by pixel."""
    if img.dim() != 3 or img.shape[:2] != channel_map.shape:
        raise ValueError(
            f"bayer_select: image {tuple(img.shape)} and channel map "
            f"{tuple(channel_map.shape)}; need [H,W,3] and [H,W]"
        )
    return torch.gather(img, 2, channel_map.to(torch.long).unsqueeze(-1)).squeeze(-1)
