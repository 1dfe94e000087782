"""Regularisers of the refinement stage: non-event constraint L_ne (eq. 17) and spatial
gradient loss L_sp (eq. 18)."""

from __future__ import annotations

import torch
from torch import Tensor

from evsplat.losses.event import masked_mean


def non_event_loss(delta_pred: Tensor, event_mask: Tensor, c: float) -> Tensor:
    """L_ne = mean over pixels without events of ReLU(|ΔÎ| - C) (eq. 17).

    ``delta_pred`` [H,W] or [C,H,W], ``event_mask`` [H,W] (True where events fired), ``c`` the
    contrast threshold: where no event fired the brightness changed by less than C.
    """
    return masked_mean(torch.relu(delta_pred.abs() - c), ~event_mask.to(torch.bool))


def spatial_gradient_loss(img: Tensor) -> Tensor:
    """L_sp = mean |I(i, j+1) - I(i, j)| + mean |I(i+1, j) - I(i, j)| (eq. 18).

    ``img`` is [H,W] or [H,W,C] (the rasterizer's layout); each term is averaged over its own
    differences; an image 1 pixel wide or high contributes 0 for that direction.
    """
    zero = img.sum() * 0.0
    dx = (img[:, 1:] - img[:, :-1]).abs().mean() if img.shape[1] > 1 else zero
    dy = (img[1:] - img[:-1]).abs().mean() if img.shape[0] > 1 else zero
    return dx + dy
