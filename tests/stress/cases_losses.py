"""Stress cases of the losses and of the evaluation colour fit and metrics."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

from tests.stress.harness import Arrays, Case, grads, leaf

# ---- losses --------------------------------------------------------------------------------------


def _image(r: np.random.Generator, shape: tuple[int, ...], kind: str) -> np.ndarray:
    if kind == "zero":
        return np.zeros(shape, np.float32)
    if kind == "constant":
        return np.full(shape, float(r.choice([-1e3, -1.0, 1e-8, 0.5, 1e3])), np.float32)
    scale = float(r.choice([1e-6, 1.0, 1e3]))
    return (r.normal(size=shape) * scale).astype(np.float32)


def _loss_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.losses.depth import silog
    from evsplat.losses.event import event_loss, log_render
    from evsplat.losses.flow import camera_flow, event_flow_loss, linearized_brightness_change
    from evsplat.losses.patch import patch_motion_loss
    from evsplat.losses.reg import non_event_loss, spatial_gradient_loss
    from evsplat.losses.ssim import ssim

    h, w = int(r.integers(1, 24)), int(r.integers(1, 24))
    img_kind = str(r.choice(["zero", "constant", "random"]))
    mask = torch.as_tensor(r.random((h, w)) < float(r.choice([0.0, 0.5, 1.0])))
    if kind == "ssim":
        a, b = leaf(_image(r, (h, w), img_kind)), leaf(_image(r, (h, w), img_kind))
        out = ssim(a, b, data_range=float(r.choice([1e-3, 1.0, 1e3])))
        out.backward()
        # float32 local variances (E[x^2] - E[x]^2) of values ~1e3 with data_range 1e-3 (C1, C2
        # ~1e-12) round off by ~1e-3 relative; exact SSIM lies in [-1, 1].
        assert -1.0 - 1e-3 <= out.item() <= 1.0 + 1e-3, f"SSIM {out.item()} outside [-1, 1]"
        return [out, *grads(a, b)]
    if kind == "event_loss":
        a, b = leaf(_image(r, (h, w), img_kind)), leaf(_image(r, (h, w), "random"))
        out = event_loss(a, b, mask, float(r.choice([0.0, 0.2, 1.0])))
        out.backward()
        return [out, *grads(a, b)]
    if kind == "silog":
        depth_kind = str(r.choice(["zero", "partial", "huge", "random"]))
        d = np.abs(_image(r, (h, w), "random")) + 0.1
        if depth_kind == "zero":
            d[:] = 0.0
        elif depth_kind == "partial":
            d[r.random((h, w)) < 0.5] = 0.0
        elif depth_kind == "huge":
            d *= 1e30
        pred, prior = leaf(d), leaf(np.abs(_image(r, (h, w), img_kind)))
        out = silog(pred, prior, mask if r.random() < 0.5 else None)
        out.backward()
        return [out, *grads(pred, prior)]
    if kind == "flow":
        log_img = leaf(_image(r, (h, w), img_kind))
        depth = leaf(np.abs(_image(r, (h, w), str(r.choice(["zero", "random"])))))
        fx, fy = float(r.uniform(1, 500)), float(r.uniform(1, 500))
        K = torch.tensor([[fx, 0, w / 2], [0, fy, h / 2], [0, 0, 1]])
        w2c_b = torch.eye(4)
        w2c_b[:3, 3] = torch.as_tensor(r.normal(size=3) * float(r.choice([0.0, 1e-6, 10.0])))
        flow = camera_flow(depth, K, torch.eye(4), w2c_b)
        pred = linearized_brightness_change(log_img, flow)
        obs = leaf(_image(r, (h, w), str(r.choice(["zero", "random"]))))
        out = event_flow_loss(obs, pred, mask if r.random() < 0.5 else None)
        out.backward()
        return [out, flow, *grads(log_img, depth, obs)]
    if kind == "patch":
        m = int(r.integers(1, 5))
        frames = leaf(_image(r, (m, h, w), img_kind))
        far = float(r.choice([1.0, 1e3, 1e6, 1e9]))
        centres = leaf(r.uniform(-far, far, (int(r.integers(0, 6)), m, 2)))
        out = patch_motion_loss(frames, centres, int(r.integers(1, 8)))
        out.backward()
        return [out, *grads(frames, centres)]
    if kind == "reg":
        img = leaf(_image(r, (h, w), img_kind))
        out = non_event_loss(img, mask, float(r.uniform(0.01, 1))) + spatial_gradient_loss(img)
        out = out + log_render(img).mean()
        out.backward()
        return [out, *grads(img)]
    raise AssertionError(kind)


def _bad_loss(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.losses.depth import silog
    from evsplat.losses.event import event_loss
    from evsplat.losses.flow import event_flow_loss
    from evsplat.losses.ssim import ssim

    a, b = torch.zeros(4, 5), torch.zeros(5, 4)
    {
        "ssim_shape": lambda: ssim(a, b),
        "ssim_range": lambda: ssim(a, a, data_range=0.0),
        "silog_shape": lambda: silog(a, b),
        "event_shape": lambda: event_loss(a, b, None, 0.2),
        "flow_shape": lambda: event_flow_loss(a, b),
    }[kind]()
    return []


def loss_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Losses: SSIM on zero-variance images, SiLog with zero / huge depth, the L2-normalised
    flow loss on all-zero maps, patch loss with centres far outside, regularisers on 1-pixel
    images; mismatched shapes must be refused."""
    kinds = ["ssim", "event_loss", "silog", "flow", "patch", "reg"]
    bad = ["ssim_shape", "ssim_range", "silog_shape", "event_shape", "flow_shape"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 10 == 9:
            kind = bad[(i // 10) % len(bad)]
            yield Case("losses", kind, lambda r=r, k=kind: _bad_loss(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            yield Case("losses", kind, lambda r=r, k=kind: _loss_case(r, k))


# ---- evaluation colour fit and metrics -----------------------------------------------------------


def _colour_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.metrics import fit_log_linear, psnr, ssim

    h, w, c = int(r.integers(1, 20)), int(r.integers(1, 20)), int(r.choice([1, 3]))
    gt = r.random((h, w, c)).astype(np.float32)
    pred = r.random((h, w, c)).astype(np.float32) * float(r.choice([1e-6, 1.0, 1e6]))
    if kind in ("constant_pred", "constant_both"):
        pred[:] = float(r.choice([0.0, 1e-9, 0.5, 1.0, 1e9]))
    if kind in ("constant_gt", "constant_both"):
        gt[:] = float(r.choice([0.0, 0.5, 1.0]))
    if kind == "negative":
        pred = -pred
    fit = fit_log_linear(pred, gt)
    assert fit.shape == pred.shape and fit.min() >= 0 and fit.max() <= 1, "fit outside [0, 1]"
    mask = r.random((h, w)) < 0.5
    return [fit, psnr(fit, gt), ssim(fit, gt), psnr(fit, gt, mask) if mask.any() else 0.0]


def colour_fit_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Evaluation colour fit + PSNR/SSIM: constant renders and ground truths, zeros, negative
    and huge renders, 1-pixel images."""
    kinds = ["constant_pred", "constant_gt", "constant_both", "negative", "random"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        kind = kinds[i % len(kinds)]
        yield Case("colour_fit", kind, lambda r=r, k=kind: _colour_case(r, k))
