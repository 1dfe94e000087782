"""Depth loss L_d (paper eq. 16): scale-invariant log error against a depth prior."""

from __future__ import annotations

import torch
from torch import Tensor


def silog(pred: Tensor, prior: Tensor, mask: Tensor | None = None, eps: float = 1e-6) -> Tensor:
    """L_d = 1/n Σ α_i² - 1/n² (Σ α_i)², α_i = log d_i - log d̂_i (eq. 16).

    ``pred`` is the rendered depth d̂, ``prior`` the estimated depth d (same shape). Pixels with
    either depth <= ``eps`` (nothing rendered, invalid prior) are left out, as are those outside
    ``mask``; with none left the loss is 0. Computed as the variance of α, which equals eq. 16
    and cannot round below zero; multiplying either depth by a constant leaves it unchanged.
    """
    if pred.shape != prior.shape:
        raise ValueError(f"silog: rendered {tuple(pred.shape)} vs prior {tuple(prior.shape)}")
    valid = (pred > eps) & (prior > eps)
    if mask is not None:
        valid = valid & mask.to(torch.bool)
    one = torch.ones_like(pred)
    alpha = torch.log(torch.where(valid, prior, one)) - torch.log(torch.where(valid, pred, one))
    w = valid.to(pred.dtype)
    n = w.sum().clamp_min(1.0)
    mean = (alpha * w).sum() / n
    return (((alpha - mean) ** 2) * w).sum() / n
