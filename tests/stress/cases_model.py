"""Stress cases of the Gaussian activations and the rasterizer."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

from tests.stress.harness import Arrays, Case, grads, leaf

# ---- model activations ---------------------------------------------------------------------------


def _model_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.model.gaussians import GaussianModel

    n = int(r.integers(1, 16))
    model = GaussianModel(n, int(r.choice([1, 3])), sh_degree=int(r.integers(0, 4)))
    with torch.no_grad():
        model.means.copy_(torch.as_tensor(r.normal(size=(n, 3)) * float(r.choice([1e-6, 1, 1e6]))))
        big = float(r.choice([1e-30, 1.0, 1e4, 1e30]))
        model.log_scales.copy_(torch.as_tensor(r.uniform(-big, big, (n, 3))))
        model.opacity_logits.copy_(torch.as_tensor(r.uniform(-big, big, n)))
        model.sh.copy_(torch.as_tensor(r.normal(size=model.sh.shape)))
        if kind == "zero_quats":
            model.quats.zero_()
        else:
            mag = float(r.choice([1e-30, 1e-12, 1e-6, 1.0, 1e6, 1e18, 1e30]))
            model.quats.copy_(torch.as_tensor(r.normal(size=(n, 4)) * mag))
    centre = torch.as_tensor(r.normal(size=3), dtype=torch.float32)
    if kind == "camera_on_a_mean":
        centre = model.means.detach()[0].clone()
    scales, opac, rots = model.scales(), model.opacities(), model.rotations()
    colors = model.colors(centre)
    loss = scales.sum() + opac.sum() + rots.sum() + colors.sum()
    loss.backward()
    norms = rots.detach().norm(dim=-1)
    assert torch.allclose(norms, torch.ones_like(norms), atol=1e-4), "rotation not unit length"
    assert bool(((opac >= 0) & (opac <= 1)).all()), "opacity outside [0, 1]"
    return [scales, opac, rots, colors, *[p.grad for p in model.parameters() if p.grad is not None]]


def model_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Gaussian activations: log-scales and opacity logits up to ±1e30, zero / tiny / huge
    quaternions, SH colour seen from a camera sitting on a Gaussian."""
    kinds = ["zero_quats", "camera_on_a_mean", "random"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        kind = kinds[i % len(kinds)]
        yield Case("model", kind, lambda r=r, k=kind: _model_case(r, k))


# ---- rasterizer (small cases: each call runs on the GPU context) ---------------------------------


def _raster_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.raster import rasterize

    n = int(r.integers(1, 8))
    w, h = int(r.integers(1, 24)), int(r.integers(1, 24))
    if kind == "1x1":
        w = h = 1
    elif kind == "aspect":
        w, h = (1, 96) if r.random() < 0.5 else (96, 1)
    means = np.column_stack([r.normal(size=(n, 2)), r.uniform(1, 5, n)])
    scales = np.exp(r.uniform(-3, 0, (n, 3)))
    quats = r.normal(size=(n, 4))
    near = 0.01
    if kind == "degenerate":
        scales[:] = 0.0
    elif kind == "tiny":
        scales[:] = 1e-7
    elif kind == "huge":
        scales[:] = float(r.choice([1e2, 1e4, 1e6]))
    elif kind == "flat":
        scales[:, int(r.integers(0, 3))] = float(r.choice([0.0, 1e-9]))
    elif kind == "behind":
        means[:, 2] = -np.abs(means[:, 2])
    elif kind == "near_plane":
        means[:, 2] = near + r.choice([-1e-7, 0.0, 1e-7, 1e-4], n)
    elif kind == "coincident":
        means[:] = means[0]
    elif kind == "off_screen":
        means[:, :2] = r.choice([-1.0, 1.0], (n, 2)) * float(r.choice([1e2, 1e6]))
    elif kind == "zero_quats":
        quats[:] = 0.0
    f = float(r.choice([0.5, 50.0, 5e4]))
    K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], dtype=torch.float32)
    m, q, s = leaf(means), leaf(quats), leaf(scales)
    o = leaf(r.choice([0.0, 1.0, 0.5], n) if kind == "opacity_edges" else r.random(n))
    feats = leaf(r.random((n, int(r.integers(1, 4)))))
    image, depth, alpha, meta = rasterize(m, q, s, o, feats, torch.eye(4), K, w, h, near=near)
    weights = [
        torch.as_tensor(r.normal(size=t.shape), dtype=torch.float32) for t in (image, depth, alpha)
    ]
    loss = (image * weights[0]).sum() + (depth * weights[1]).sum() + (alpha * weights[2]).sum()
    loss.backward()
    a = alpha.detach()
    assert bool(((a >= 0) & (a <= 1 + 1e-6)).all()), "alpha outside [0, 1]"
    return [image, depth, alpha, meta["means2d"], *grads(m, q, s, o, feats)]


def _bad_raster(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.raster import rasterize

    n = 2
    args = [torch.zeros(n, 3), torch.ones(n, 4), torch.ones(n, 3), torch.ones(n), torch.ones(n, 1)]
    args[0][:, 2] = 2.0
    if kind == "nan_means":
        args[0][0, 0] = float("nan")
    elif kind == "inf_scales":
        args[2][1, 1] = float("inf")
    size = (0, 4) if kind == "zero_width" else (4, 4)
    rasterize(*args, torch.eye(4), torch.eye(3), *size)
    return []


def raster_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Rasterizer: degenerate / tiny / huge / flat / behind-camera / near-plane / coincident /
    off-screen Gaussians, zero quaternions, opacity 0 and 1, 1x1 images, 1x96 and 96x1 images;
    NaN means, infinite scales and a zero-width image must be refused."""
    kinds = ["degenerate", "tiny", "huge", "flat", "behind", "near_plane", "coincident",
             "off_screen", "zero_quats", "opacity_edges", "1x1", "aspect", "random"]  # fmt: skip
    bad = ["nan_means", "inf_scales", "zero_width"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 14 == 13:
            kind = bad[(i // 14) % len(bad)]
            yield Case("raster", kind, lambda r=r, k=kind: _bad_raster(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            yield Case("raster", kind, lambda r=r, k=kind: _raster_case(r, k))
