"""Non-event constraint L_ne (eq. 17) and spatial gradient loss L_sp (eq. 18) vs numpy."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsplat.losses.reg import non_event_loss, spatial_gradient_loss


def test_non_event_loss_matches_hand_computed_value():
    delta = torch.tensor([[0.5, -0.1], [-0.4, 0.05]])
    events = torch.tensor([[True, False], [False, False]])
    # Event-free pixels: ReLU(0.1-0.2)=0, ReLU(0.4-0.2)=0.2, ReLU(0.05-0.2)=0 -> mean 0.2/3.
    assert float(non_event_loss(delta, events, 0.2)) == pytest.approx(0.2 / 3, abs=1e-7)


def test_non_event_loss_matches_numpy_for_multichannel_changes():
    rng = np.random.default_rng(0)
    delta = rng.normal(0, 0.4, (3, 7, 9))
    events = rng.uniform(size=(7, 9)) > 0.6
    expected = np.maximum(np.abs(delta) - 0.25, 0)[:, ~events].mean()
    got = non_event_loss(torch.tensor(delta), torch.tensor(events), 0.25)
    assert float(got) == pytest.approx(expected, rel=1e-9)


def test_non_event_loss_is_zero_with_finite_gradient_when_every_pixel_has_events():
    delta = torch.ones(4, 4, requires_grad=True)
    loss = non_event_loss(delta, torch.ones(4, 4, dtype=torch.bool), 0.1)
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.isfinite(delta.grad).all()


@pytest.mark.parametrize("shape", [(6, 8), (6, 8, 3)])
def test_spatial_gradient_loss_matches_numpy_finite_differences(shape):
    rng = np.random.default_rng(1)
    img = rng.uniform(size=shape)
    h, w = shape[:2]
    dx = [abs(img[i, j + 1] - img[i, j]) for i in range(h) for j in range(w - 1)]
    dy = [abs(img[i + 1, j] - img[i, j]) for i in range(h - 1) for j in range(w)]
    expected = np.mean(dx) + np.mean(dy)
    assert float(spatial_gradient_loss(torch.tensor(img))) == pytest.approx(expected, rel=1e-9)


def test_spatial_gradient_loss_of_flat_and_single_row_images_is_zero_with_finite_gradient():
    flat = torch.full((5, 5), 0.3, requires_grad=True)
    loss = spatial_gradient_loss(flat)
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.isfinite(flat.grad).all()
    row = torch.tensor([[0.0, 1.0, 3.0]])
    assert float(spatial_gradient_loss(row)) == pytest.approx(1.5)
