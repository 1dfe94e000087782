"""Numerical stress for evsplat.rasterize: degenerate and extreme Gaussians give finite outputs
and gradients; plus the fitting test (Adam on 2k Gaussians against a procedural image)."""

from __future__ import annotations

import math
import time

import pytest
import torch

import evsplat
from tests.test_raster import make_scene


def _finite_render_and_grads(means, quats, scales, opacities, features, viewmat, K, w, h):
    leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, features)]
    image, depth, alpha, meta = evsplat.rasterize(*leaves, viewmat, K, w, h)
    for name, t in (("image", image), ("depth", depth), ("alpha", alpha)):
        assert torch.isfinite(t).all(), name
    (image.sum() + depth.sum() + alpha.sum()).backward()
    for name, t in zip(["means", "quats", "scales", "opacities", "features"], leaves):
        assert torch.isfinite(t.grad).all(), name
    assert torch.isfinite(meta["means2d_grad"]).all()
    return image, depth, alpha, meta


def test_extreme_gaussians_give_finite_outputs_and_gradients():
    w, h = 48, 40
    means, quats, scales, opac, feats, view, K = make_scene(14, 3, w, h, seed=2)
    scales[0] = 1e-8  # needle
    scales[1] = 1e4  # covers everything
    quats[2] = 0.0  # zero quaternion
    means[3, 2] = 0.01  # exactly on the near plane
    means[4, 2] = 0.0  # in the camera plane
    means[5, 2] = -1.0  # behind
    means[6] = torch.tensor([0.0, 0.0, 1e4])  # at the far plane
    means[7] = torch.tensor([1e6, -1e6, 5.0])  # far outside the frustum
    means[8] = torch.tensor([-1e6, 1e6, 1e6])
    means[9] = torch.tensor([0.5, 0.5, 0.02])  # just past the near plane, huge footprint
    opac[10] = 0.0
    opac[11] = 1.0
    _, _, alpha, meta = _finite_render_and_grads(means, quats, scales, opac, feats, view, K, w, h)
    assert alpha.max() > 0.9
    assert not meta["visible"][[4, 5, 7, 8]].any()


def test_a_million_gaussians_on_one_pixel_stay_finite():
    n = 1_000_000
    w = h = 32
    g = torch.Generator().manual_seed(0)
    means = torch.zeros(n, 3)
    means[:, 2] = 2.0 + torch.rand(n, generator=g)
    # All project onto the centre (8.5, 8.5) of one pixel: x/z * 20 + 16 = 8.5.
    means[:, 0] = means[:, 1] = -0.375 * means[:, 2]
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).contiguous()
    scales = torch.full((n, 3), 1e-3)
    opac = torch.rand(n, generator=g)
    feats = torch.rand(n, 1, generator=g)
    K = torch.tensor([[20.0, 0.0, 16.0], [0.0, 20.0, 16.0], [0.0, 0.0, 1.0]])
    image, depth, alpha, meta = _finite_render_and_grads(
        means, quats, scales, opac, feats, torch.eye(4), K, w, h
    )
    # Visible: all but those too faint to draw (opacity < 1/255), which projection culls.
    vis = meta["visible"]
    assert torch.equal(vis, opac >= 1 / 255) and alpha[8, 8] > 0.99
    centre = torch.tensor([8.5, 8.5]).expand(int(vis.sum()), 2)
    assert torch.allclose(meta["means2d"][vis], centre, atol=1e-4)


def _procedural_image(size: int) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    r = 0.5 + 0.4 * torch.sin(6 * xs) * torch.cos(4 * ys)
    gch = ((xs - 0.5) ** 2 + (ys - 0.4) ** 2 < 0.08).float() * 0.7 + 0.15
    b = 0.5 + 0.5 * torch.tanh(8 * (xs + ys - 1.0))
    return torch.stack([r, gch, b], -1)


@pytest.mark.parametrize(
    "size,n,steps",
    [
        (48, 300, 200),  # default: well under a minute
        pytest.param(128, 2000, 300, marks=pytest.mark.benchmark),  # the 2k / 128^2 run
    ],
)
def test_fitting_gaussians_to_a_procedural_image_reaches_30_db(size, n, steps):
    target = _procedural_image(size)
    g = torch.Generator().manual_seed(0)
    f = float(size)
    K = torch.tensor([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
    means = torch.cat([torch.rand(n, 2, generator=g) * 1.0 - 0.5, torch.full((n, 1), 1.0)], 1)
    log_scales = torch.full((n, 3), math.log(0.9 / math.sqrt(n)))
    quats = torch.randn(n, 4, generator=g)
    logit_op = torch.zeros(n)
    colors = torch.rand(n, 3, generator=g)
    params = [means, log_scales, quats, logit_op, colors]
    for p in params:
        p.requires_grad_(True)
    opt = torch.optim.Adam(
        [
            {"params": [means], "lr": 2e-3},
            {"params": [log_scales], "lr": 1e-2},
            {"params": [quats], "lr": 1e-2},
            {"params": [logit_op], "lr": 5e-2},
            {"params": [colors], "lr": 2e-2},
        ]  # fmt: skip
    )
    start = time.perf_counter()
    for _ in range(steps):
        opt.zero_grad()
        image, _, _, _ = evsplat.rasterize(
            means, quats, log_scales.exp(), torch.sigmoid(logit_op), colors, torch.eye(4), K,
            size, size,
        )  # fmt: skip
        loss = (image - target).abs().mean()
        loss.backward()
        opt.step()
    mse = ((image.detach() - target) ** 2).mean()
    psnr = 10 * math.log10(1.0 / float(mse))
    print(f"fitting {n} Gaussians, {size}x{size}, {steps} Adam steps: {psnr:.2f} dB in "
          f"{time.perf_counter() - start:.1f} s")  # fmt: skip
    assert psnr >= 30.0
