"""SiLog depth loss (eq. 16) against a direct numpy evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsplat.losses.depth import silog


def silog_numpy(pred: np.ndarray, prior: np.ndarray) -> float:
    """Eq. 16 written as printed: 1/n Σα² - 1/n² (Σα)²."""
    alpha = np.log(prior) - np.log(pred)
    n = alpha.size
    return float((alpha**2).sum() / n - alpha.sum() ** 2 / n**2)


def test_silog_matches_equation_16_in_numpy():
    rng = np.random.default_rng(0)
    pred, prior = rng.uniform(0.5, 5.0, (2, 12, 9))
    got = silog(torch.tensor(pred), torch.tensor(prior))
    assert float(got) == pytest.approx(silog_numpy(pred, prior), rel=1e-9)


@pytest.mark.parametrize("s", [0.01, 0.5, 3.0, 250.0])
def test_silog_is_invariant_to_the_scale_of_either_depth(s):
    rng = np.random.default_rng(1)
    pred = torch.tensor(rng.uniform(0.5, 5.0, (10, 10)))
    prior = torch.tensor(rng.uniform(0.5, 5.0, (10, 10)))
    base = float(silog(pred, prior))
    assert base > 0.01
    assert float(silog(pred * s, prior)) == pytest.approx(base, rel=1e-9)
    assert float(silog(pred, prior * s)) == pytest.approx(base, rel=1e-9)
    assert float(silog(pred, pred * s)) == pytest.approx(0.0, abs=1e-12)


def test_silog_leaves_out_zero_depths_and_masked_pixels_with_finite_gradients():
    rng = np.random.default_rng(2)
    pred_np, prior_np = rng.uniform(0.5, 5.0, (2, 6, 6))
    pred_np[0, :3] = 0.0  # nothing rendered
    prior_np[1, 2] = 0.0  # invalid prior
    mask_np = np.ones((6, 6), bool)
    mask_np[5] = False
    valid = (pred_np > 0) & (prior_np > 0) & mask_np
    pred = torch.tensor(pred_np, requires_grad=True)
    loss = silog(pred, torch.tensor(prior_np), torch.tensor(mask_np))
    loss.backward()
    assert float(loss.detach()) == pytest.approx(
        silog_numpy(pred_np[valid], prior_np[valid]), rel=1e-9
    )
    assert torch.isfinite(pred.grad).all()
    assert torch.all(pred.grad[torch.tensor(~valid)] == 0)


def test_silog_is_zero_with_finite_gradient_when_no_pixel_is_valid():
    pred = torch.zeros(4, 4, requires_grad=True)
    loss = silog(pred, torch.zeros(4, 4))
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.isfinite(pred.grad).all()
