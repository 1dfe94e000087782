"""Event-based mover initialisation (evsplat.train.mover) against analytic answers."""

from __future__ import annotations

import math

import numpy as np
import torch

from evsplat.camera import project_points, viewmat
from evsplat.config import ModelConfig, MoverConfig
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel
from evsplat.train.mover import (
    find_path,
    fit_mlp_to_path,
    lift,
    locate,
    place_on_mover,
    unexplained,
)


def _ring(h: int, w: int, cx: float, cy: float, r: float, width: float = 1.5) -> torch.Tensor:
    """Energy on a ring (a moving disc's events sit on its outline), pixel centres at +0.5."""
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    d = np.hypot(xs - cx, ys - cy)
    return torch.from_numpy(np.exp(-0.5 * ((d - r) / width) ** 2))


def test_locate_finds_a_ring_centre_and_radius():
    energy = _ring(96, 96, 40.3, 57.8, 14.0)
    energy += 0.02 * torch.rand(96, 96, generator=torch.Generator().manual_seed(0))
    centre, radius, contrast = locate(energy)
    assert np.hypot(*(centre - [40.3, 57.8])) < 0.7
    assert 12.0 < radius < 19.0  # a ring's radius of gyration is its radius
    assert contrast > 3.0


def test_locate_sees_no_blob_in_noise():
    noise = torch.rand(96, 96, generator=torch.Generator().manual_seed(1))
    assert locate(noise)[2] < 1.4  # MoverConfig.min_contrast


def test_unexplained_is_zero_where_the_prediction_matches():
    esi = torch.zeros(32, 32)
    esi[10:20, 10:20] = 0.4
    assert float(unexplained(esi, esi.clone(), 3).abs().max()) == 0.0
    res = unexplained(esi, torch.zeros_like(esi), 3)
    assert res.shape == esi.shape and float(res[15, 15]) > 0.35 and float(res[2, 28]) == 0.0


def test_find_path_follows_a_moving_ring_over_a_static_residual():
    """The mover moves 60 px while a fixed pattern (the static model's own error) stays: the
    per-pixel median over windows removes the pattern, the path follows the ring."""
    h = w = 96
    static = 0.6 * _ring(h, w, 70.0, 20.0, 6.0)  # stronger than the mover at some pixels
    true = lambda t: np.array([20.0 + 60.0 * (t - 0) / 1e6, 60.0 - 20.0 * t / 1e6])  # noqa: E731

    def residual_of(t0: int, t1: int) -> torch.Tensor:
        cx, cy = true(0.5 * (t0 + t1))
        return _ring(h, w, cx, cy, 12.0) + static

    cfg = MoverConfig(windows=12, window=0.02)
    path = find_path(residual_of, 0, 1_000_000, cfg)
    assert path.found.all()
    truth = np.stack([true(t) for t in path.times_us])
    assert np.abs(path.uv - truth).max() < 1.0
    mid = np.array([true(500_000)])
    assert np.abs(path.at(np.array([500_000])) - mid).max() < 1.0


def test_lift_back_projects_onto_the_pixel():
    K = np.array([[100.0, 0, 48], [0, 100.0, 40], [0, 0, 1]])
    c2w = np.eye(4)
    c2w[:3, 3] = [0.3, -0.2, 0.1]
    c2w[:3, :3] = np.array(
        [[math.cos(0.2), 0, math.sin(0.2)], [0, 1, 0], [-math.sin(0.2), 0, math.cos(0.2)]]
    )
    uv = np.array([[10.5, 70.25], [48.0, 40.0]])
    pts = lift(uv, np.array([2.0, 3.5]), np.stack([c2w, c2w]), K)
    back = project_points(
        torch.tensor(pts, dtype=torch.float32),
        viewmat(c2w),
        torch.tensor(K, dtype=torch.float32),
    )
    assert np.abs(back.numpy() - uv).max() < 1e-3
    cam_z = (pts - c2w[:3, 3]) @ c2w[:3, 2]
    assert np.allclose(cam_z, [2.0, 3.5], atol=1e-6)


def test_fit_mlp_to_path_carries_gaussians_along_it():
    cfg = ModelConfig(mlp_width=64, mlp_depth=4, mlp_skip=2, pe_x=3)
    torch.manual_seed(0)
    mlp = DeformationMLP(cfg)
    means = torch.randn(200, 3) * 0.1 + torch.tensor([0.0, 0.0, 3.0])
    times = torch.linspace(0, 1, 11)
    offsets = torch.stack([torch.sin(3 * times), 0.5 * times, 0.1 * times**2], 1)
    rms = fit_mlp_to_path(mlp, means, times, offsets, steps=600, lr=5e-3, seed=0)
    with torch.no_grad():
        for t, goal in zip(times.tolist(), offsets):
            dx = mlp(means, t)[0]
            assert float((dx - goal).norm(dim=1).max()) < 0.08, t
    assert rms < 0.05


def test_place_on_mover_moves_rows_and_clears_their_optimizer_state():
    model = GaussianModel.random_init(50, 3, [0, 0, 0], [1, 1, 1], seed=0)
    opt = torch.optim.Adam([{"params": [p], "lr": 1e-2} for p in model.parameters()])
    loss = sum((p**2).sum() for p in model.parameters())
    loss.backward()
    opt.step()
    before = model.means.detach().clone()
    rows = torch.tensor([3, 7, 11, 40])
    place_on_mover(model, opt, rows, np.array([5.0, 5.0, 5.0]), 0.5, 0.5, seed=0)
    dist = (model.means.detach()[rows] - 5.0).norm(dim=1)
    assert bool((dist <= 0.5 + 1e-6).all())
    assert torch.allclose(model.opacities().detach()[rows], torch.full((4,), 0.5), atol=1e-5)
    keep = torch.ones(50, dtype=torch.bool)
    keep[rows] = False
    assert torch.equal(model.means.detach()[keep], before[keep])
    state = opt.state[model.means]
    assert float(state["exp_avg"][rows].abs().sum()) == 0.0
    assert float(state["exp_avg"][keep].abs().sum()) > 0.0
    assert any(p is model.means for g in opt.param_groups for p in g["params"])
