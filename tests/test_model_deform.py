"""Deformation MLP: identity start, architecture shapes, encoding, masked (static) Gaussians."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from evsplat.config import ModelConfig, preset
from evsplat.model.deform import DeformationMLP, deformed, deformed_means, positional_encoding
from evsplat.model.gaussians import GaussianModel


def test_mlp_starts_as_the_identity_deformation():
    mlp = DeformationMLP(ModelConfig())
    x = torch.randn(20, 3)
    for t in (0.0, 0.37, 1.0):
        dx, dq, ds = mlp(x, t)
        assert torch.equal(dx, torch.zeros(20, 3)) and torch.equal(dq, torch.zeros(20, 4))
        assert torch.equal(ds, torch.zeros(20, 3))
    model = GaussianModel.random_init(20, 1, [0, 0, 0], [1, 1, 1])
    with torch.no_grad():
        model.quats.copy_(torch.randn(20, 4))
    means, rots, scales = deformed(model, mlp, 0.5)
    assert torch.equal(means, model.means)
    assert torch.allclose(rots, model.rotations(), atol=1e-7)
    assert torch.allclose(scales, model.scales())


def test_mlp_layers_follow_deformable_3dgs_encoding_and_skip_shapes():
    mlp = DeformationMLP(preset("paper").model)  # Deformable-3DGS's 8x256, skip at layer 4
    # γ(x): 3 + 3·2·10 = 63, γ(t): 1 + 2·6 = 13.
    assert mlp.input_dim == 76
    assert len(mlp.layers) == 8
    ins = [layer.in_features for layer in mlp.layers]
    assert ins == [76, 256, 256, 256, 256, 256 + 76, 256, 256]
    assert all(layer.out_features == 256 for layer in mlp.layers)
    assert (mlp.head_dx.out_features, mlp.head_dq.out_features, mlp.head_ds.out_features) == (
        3,
        4,
        3,
    )
    small = DeformationMLP(
        dataclasses.replace(ModelConfig(), mlp_width=32, mlp_depth=4, mlp_skip=1)
    )
    assert [layer.in_features for layer in small.layers] == [76, 32, 32 + 76, 32]
    with pytest.raises(ValueError, match="skip"):
        DeformationMLP(dataclasses.replace(ModelConfig(), mlp_depth=4, mlp_skip=3))


def test_positional_encoding_matches_nerf_formula():
    p = np.array([[0.3, -1.2], [2.0, 0.1]])
    expected = [p]
    expected += [np.sin(p * 2.0**k) for k in range(3)]
    expected += [np.cos(p * 2.0**k) for k in range(3)]
    got = positional_encoding(torch.tensor(p), 3).numpy()
    # Layout: input, then all sines (frequency-major), then all cosines.
    np.testing.assert_allclose(got, np.concatenate(expected, axis=1), atol=1e-12)
    mlp = DeformationMLP(ModelConfig())
    enc = mlp.encode(torch.tensor([[0.1, 0.2, 0.3]]), 0.5)
    np.testing.assert_allclose(
        enc[0, 63:].numpy(), positional_encoding(torch.tensor([[0.5]]), 6)[0]
    )


def _trained_like(mlp: DeformationMLP) -> None:
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for head in (mlp.head_dx, mlp.head_dq, mlp.head_ds):
            head.weight.copy_(torch.randn(head.weight.shape, generator=gen) * 0.05)


def test_deformed_mask_keeps_static_gaussians_canonical_and_moves_the_rest():
    cfg = dataclasses.replace(ModelConfig(), mlp_width=32, mlp_depth=4, mlp_skip=1)
    mlp = DeformationMLP(cfg)
    _trained_like(mlp)
    model = GaussianModel.random_init(10, 1, [0, 0, 0], [1, 1, 1])
    mask = torch.arange(10) % 3 == 0
    means, rots, scales = deformed(model, mlp, 0.6, mask=mask)
    full = deformed(model, mlp, 0.6)
    assert torch.equal(means[~mask], model.means[~mask])
    assert torch.allclose(rots[~mask], model.rotations()[~mask])
    assert torch.equal(scales[~mask], model.scales()[~mask])
    assert torch.allclose(means[mask], full[0][mask], atol=1e-6)
    assert torch.allclose(rots[mask], full[1][mask], atol=1e-6)
    assert torch.allclose(scales[mask], full[2][mask], atol=1e-6)
    assert not torch.allclose(means[mask], model.means[mask])
    assert torch.allclose(rots.norm(dim=-1), torch.ones(10), atol=1e-6)


def test_deformed_with_every_gaussian_static_is_canonical():
    cfg = dataclasses.replace(ModelConfig(), mlp_width=32, mlp_depth=4, mlp_skip=1)
    mlp = DeformationMLP(cfg)
    _trained_like(mlp)
    model = GaussianModel.random_init(5, 1, [0, 0, 0], [1, 1, 1])
    means, _, scales = deformed(model, mlp, 0.6, mask=torch.zeros(5, dtype=torch.bool))
    assert torch.equal(means, model.means) and torch.equal(scales, model.scales())


def test_deformed_is_canonical_without_mlp_and_gradients_reach_mlp_and_gaussians():
    model = GaussianModel.random_init(6, 1, [0, 0, 0], [1, 1, 1])
    means, rots, scales = deformed(model, None, 0.3)
    assert means is model.means
    mlp = DeformationMLP(dataclasses.replace(ModelConfig(), mlp_width=16, mlp_depth=3, mlp_skip=0))
    _trained_like(mlp)
    with torch.no_grad():
        model.quats.zero_()  # degenerate rotations stay finite
    out = deformed(model, mlp, torch.tensor(0.25))
    sum(o.sum() for o in out).backward()
    assert torch.isfinite(model.means.grad).all() and torch.isfinite(model.log_scales.grad).all()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in mlp.parameters())


def test_deformed_means_of_some_rows_match_the_full_deformation_with_a_static_mask():
    torch.manual_seed(0)
    model = GaussianModel.random_init(40, 3, [0, 0, 0], [1, 1, 1], seed=0)
    mlp = DeformationMLP(ModelConfig(mlp_width=16, mlp_depth=3, mlp_skip=1, pe_x=2, pe_t=2))
    for head in (mlp.head_dx, mlp.head_dq, mlp.head_ds):
        torch.nn.init.normal_(head.weight, std=0.3)
    static = torch.rand(40, generator=torch.Generator().manual_seed(1)) < 0.5
    rows = torch.tensor([0, 3, 4, 17, 39, 22])
    full = deformed(model, mlp, 0.3, mask=~static)[0][rows]
    got = deformed_means(model, mlp, 0.3, rows, static)
    torch.testing.assert_close(got, full)
    assert bool(static[rows].any()) and bool((~static[rows]).any())
    torch.testing.assert_close(got[static[rows]], model.means[rows][static[rows]])
    all_moving = deformed(model, mlp, 0.3)[0][rows]
    torch.testing.assert_close(deformed_means(model, mlp, 0.3, rows), all_moving)
