"""Evaluation protocol: log-space colour fit, PSNR and SSIM against analytic values."""

import numpy as np

from evsplat.metrics import fit_log_linear, psnr, ssim


def test_colour_fit_undoes_an_exact_power_law_per_channel():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.05, 0.95, size=(16, 20, 3)).astype(np.float32)
    a = np.array([0.5, 1.5, 2.0])
    b = np.array([0.1, -0.2, 0.3])
    # render such that log(gt) = a*log(render) + b exactly (up to the tiny log epsilon)
    render = np.exp((np.log(gt) - b) / a).astype(np.float32)
    fitted = fit_log_linear(render, gt, eps=1e-12)
    np.testing.assert_allclose(fitted, gt, atol=1e-4)


def test_colour_fit_of_a_constant_render_is_finite_and_matches_the_mean_log_level():
    gt = np.linspace(0.1, 0.9, 64, dtype=np.float32).reshape(8, 8, 1)
    fitted = fit_log_linear(np.full_like(gt, 0.3), gt)
    assert np.isfinite(fitted).all()
    np.testing.assert_allclose(fitted, np.exp(np.log(gt + 1e-3).mean()) - 1e-3, rtol=2e-2)


def test_psnr_matches_the_analytic_value_and_respects_a_mask():
    a = np.zeros((10, 10, 3), np.float32)
    b = np.full_like(a, 0.1)
    assert abs(psnr(a, b) - 20.0) < 1e-5  # 0.1 is not exact in float32
    mask = np.zeros((10, 10), bool)
    mask[:5] = True
    b[5:] = 1.0  # outside the mask: ignored
    assert abs(psnr(a, b, mask) - 20.0) < 1e-5
    assert psnr(a, a) == 100.0


def test_ssim_is_one_for_identical_images_and_lower_for_noise():
    rng = np.random.default_rng(1)
    img = rng.uniform(size=(32, 32, 3)).astype(np.float32)
    assert abs(ssim(img, img) - 1.0) < 1e-5
    noisy = np.clip(img + rng.normal(0, 0.2, img.shape), 0, 1).astype(np.float32)
    assert ssim(img, noisy) < 0.9
    flat = np.full_like(img, 0.5)
    assert np.isfinite(ssim(flat, flat))
