"""Every loss's analytic gradient against finite differences (torch.autograd.gradcheck, float64)."""

from __future__ import annotations

import torch
from torch.autograd import gradcheck

from evsplat.losses.depth import silog
from evsplat.losses.event import event_loss, log_render
from evsplat.losses.flow import (
    camera_flow,
    event_flow_loss,
    gaussian_flow_features,
    linearized_brightness_change,
)
from evsplat.losses.patch import patch_motion_loss
from evsplat.losses.reg import non_event_loss, spatial_gradient_loss
from evsplat.losses.ssim import ssim

D = torch.float64


def rand(*shape, lo=0.0, hi=1.0, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=D)).requires_grad_(True)


K = torch.tensor([[20.0, 0, 6.0], [0, 22.0, 5.0], [0, 0, 1]], dtype=D)


def test_event_loss_and_ssim_gradients_match_finite_differences():
    obs = rand(2, 9, 9, lo=-0.5, hi=0.5, seed=1).detach()
    mask = torch.rand(9, 9, generator=torch.Generator().manual_seed(2)) > 0.5
    img0 = rand(2, 9, 9, seed=4).detach()
    assert gradcheck(
        lambda a: event_loss(log_render(a) - log_render(img0), obs, mask, 0.2),
        (rand(2, 9, 9, seed=3),),
        fast_mode=True,
    )
    assert gradcheck(lambda a: ssim(a, obs, window=5), (rand(2, 9, 9, seed=5),), fast_mode=True)


def test_flow_gradients_match_finite_differences():
    w2c_b = torch.eye(4, dtype=D)
    w2c_b[:3, 3] = torch.tensor([0.1, -0.05, 0.02], dtype=D)
    depth = rand(6, 7, lo=1.0, hi=3.0, seed=6)
    assert gradcheck(lambda d: camera_flow(d, K, torch.eye(4, dtype=D), w2c_b), (depth,))
    m0, m1 = rand(4, 3, lo=-0.5, hi=0.5, seed=7), rand(4, 3, lo=-0.5, hi=0.5, seed=8)
    view = torch.eye(4, dtype=D)
    view[2, 3] = 3.0
    assert gradcheck(lambda a, b: gaussian_flow_features(a, b, view, K), (m0, m1))
    short = rand(6, 7, lo=-1, hi=1, seed=9).detach()
    log_img, flow = rand(6, 7, seed=10), rand(6, 7, 2, lo=-1, hi=1, seed=11)
    assert gradcheck(
        lambda li, f: event_flow_loss(short, linearized_brightness_change(li, f)), (log_img, flow)
    )


def test_patch_loss_gradient_with_respect_to_centres_matches_finite_differences():
    frames = rand(3, 10, 10, seed=12).detach()
    # Off the pixel grid's kinks: bilinear interpolation is smooth between sample lines.
    centres = torch.tensor(
        [[[4.3, 5.2], [4.6, 5.4], [4.9, 5.7]], [[2.2, 7.3], [2.4, 7.1], [2.7, 6.8]]], dtype=D
    ).requires_grad_(True)
    assert gradcheck(lambda c: patch_motion_loss(frames, c, 3), (centres,))


def test_depth_and_regulariser_gradients_match_finite_differences():
    prior = rand(5, 5, lo=0.5, hi=4, seed=13).detach()
    assert gradcheck(lambda p: silog(p, prior), (rand(5, 5, lo=0.5, hi=4, seed=14),))
    events = torch.rand(6, 6, generator=torch.Generator().manual_seed(15)) > 0.5
    assert gradcheck(lambda d: non_event_loss(d, events, 0.2), (rand(6, 6, lo=-1, hi=1, seed=16),))
    assert gradcheck(spatial_gradient_loss, (rand(6, 6, 3, seed=17),))
