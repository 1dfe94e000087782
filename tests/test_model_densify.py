"""Densifier: clone / split / prune / opacity reset / cap on constructed cases, Adam in sync."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from evsplat.config import DensifyConfig, ModelConfig
from evsplat.model.densify import Densifier
from evsplat.model.gaussians import PARAM_NAMES, GaussianModel

W = H = 100


def four_gaussians() -> GaussianModel:
    """0 small, 1 large, 2 small, 3 small and nearly transparent (extent 1, dense size 0.01)."""
    m = GaussianModel(4, 1)
    with torch.no_grad():
        m.means.copy_(torch.tensor([[0.0, 0, 2], [0.5, 0, 2], [-0.5, 0, 2], [0, 0.5, 2]]))
        m.log_scales.copy_(
            torch.log(torch.tensor([0.005, 0.05, 0.005, 0.005]))[:, None].repeat(1, 3)
        )
        m.opacity_logits.copy_(torch.logit(torch.tensor([0.5, 0.5, 0.5, 0.001])))
        m.sh.copy_(torch.arange(4.0).reshape(4, 1, 1))
    return m


def adam_with_state(m: GaussianModel) -> torch.optim.Adam:
    """Adam over the model with non-zero moments; parameter values are left as they were."""
    opt = torch.optim.Adam(m.param_groups(ModelConfig()), eps=1e-15)
    saved = [p.detach().clone() for p in m.parameters()]
    for p in m.parameters():
        p.grad = torch.ones_like(p)
    opt.step()
    opt.zero_grad(set_to_none=True)
    with torch.no_grad():
        for p, v in zip(m.parameters(), saved):
            p.copy_(v)
    return opt


def assert_optimizer_matches_model(opt: torch.optim.Adam, m: GaussianModel) -> None:
    by_name = {g["name"]: g["params"] for g in opt.param_groups}
    for name in PARAM_NAMES:
        p = getattr(m, name)
        assert len(by_name[name]) == 1 and by_name[name][0] is p
        state = opt.state[p]
        assert state["exp_avg"].shape == p.shape and state["exp_avg_sq"].shape == p.shape


def test_densifier_clones_small_splits_large_and_prunes_transparent_gaussians():
    m = four_gaussians()
    opt = adam_with_state(m)
    old_state_2 = opt.state[m.means]["exp_avg"][2].clone()
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    high, low = 1e-4, 1e-7  # pixel units; x W/2 = 5e-3 and 5e-6 against the 2e-4 threshold
    grads = torch.tensor([[high, 0.0], [0.0, high], [low, 0.0], [low, 0.0]])
    for _ in range(3):
        d.accumulate(grads, torch.tensor([3, 5, 3, 3]), W, H)
    torch.manual_seed(0)
    counts = d.step(m, opt, 600)
    assert counts == {"cloned": 1, "split": 1, "pruned": 1, "recycled": 0}
    # Kept originals 0 and 2, then the clone of 0, then the two children of 1.
    assert m.num_gaussians == 5
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([0.0, 2.0, 0.0, 1.0, 1.0]))
    assert torch.equal(m.means[2], m.means[0])
    child_scale = math.log(0.05 / 1.6)
    assert torch.allclose(m.log_scales[3:], torch.full((2, 3), child_scale))
    assert float((m.means.detach()[3:] - torch.tensor([0.5, 0, 2])).norm(dim=-1).max()) < 0.25
    assert torch.allclose(m.opacities()[2:], torch.full((3,), 0.5))
    # Adam: shapes follow, old rows keep their moments, new rows start at zero.
    assert_optimizer_matches_model(opt, m)
    assert torch.equal(opt.state[m.means]["exp_avg"][1], old_state_2)
    assert torch.equal(opt.state[m.means]["exp_avg"][2:], torch.zeros(3, 3))
    # The optimizer still steps, and moves the new Gaussians too.
    before = m.means.detach().clone()
    for p in m.parameters():
        p.grad = torch.ones_like(p)
    opt.step()
    assert bool((m.means.detach() != before).all())
    # Statistics restart for the new set.
    assert d.grad_accum.shape == (5,) and float(d.denom.sum()) == 0.0


def test_densifier_does_nothing_outside_its_interval_or_window():
    m = four_gaussians()
    opt = adam_with_state(m)
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    d.accumulate(torch.full((4, 2), 1e-3), torch.ones(4, dtype=torch.int32), W, H)
    assert d.step(m, opt, 650) == {}  # not a multiple of the interval
    assert d.step(m, opt, 400) == {}  # before the start (500 of 30k)
    assert d.step(m, opt, 15_100) == {}  # after the stop (15k of 30k)
    assert m.num_gaussians == 4


def test_densifier_window_scales_with_the_run_length_but_resets_count_iterations():
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=3000)
    assert (d.start, d.stop, d.reset_interval) == (50, 1500, 3000)


def test_a_run_shorter_than_the_reset_period_never_resets_opacity():
    m = four_gaussians()
    opt = adam_with_state(m)
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=800)
    for it in range(800):
        d.accumulate(torch.zeros(4, 2), torch.ones(4, dtype=torch.int32), W, H)
        assert "reset" not in d.step(m, opt, it)
    assert float(m.opacities().detach().min()) > 0.05


def test_opacity_reset_caps_opacities_and_zeroes_their_adam_moments():
    m = four_gaussians()
    opt = adam_with_state(m)
    means_state = opt.state[m.means]["exp_avg"].clone()
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    d.accumulate(torch.zeros(4, 2), torch.ones(4, dtype=torch.int32), W, H)
    counts = d.step(m, opt, 3000)
    assert counts["reset"] == 1 and counts["pruned"] == 1
    assert torch.allclose(m.opacities(), torch.full((3,), 0.01), atol=1e-6)
    assert torch.equal(opt.state[m.opacity_logits]["exp_avg"], torch.zeros(3))
    assert torch.equal(opt.state[m.means]["exp_avg"], means_state[[0, 1, 2]])
    assert_optimizer_matches_model(opt, m)


def test_after_the_first_reset_huge_gaussians_are_pruned_by_screen_and_world_size():
    m = four_gaussians()
    with torch.no_grad():
        m.log_scales[1] = math.log(0.5)  # > 0.1 x extent in the world
        m.opacity_logits[3] = 0.0
    opt = adam_with_state(m)
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    d.accumulate(torch.zeros(4, 2), torch.tensor([3, 3, 3, 40]), W, H)  # 3 is 40 px wide
    counts = d.step(m, opt, 3100)
    assert counts == {"cloned": 0, "split": 0, "pruned": 2, "recycled": 0}
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([0.0, 2.0]))
    assert_optimizer_matches_model(opt, m)


def test_max_gaussians_cap_prunes_the_least_opaque():
    m = four_gaussians()
    with torch.no_grad():
        m.opacity_logits.copy_(torch.tensor([0.3, -2.0, 1.0, 0.5]))
    opt = adam_with_state(m)
    d = Densifier(dataclasses.replace(DensifyConfig(), max_gaussians=2), 1.0, 30_000)
    assert d.step(m, opt, 7) == {"capped": 2}
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([2.0, 3.0]))
    assert_optimizer_matches_model(opt, m)


def test_near_the_budget_only_the_strongest_gradients_are_densified():
    m = four_gaussians()
    opt = adam_with_state(m)
    d = Densifier(dataclasses.replace(DensifyConfig(), max_gaussians=5), 1.0, 30_000)
    # 0 and 2 (small) both pass the threshold; 2's gradient is larger; room for one more.
    grads = torch.tensor([[1e-4, 0.0], [0.0, 0.0], [3e-4, 0.0], [0.0, 0.0]])
    d.accumulate(grads, torch.tensor([3, 3, 3, 3]), W, H)
    counts = d.step(m, opt, 600)
    assert counts == {"cloned": 1, "split": 0, "pruned": 1, "recycled": 0}  # 3 is transparent
    # Kept 0, 1, 2, then the clone of 2: no growth past the budget, nothing capped.
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([0.0, 1.0, 2.0, 2.0]))
    assert_optimizer_matches_model(opt, m)


def test_accumulate_adds_ndc_gradient_norms_of_visible_gaussians_only():
    d = Densifier(DensifyConfig(), scene_extent=1.0)
    grads = torch.tensor([[3.0, 4.0], [1.0, 1.0], [float("nan"), 0.0]])
    d.accumulate(grads, torch.tensor([2, 0, 1]), 100, 50)
    d.accumulate(grads, torch.tensor([7, 0, 1]), 100, 50)
    assert d.grad_accum[0] == pytest.approx(2 * math.hypot(3 * 50, 4 * 25))
    assert d.grad_accum[1] == 0 and d.grad_accum[2] == 0  # invisible; NaN counted as 0
    assert d.denom.tolist() == [2.0, 0.0, 2.0]
    assert d.max_radii.tolist() == [7.0, 0.0, 1.0]
    e = Densifier(DensifyConfig(), scene_extent=1.0)
    e.load_state_dict(d.state_dict())
    assert torch.equal(e.grad_accum, d.grad_accum) and torch.equal(e.max_radii, d.max_radii)


def clone_0_split_1(m: GaussianModel, opt: torch.optim.Optimizer) -> Densifier:
    """One densification step on ``four_gaussians`` that clones row 0, splits row 1 and keeps
    rows 2 and 3 (their gradients are below the threshold)."""
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    grads = torch.tensor([[1e-4, 0.0], [0.0, 1e-4], [1e-7, 0.0], [1e-7, 0.0]])
    d.accumulate(grads, torch.tensor([3, 5, 3, 3]), W, H)
    torch.manual_seed(0)
    d.step(m, opt, 600)
    return d


def test_densifier_origin_maps_rows_after_a_step_to_rows_before():
    m = four_gaussians()
    opt = adam_with_state(m)
    d = clone_0_split_1(m, opt)
    # Kept 0 and 2, then the clone of 0 and the two children of 1 (the split parent itself
    # is gone): new rows point at the row they came from.
    assert d.origin.tolist() == [0, 2, 0, 1, 1]
    d.step(m, opt, 601)  # nothing happens: every row is its own origin
    assert d.origin.tolist() == [0, 1, 2, 3, 4]


def test_gaussians_ruled_out_are_pruned_with_their_clones_at_a_densification_only():
    m = four_gaussians()
    opt = adam_with_state(m)
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    grads = torch.tensor([[1e-4, 0.0], [0.0, 1e-4], [1e-7, 0.0], [1e-7, 0.0]])
    d.accumulate(grads, torch.tensor([3, 5, 3, 3]), W, H)
    ruled_out = torch.tensor([True, False, False, False])  # row 0, which is also cloned
    assert not d.densifies(601) and d.step(m, opt, 601, ruled_out) == {}
    assert m.num_gaussians == 4
    torch.manual_seed(0)
    assert d.densifies(600)
    counts = d.step(m, opt, 600, ruled_out)
    assert counts == {"cloned": 1, "split": 1, "pruned": 3, "recycled": 0, "swept": 1}
    # Row 0 and its clone are gone, 3 is transparent: left are 2 and the two children of 1.
    assert d.origin.tolist() == [2, 1, 1]
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([2.0, 1.0, 1.0]))
    assert_optimizer_matches_model(opt, m)


def test_clones_and_split_children_carry_their_parents_time_parameters():
    m = four_gaussians()
    with torch.no_grad():
        m.t_mean.copy_(torch.tensor([0.1, 0.2, 0.3, 0.4]))
        m.t_log_scale.copy_(torch.tensor([-1.0, -2.0, -3.0, -4.0]))
    opt = adam_with_state(m)
    d = clone_0_split_1(m, opt)
    parent_mean, parent_scale = [0.1, 0.2, 0.3, 0.4], [-1.0, -2.0, -3.0, -4.0]
    assert m.t_mean.tolist() == pytest.approx([parent_mean[i] for i in d.origin.tolist()])
    assert m.t_log_scale.tolist() == pytest.approx([parent_scale[i] for i in d.origin.tolist()])
    assert_optimizer_matches_model(opt, m)


def test_at_the_budget_the_faintest_gaussians_make_room_for_high_gradients():
    m = four_gaussians()
    with torch.no_grad():  # peak opacities 0.5, 0.02, 0.5, 0.03: 1 and 3 are faint
        m.opacity_logits.copy_(torch.logit(torch.tensor([0.5, 0.02, 0.5, 0.03])))
    opt = adam_with_state(m)
    cfg = dataclasses.replace(DensifyConfig(), max_gaussians=4, recycle_fraction=0.25)
    d = Densifier(cfg, 1.0, 30_000)
    # 0 and 2 (small, opaque) both want a clone; the budget is full and allows recycling one
    # Gaussian (0.25 x 4): the faintest, 1, goes and the stronger gradient, 2, is cloned.
    grads = torch.tensor([[1e-4, 0.0], [0.0, 0.0], [3e-4, 0.0], [0.0, 0.0]])
    d.accumulate(grads, torch.tensor([3, 3, 3, 3]), W, H)
    counts = d.step(m, opt, 600)
    assert counts == {"cloned": 1, "split": 0, "pruned": 0, "recycled": 1}
    assert torch.equal(m.sh.detach().reshape(-1), torch.tensor([0.0, 2.0, 3.0, 2.0]))
    assert_optimizer_matches_model(opt, m)
    # Nothing faint enough: nothing is recycled, and nothing is densified past the budget.
    with torch.no_grad():
        m.opacity_logits.fill_(0.0)
    d.accumulate(torch.tensor([[3e-4, 0.0]] * 4), torch.tensor([3, 3, 3, 3]), W, H)
    assert d.step(m, opt, 700) == {"cloned": 0, "split": 0, "pruned": 0, "recycled": 0}


def test_split_children_of_time_local_gaussians_are_sampled_from_the_parent_in_time():
    n = 4000
    m = GaussianModel(n, 1)
    m.temporal = True
    with torch.no_grad():
        m.log_scales.fill_(math.log(0.05))  # all large: all split
        m.opacity_logits.fill_(0.0)
        m.t_mean.copy_(torch.full((n,), 0.5))
        # Half time-local (width 0.05), half static (width 10).
        m.t_log_scale.copy_(torch.log(torch.tensor([0.05, 10.0])).repeat(n // 2))
    opt = adam_with_state(m)
    d = Densifier(DensifyConfig(), scene_extent=1.0, total_iterations=30_000)
    d.accumulate(torch.full((n, 2), 1e-4), torch.full((n,), 3), W, H)
    torch.manual_seed(0)
    assert d.step(m, opt, 600)["split"] == n
    parents = d.origin
    local = torch.tensor([True, False]).repeat(n // 2)[parents]
    t_mean, width = m.t_mean.detach(), torch.exp(m.t_log_scale.detach())
    # Local children: centres drawn from N(0.5, 0.05) (mean and spread within 4 standard
    # errors of 2n samples), widths divided like the scales (by 1.6).
    sample = t_mean[local]
    assert abs(float(sample.mean()) - 0.5) < 4 * 0.05 / math.sqrt(n)
    assert float(sample.std()) == pytest.approx(0.05, rel=0.05)
    assert torch.allclose(width[local], torch.full_like(width[local], 0.05 / 1.6))
    # Static children keep their parent's time: a background must not become time-local.
    assert torch.equal(t_mean[~local], torch.full_like(t_mean[~local], 0.5))
    assert torch.allclose(width[~local], torch.full_like(width[~local], 10.0))
    assert_optimizer_matches_model(opt, m)
