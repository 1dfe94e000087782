"""Coarse-to-fine: early iterations render at half resolution and compare with 2x2-binned events.

A 2x2 block of an RGGB-like mosaic holds one pixel of every colour, so binning the event image
per channel gives a full-colour half-resolution ESI: the coarse render is compared channel by
channel with no Bayer selection. Halving both image axes with pixel centres at (j + 0.5, i + 0.5)
is exactly K with its first two rows halved.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from evsplat.config import TrainConfig
from evsplat.render import Renderer
from evsplat.train.stages import Stage


def coarse_due(cfg: TrainConfig, iteration: int, stage: Stage) -> bool:
    """Whether ``iteration`` renders at half resolution (``SkipConfig.coarse_fraction``)."""
    end = int(round(cfg.skips.coarse_fraction * cfg.schedule.iterations))
    return iteration < end and stage is not Stage.REFINE


def half_renderer(renderer: Renderer) -> Renderer:
    """The same scene and camera at half the resolution (odd last rows/columns dropped)."""
    scale = torch.tensor([[0.5], [0.5], [1.0]], dtype=renderer.K.dtype, device=renderer.K.device)
    return dataclasses.replace(
        renderer, K=renderer.K * scale, width=renderer.width // 2, height=renderer.height // 2
    )


def _blocks(x: Tensor) -> Tensor:
    """[H,W] -> [H/2, W/2, 4]: each output pixel's 2x2 block of inputs (odd edges dropped)."""
    h, w = x.shape[0] // 2 * 2, x.shape[1] // 2 * 2
    b = x[:h, :w].reshape(h // 2, 2, w // 2, 2)
    return b.permute(0, 2, 1, 3).reshape(h // 2, w // 2, 4)


def bin_events(esi: Tensor, mask: Tensor, channel_map: Tensor | None) -> tuple[Tensor, Tensor]:
    """Half-resolution (ESI, event mask) of a full-resolution window.

    Mono: the mean log change of each 2x2 block, ``[H/2, W/2]``. Colour (``channel_map [H,W]``
    of 0/1/2): per channel the mean over the block's pixels of that colour, ``[3, H/2, W/2]``.
    A block has events when any of its pixels has; a pixel without events still says its log
    change stayed below the threshold, so the whole block is compared.
    """
    values = _blocks(esi)
    has = _blocks(mask.to(torch.bool)).any(dim=-1)
    if channel_map is None:
        return values.mean(dim=-1), has
    which = _blocks(channel_map.to(torch.long))
    out = []
    for c in range(3):
        sel = (which == c).to(values.dtype)
        out.append((values * sel).sum(-1) / sel.sum(-1).clamp_min(1.0))
    return torch.stack(out), has
