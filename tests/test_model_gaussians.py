"""GaussianModel: initialisation, guarded activations, SH colour, optimizer groups, checkpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.config import ModelConfig
from evsplat.model.gaussians import (
    PARAM_NAMES,
    SH_C0,
    T_LOG_SCALE_RANGE,
    GaussianModel,
    color_activation,
    eval_sh,
    quat_to_rotmat,
)
from evsplat.render import Renderer


def test_random_init_places_means_inside_bounds_with_spacing_scale_opacity_and_grey():
    lo, hi = [-1.0, 0.0, 2.0], [1.0, 0.5, 6.0]
    m = GaussianModel.random_init(4000, 3, lo, hi, seed=3)
    means = m.means.detach()
    assert bool((means >= torch.tensor(lo)).all() and (means <= torch.tensor(hi)).all())
    # The box is filled, not a corner of it.
    assert torch.allclose(means.mean(0), torch.tensor([0.0, 0.25, 4.0]), atol=0.1)
    spacing = (2.0 * 0.5 * 4.0 / 4000) ** (1 / 3)
    assert torch.allclose(m.scales(), torch.full((4000, 3), spacing), rtol=1e-5)
    assert torch.allclose(m.opacities(), torch.full((4000,), 0.1), atol=1e-6)
    # Grey: the softplus of 0.5 is within 1e-3 of it.
    assert torch.allclose(m.colors(), torch.full((4000, 3), 0.5), atol=1e-3)
    assert torch.equal(m.rotations(), torch.tensor([1.0, 0, 0, 0]).repeat(4000, 1))


def test_random_init_is_reproducible_by_seed_and_accepts_a_flat_box_and_init_scale():
    a = GaussianModel.random_init(50, 1, [0, 0, 0], [1, 1, 1], seed=7)
    b = GaussianModel.random_init(50, 1, [0, 0, 0], [1, 1, 1], seed=7)
    assert torch.equal(a.means, b.means)
    flat = GaussianModel.random_init(50, 1, [0, 0, 1], [1, 1, 1])
    assert torch.isfinite(flat.scales()).all() and bool((flat.means[:, 2] == 1).all())
    fixed = GaussianModel.random_init(5, 1, [0, 0, 0], [1, 1, 1], init_scale=0.02)
    assert torch.allclose(fixed.scales(), torch.full((5, 3), 0.02))
    with pytest.raises(ValueError, match="bounds"):
        GaussianModel.random_init(5, 1, [0, 0, 0], [1, -1, 1])


def test_rotations_of_zero_quaternions_are_identity_with_finite_gradients():
    m = GaussianModel(3, 1)
    with torch.no_grad():
        m.quats.copy_(torch.tensor([[0.0, 0, 0, 0], [2.0, 0, 0, 0], [0.0, 3.0, 0, 4.0]]))
    r = m.rotations()
    expected = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.0, 0.6, 0, 0.8]])
    assert torch.allclose(r, expected)
    (r * torch.arange(12.0).reshape(3, 4)).sum().backward()
    assert torch.isfinite(m.quats.grad).all()


def test_scales_are_clamped_and_finite_for_extreme_log_scales():
    m = GaussianModel(3, 1)
    with torch.no_grad():
        m.log_scales.copy_(torch.tensor([[-100.0] * 3, [0.0] * 3, [100.0] * 3]))
    s = m.scales()
    assert torch.allclose(s[:, 0], torch.tensor([1e-6, 1.0, 1e3]), rtol=1e-5)
    s.sum().backward()
    assert torch.isfinite(m.log_scales.grad).all()


def test_quat_to_rotmat_matches_rodrigues_formula():
    axis = np.array([1.0, 2.0, -0.5])
    axis /= np.linalg.norm(axis)
    angle = 0.7
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    expected = np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx
    q = torch.tensor([[math.cos(angle / 2), *(math.sin(angle / 2) * axis)]])
    np.testing.assert_allclose(quat_to_rotmat(q)[0].numpy(), expected, atol=1e-12)


def test_colors_of_degree_one_follow_the_3dgs_sh_formula_seen_from_the_camera():
    m = GaussianModel(2, 3, sh_degree=1)
    rng = np.random.default_rng(0)
    sh = rng.normal(0, 0.3, (2, 4, 3))
    means = np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, 4.0]])
    with torch.no_grad():
        m.sh.copy_(torch.tensor(sh))
        m.means.copy_(torch.tensor(means))
    cam = np.array([0.5, -0.5, 0.0])
    d = means - cam
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c0, c1 = 0.28209479177387814, 0.4886025119029199
    x, y, z = d[:, :1], d[:, 1:2], d[:, 2:]
    expected = c0 * sh[:, 0] - c1 * y * sh[:, 1] + c1 * z * sh[:, 2] - c1 * x * sh[:, 3] + 0.5
    got = m.colors(torch.tensor(cam, dtype=torch.float32))

    def softplus(x):  # beta 10, as COLOR_BETA
        return np.logaddexp(0.0, 10.0 * x) / 10.0

    np.testing.assert_allclose(got.detach().numpy(), softplus(expected), atol=1e-6)
    # No camera centre: the view-independent DC band only.
    np.testing.assert_allclose(
        m.colors().detach().numpy(), softplus(c0 * sh[:, 0] + 0.5), rtol=1e-6, atol=1e-7
    )


def test_a_colour_channel_pushed_below_zero_learns_again():
    # 3DGS's max(x, 0) passes no gradient below 0: a channel driven under it stays black. The
    # softplus passes one, however small, and Adam's normalised steps act on it.
    m = GaussianModel(1, 3)
    with torch.no_grad():
        m.sh[:, 0] = (torch.tensor([-1.0, 0.0, 1.0]) - 0.5) / SH_C0  # values -1, 0, 1
    opt = torch.optim.Adam([m.sh], lr=0.05)
    target = torch.full((1, 3), 0.5)
    for _ in range(300):
        opt.zero_grad()
        ((m.colors() - target) ** 2).sum().backward()
        opt.step()
    assert torch.allclose(m.colors(), target, atol=0.02)
    extreme = color_activation(torch.tensor([-1e30, -50.0, 0.0, 50.0, 1e30]))
    assert bool(torch.isfinite(extreme).all() and (extreme >= 0).all())
    assert float(extreme[3]) == pytest.approx(50.0)


def test_sh_basis_up_to_degree_three_is_orthonormal_on_the_sphere():
    # Fibonacci sphere: near-uniform directions, so the mean approximates (1/4π)∫ over S².
    n = 40_000
    k = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * k / n
    phi = math.pi * (1 + 5**0.5) * k
    r = torch.sqrt(1 - z * z)
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)
    one_hot = torch.eye(16, dtype=torch.float64)
    basis = torch.stack(
        [eval_sh(one_hot[j].reshape(1, 16, 1).expand(n, 16, 1), dirs)[:, 0] for j in range(16)],
        dim=1,
    )
    gram = 4 * math.pi * basis.T @ basis / n
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=2e-3)


def test_param_groups_cover_every_parameter_with_3dgs_rates_scaled_by_extent():
    m = GaussianModel(4, 1)
    cfg = ModelConfig()
    groups = m.param_groups(cfg, scene_extent=5.0)
    lrs = {g["name"]: g["lr"] for g in groups}
    assert lrs == {
        "means": pytest.approx(1.6e-4 * 5.0),
        "log_scales": 5e-3,
        "quats": 1e-3,
        "opacity_logits": 5e-2,
        "sh": 2.5e-3,
        "t_mean": cfg.t_mean_lr,  # documented choices, not 3DGS rates
        "t_log_scale": cfg.t_scale_lr,
    }
    grouped = {id(p) for g in groups for p in g["params"]}
    assert grouped == {id(p) for p in m.parameters()}
    torch.optim.Adam(groups, eps=1e-15)  # accepted as is


def test_checkpoint_round_trip_and_foreign_state_is_rejected():
    m = GaussianModel.random_init(10, 3, [0, 0, 0], [1, 1, 1], sh_degree=2, seed=1)
    state = m.state_for_checkpoint()
    back = GaussianModel.from_checkpoint(state)
    for name in PARAM_NAMES:
        assert torch.equal(getattr(back, name), getattr(m, name))
    assert (back.channels, back.sh_degree, back.temporal) == (3, 2, False)
    with pytest.raises(ValueError, match="lacks sh"):
        GaussianModel.from_checkpoint({k: v for k, v in state.items() if k != "sh"})
    bad = dict(state, quats=torch.zeros(10, 3))
    with pytest.raises(ValueError, match="quats has shape"):
        GaussianModel.from_checkpoint(bad)
    nan = dict(state, means=torch.full((10, 3), float("nan")))
    with pytest.raises(ValueError, match="NaN"):
        GaussianModel.from_checkpoint(nan)


def test_time_local_opacity_follows_a_gaussian_in_time_and_is_off_unless_enabled():
    m = GaussianModel.random_init(5, 1, [0, 0, 0], [1, 1, 1], seed=3)
    with torch.no_grad():
        m.opacity_logits.copy_(torch.tensor([0.0, 1.0, -1.0, 2.0, 0.5]))
        m.t_mean.copy_(torch.tensor([0.1, 0.5, 0.9, 0.5, 0.3]))
        m.t_log_scale.copy_(torch.tensor([math.log(0.1), 0.0, math.log(0.2), -30.0, 30.0]))
    peak = 1.0 / (1.0 + np.exp(-np.array([0.0, 1.0, -1.0, 2.0, 0.5])))
    assert torch.allclose(m.opacities(0.4), torch.tensor(peak, dtype=torch.float32))  # off
    m.temporal = True
    # Widths are clamped to [0.02, 20]: -30 gives 0.02 and +30 gives 20.
    width = np.array([0.1, 1.0, 0.2, 0.02, 20.0])
    for t in (0.0, 0.4, 0.5, 1.0):
        mu = np.array([0.1, 0.5, 0.9, 0.5, 0.3])
        want = peak * np.exp(-0.5 * ((t - mu) / width) ** 2)
        assert np.allclose(m.opacities(t).detach().numpy(), want, rtol=1e-5, atol=1e-7)
    assert torch.equal(m.opacities(), torch.sigmoid(m.opacity_logits))  # no time: the peak
    assert math.isclose(math.exp(T_LOG_SCALE_RANGE[0]), 0.02)
    # Gradients reach the time parameters and stay finite at the clamp limits.
    m.opacities(0.45).sum().backward()
    assert torch.isfinite(m.t_mean.grad).all() and m.t_mean.grad[1] != 0
    assert torch.isfinite(m.t_log_scale.grad).all() and m.t_log_scale.grad[0] != 0


def test_start_time_local_narrows_a_random_fraction_and_rejects_bad_settings():
    n = 10_000
    m = GaussianModel.random_init(n, 1, [0, 0, 0], [1, 1, 1], seed=0)
    m.start_time_local(0.3, 0.05, seed=1)
    width = torch.exp(m.t_log_scale.detach())
    local = torch.isclose(width, torch.tensor(0.05))
    # A binomial(n, 0.3) count: within 4 standard deviations; the others keep width 1.
    assert abs(int(local.sum()) - 0.3 * n) < 4 * math.sqrt(n * 0.3 * 0.7)
    assert torch.equal(width[~local], torch.ones(int((~local).sum())))
    again = GaussianModel.random_init(n, 1, [0, 0, 0], [1, 1, 1], seed=0)
    again.start_time_local(0.3, 0.05, seed=1)
    assert torch.equal(again.t_log_scale, m.t_log_scale)  # reproducible by seed
    for fraction, width in ((1.5, 0.05), (0.3, 0.0)):
        with pytest.raises(ValueError, match="start_time_local"):
            m.start_time_local(fraction, width)


def test_a_checkpoint_from_before_time_local_opacity_loads_as_static():
    m = GaussianModel.random_init(6, 1, [0, 0, 0], [1, 1, 1], seed=2)
    m.temporal = True
    state = m.state_for_checkpoint()
    back = GaussianModel.from_checkpoint(state)
    assert back.temporal and torch.equal(back.t_mean, m.t_mean)
    old = {k: v for k, v in state.items() if not k.startswith("t_") and k != "temporal"}
    legacy = GaussianModel.from_checkpoint(old)
    assert not legacy.temporal
    assert torch.equal(legacy.opacities(0.7), torch.sigmoid(m.opacity_logits))


@pytest.mark.parametrize("opacity", [0.0039, 0.0045])
def test_a_gaussian_too_faint_to_draw_at_a_time_is_culled_there(opacity):
    # Time-local opacity at the render's time below 1/255: the rasterizer draws nothing of it
    # and culls it (radius 0, depth 0), so densification and L_m's sampling pass it over.
    m = GaussianModel(1, 1)
    m.temporal = True
    with torch.no_grad():
        m.means.copy_(torch.tensor([[0.0, 0.0, 3.0]]))
        m.log_scales.fill_(math.log(0.3))  # 4 px at f = 40: the centre pixels see ~0.98 of it
        m.opacity_logits.fill_(math.log(0.5))  # peak 1/3
        m.t_mean.fill_(0.0)
        m.t_log_scale.fill_(math.log(0.2))
        m.sh.fill_(0.5 / SH_C0)  # white, against the grey background
    # The time at which the temporal factor brings the peak 1/3 down to `opacity`.
    t = 0.2 * math.sqrt(2 * math.log((1 / 3) / opacity))
    K = torch.tensor([[40.0, 0, 16], [0, 40, 16], [0, 0, 1]])
    out = Renderer(m, None, K, 32, 32, 0, 1_000_000).render(round(t * 1e6), np.eye(4))
    touched = bool((out.image - 0.5).abs().max() > 0)
    assert touched == (opacity > 1 / 255)
    assert (int(out.meta["radii"][0]) > 0) == touched
    assert (float(out.meta["depths"][0]) > 0) == touched
