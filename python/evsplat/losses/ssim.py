"""Structural similarity (Wang et al. 2004) with a Gaussian window, as 3DGS computes it."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def gaussian_window(window: int, sigma: float, device: torch.device | None = None) -> Tensor:
    """Normalised 1-D Gaussian weights of length ``window`` (on ``device``, default the CPU)."""
    x = torch.arange(window, dtype=torch.float32, device=device) - (window - 1) / 2.0
    w = torch.exp(-(x * x) / (2.0 * sigma * sigma))
    return w / w.sum()


def ssim(
    a: Tensor, b: Tensor, window: int = 11, sigma: float = 1.5, data_range: float | None = None
) -> Tensor:
    """Mean SSIM of ``a`` and ``b`` ([H,W], [C,H,W] or [B,C,H,W]), per channel, averaged.

    Local statistics use a ``window``-wide Gaussian (std ``sigma``) with zero padding so the
    map has the image's size (3DGS convention). C1 = (0.01 L)^2, C2 = (0.03 L)^2 with
    L = ``data_range`` (default 1, for images in [0, 1]); both are > 0, so constant or zero
    images give finite values and gradients (identical images give exactly 1).
    """
    if a.shape != b.shape or a.dim() not in (2, 3, 4):
        raise ValueError(f"ssim: shapes {tuple(a.shape)} and {tuple(b.shape)}; need equal 2-4-D")
    shape4 = a.reshape(-1, *a.shape[-3:]) if a.dim() == 4 else a.reshape(1, -1, *a.shape[-2:])
    a4, b4 = shape4, b.reshape(shape4.shape)
    channels = a4.shape[1]
    g = gaussian_window(window, sigma, a.device).to(a.dtype)
    # The five local statistics in one separable pass (a row then a column convolution): the
    # same sums as the 11x11 window with zero padding, at 2/11 of the multiply-adds.
    stack = torch.cat([a4, b4, a4 * a4, b4 * b4, a4 * b4], dim=1)
    k = 5 * channels
    pad = window // 2
    rows = F.conv2d(
        stack, g.reshape(1, 1, 1, -1).expand(k, 1, 1, window), padding=(0, pad), groups=k
    )
    blurred = F.conv2d(
        rows, g.reshape(1, 1, -1, 1).expand(k, 1, window, 1), padding=(pad, 0), groups=k
    )
    mu_a, mu_b, e_aa, e_bb, e_ab = blurred.split(channels, dim=1)
    # Not clamped at 0: identical inputs then give cov == var exactly (SSIM exactly 1), and
    # the rounding below zero is far smaller than C2.
    var_a = e_aa - mu_a * mu_a
    var_b = e_bb - mu_b * mu_b
    cov = e_ab - mu_a * mu_b
    rng = 1.0 if data_range is None else float(data_range)
    if not rng > 0:
        raise ValueError(f"ssim: data_range={data_range}; it must be positive")
    c1, c2 = (0.01 * rng) ** 2, (0.03 * rng) ** 2
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2)
    return (num / den).mean()
