"""L_e, SSIM, the log intensity and the Bayer selection against independent numpy oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.losses.event import LOG_EPS, bayer_select, event_loss, log_render
from evsplat.losses.ssim import ssim


def ssim_numpy(a: np.ndarray, b: np.ndarray, window=11, sigma=1.5, data_range=1.0) -> float:
    """Reference SSIM written out: explicit Gaussian weights, a loop over the window offsets,
    zero padding, per channel, float64. Inputs [H,W] or [C,H,W]."""
    a = np.asarray(a, np.float64).reshape(-1, *a.shape[-2:])
    b = np.asarray(b, np.float64).reshape(-1, *b.shape[-2:])
    r = window // 2
    g1 = np.array([math.exp(-((k - r) ** 2) / (2 * sigma**2)) for k in range(window)])
    g1 /= g1.sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    values = []
    for ca, cb in zip(a, b):
        h, w = ca.shape
        pa, pb = np.pad(ca, r), np.pad(cb, r)
        stats = np.zeros((5, h, w))
        for dy in range(window):
            for dx in range(window):
                wgt = g1[dy] * g1[dx]
                xa, xb = pa[dy : dy + h, dx : dx + w], pb[dy : dy + h, dx : dx + w]
                stats += wgt * np.stack([xa, xb, xa * xa, xb * xb, xa * xb])
        ma, mb, saa, sbb, sab = stats
        va, vb, cov = saa - ma * ma, sbb - mb * mb, sab - ma * mb
        num = (2 * ma * mb + c1) * (2 * cov + c2)
        den = (ma**2 + mb**2 + c1) * (va + vb + c2)
        values.append(num / den)
    return float(np.mean(values))


def test_ssim_matches_numpy_loop_reference_mono_and_colour():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (3, 20, 17)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1).astype(np.float32)
    got = float(ssim(torch.from_numpy(a), torch.from_numpy(b)))
    assert got == pytest.approx(ssim_numpy(a, b), abs=1e-5)
    got1 = float(ssim(torch.from_numpy(a[0]), torch.from_numpy(b[0]), data_range=2.0))
    assert got1 == pytest.approx(ssim_numpy(a[0], b[0], data_range=2.0), abs=1e-5)
    got7 = float(ssim(torch.from_numpy(a[1]), torch.from_numpy(b[1]), window=7, sigma=1.0))
    assert got7 == pytest.approx(ssim_numpy(a[1], b[1], window=7, sigma=1.0), abs=1e-5)


def test_ssim_of_identical_images_is_one():
    a = torch.rand(2, 12, 12)
    assert float(ssim(a, a.clone())) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("value_a,value_b", [(0.0, 0.0), (0.3, 0.3), (0.0, 0.7)])
def test_ssim_of_constant_images_is_finite_with_finite_gradients(value_a, value_b):
    a = torch.full((16, 16), value_a, requires_grad=True)
    b = torch.full((16, 16), value_b)
    s = ssim(a, b)
    s.backward()
    assert math.isfinite(float(s.detach())) and torch.isfinite(a.grad).all()
    assert float(s.detach()) == pytest.approx(ssim_numpy(a.detach().numpy(), b.numpy()), abs=1e-6)


def test_ssim_rejects_mismatched_shapes_and_nonpositive_range():
    with pytest.raises(ValueError, match="shapes"):
        ssim(torch.zeros(4, 4), torch.zeros(4, 5))
    with pytest.raises(ValueError, match="data_range"):
        ssim(torch.zeros(4, 4), torch.zeros(4, 4), data_range=0.0)


def test_log_render_uses_the_documented_epsilon_and_clamps_negatives():
    img = torch.tensor([0.0, 0.5, -0.2], requires_grad=True)
    out = log_render(img)
    expected = np.log(np.array([0.0, 0.5, 0.0]) + 1e-3)
    assert LOG_EPS == 1e-3
    np.testing.assert_allclose(out.detach().numpy(), expected, rtol=1e-6)
    out.sum().backward()
    assert torch.isfinite(img.grad).all()


def test_event_loss_is_zero_when_renders_reproduce_the_esi_exactly():
    rng = np.random.default_rng(1)
    c = 0.25
    counts = rng.integers(-3, 4, (24, 24))  # signed event count per pixel
    log0 = rng.uniform(np.log(0.05), np.log(0.3), (24, 24))
    # Renders whose log brightness changed by exactly C per event.
    i0 = np.exp(log0) - LOG_EPS
    i1 = np.exp(log0 + c * counts) - LOG_EPS
    delta_pred = log_render(torch.tensor(i1, dtype=torch.float64)) - log_render(
        torch.tensor(i0, dtype=torch.float64)
    )
    esi = torch.tensor(c * counts, dtype=torch.float64)
    mask = torch.from_numpy(counts != 0)
    assert float(event_loss(delta_pred, esi, mask, 0.2)) == pytest.approx(0.0, abs=1e-9)
    assert float(event_loss(delta_pred, esi + 0.1, mask, 0.2)) > 0.05


def test_event_loss_matches_hand_computed_value_on_tiny_example():
    pred = torch.tensor([[0.1, 0.2], [0.3, -0.4]])
    obs = torch.tensor([[0.3, 0.2], [0.0, 0.0]])
    mask = torch.tensor([[True, True], [False, True]])
    # masked |diff| = 0.2, 0.0, 0.4 -> mean 0.2; the unmasked pixel (0.3) does not count.
    assert float(event_loss(pred, obs, mask, 0.0)) == pytest.approx(0.2, abs=1e-7)
    # no mask: (0.2 + 0 + 0.3 + 0.4) / 4
    assert float(event_loss(pred, obs, None, 0.0)) == pytest.approx(0.225, abs=1e-7)


def test_event_loss_combines_masked_l1_and_dssim_like_numpy_reference():
    rng = np.random.default_rng(2)
    pred = rng.normal(0, 0.5, (2, 18, 18)).astype(np.float32)
    obs = rng.normal(0, 0.5, (2, 18, 18)).astype(np.float32)
    mask = rng.uniform(size=(18, 18)) > 0.5
    lam = 0.2
    l1 = np.abs(pred - obs)[:, mask].mean()
    expected = (1 - lam) * l1 + lam * (1 - ssim_numpy(pred, obs)) / 2
    got = event_loss(torch.from_numpy(pred), torch.from_numpy(obs), torch.from_numpy(mask), lam)
    assert float(got) == pytest.approx(expected, abs=1e-5)


def test_event_loss_gradients_are_finite_on_all_zero_images_and_empty_mask():
    pred = torch.zeros(16, 16, requires_grad=True)
    loss = event_loss(pred, torch.zeros(16, 16), torch.zeros(16, 16, dtype=torch.bool), 0.2)
    loss.backward()
    assert float(loss.detach()) == pytest.approx(0.0, abs=1e-7)
    assert torch.isfinite(pred.grad).all()
    img = torch.zeros(16, 16, requires_grad=True)  # black render: the log epsilon keeps it finite
    delta = log_render(img) - log_render(torch.zeros(16, 16))
    event_loss(delta, torch.ones(16, 16), None, 0.2).backward()
    assert torch.isfinite(img.grad).all()


def test_bayer_select_takes_each_pixels_own_colour_channel():
    rng = np.random.default_rng(3)
    img = rng.uniform(size=(6, 8, 3)).astype(np.float32)
    # RGGB: (even, even) R, (odd, odd) B, the rest G.
    cmap = np.ones((6, 8), np.int64)
    cmap[0::2, 0::2] = 0
    cmap[1::2, 1::2] = 2
    expected = np.empty((6, 8), np.float32)
    for i in range(6):
        for j in range(8):
            expected[i, j] = img[i, j, cmap[i, j]]
    got = bayer_select(torch.from_numpy(img), torch.from_numpy(cmap))
    np.testing.assert_array_equal(got.numpy(), expected)
    with pytest.raises(ValueError, match="bayer_select"):
        bayer_select(torch.from_numpy(img), torch.zeros(6, 7, dtype=torch.long))
