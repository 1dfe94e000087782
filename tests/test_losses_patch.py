"""L_m patch extraction and loss, and the visible-Gaussian sampling, against numpy oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.losses.patch import extract_patches, patch_motion_loss, select_visible


def bilinear_numpy(img: np.ndarray, x: float, y: float) -> float:
    """Value at (x, y) with pixel (r, c) centred at (c+.5, r+.5); outside the sensor reads 0."""
    h, w = img.shape
    fx, fy = x - 0.5, y - 0.5
    c0, r0 = math.floor(fx), math.floor(fy)
    ax, ay = fx - c0, fy - r0
    total = 0.0
    for dr, wy in ((0, 1 - ay), (1, ay)):
        for dc, wx in ((0, 1 - ax), (1, ax)):
            r, c = r0 + dr, c0 + dc
            if 0 <= r < h and 0 <= c < w:
                total += wy * wx * img[r, c]
    return total


def blob_frames(centres_xy: np.ndarray, h: int = 32, w: int = 32, sigma: float = 2.0):
    """One frame per centre: a Gaussian blob of events (ESI) at that centre."""
    y, x = np.mgrid[0:h, 0:w] + 0.5
    return np.stack(
        [np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2)) for cx, cy in centres_xy]
    )


def test_extract_patches_matches_numpy_bilinear_reference_including_outside_sensor():
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(3, 10, 12))
    centres = np.array(
        [[[5.3, 4.7], [0.2, 9.8], [11.9, 1.1]], [[-1.0, 3.0], [6.0, 5.0], [12.5, 10.5]]]
    )
    side = 5
    got = extract_patches(torch.tensor(frames), torch.tensor(centres), side).numpy()
    for i in range(2):
        for j in range(3):
            for a in range(side):
                for b in range(side):
                    x = centres[i, j, 0] + b - (side - 1) / 2
                    y = centres[i, j, 1] + a - (side - 1) / 2
                    assert got[i, j, a, b] == pytest.approx(
                        bilinear_numpy(frames[j], x, y), abs=1e-9
                    )


def test_patch_motion_loss_is_zero_for_a_pattern_that_moves_with_the_centres():
    # Whole-pixel steps from a sub-pixel start: the discretised blob shifts exactly.
    path = np.array([[10.3, 12.6], [12.3, 13.6], [15.3, 14.6], [17.3, 16.6]])
    frames = torch.tensor(blob_frames(path))
    centres = torch.tensor(path)[None]  # one Gaussian that follows the blob
    assert float(patch_motion_loss(frames, centres, 7)) == pytest.approx(0.0, abs=1e-9)


def test_patch_motion_loss_is_positive_when_the_pattern_moves_but_the_centres_do_not():
    path = np.array([[10.0, 12.0], [12.5, 13.0], [15.0, 14.0], [17.5, 15.0]])
    frames = torch.tensor(blob_frames(path))
    still = torch.tensor(path[:1]).expand(4, 2)[None]
    assert float(patch_motion_loss(frames, still, 7)) > 0.05


def test_patch_motion_loss_gradient_pulls_a_centre_towards_the_moving_pattern():
    path = np.array([[12.0, 12.0], [13.5, 11.0]])  # the blob moved +1.5 px in x, -1 px in y
    frames = torch.tensor(blob_frames(path))
    centres = torch.tensor(path[:1]).expand(2, 2)[None].clone().requires_grad_(True)
    patch_motion_loss(frames, centres, 9).backward()
    g = centres.grad[0, 1]
    assert g[0] < 0 and g[1] > 0  # descent moves centre 1 towards +x, -y
    assert torch.equal(centres.grad[0, 0] != 0, torch.tensor([True, True]))


def test_patch_motion_loss_is_finite_with_finite_gradient_on_empty_frames_and_offscreen():
    frames = torch.zeros(3, 8, 8)
    centres = torch.tensor([[[-50.0, 4.0], [4.0, 4.0], [1e4, -1e4]]], requires_grad=True)
    loss = patch_motion_loss(frames, centres, 5)
    loss.backward()
    assert float(loss.detach()) == 1.0 and torch.isfinite(centres.grad).all()


def test_patch_motion_loss_does_not_reward_leaving_the_events():
    """A centre that follows the moving blob scores 0; one that jumps to an event-free corner
    scores the worst value, 1 (the plain L1 of eq. 15 gave it 0, like perfect agreement); one
    that stays put scores in between (its patches share part of the blob)."""
    path = np.array([[10.0, 12.0], [11.0, 13.0], [12.0, 14.0], [13.0, 15.0]])
    frames = torch.tensor(blob_frames(path))
    follow = torch.tensor(path)[None]
    still = torch.tensor(path[:1]).expand(4, 2)[None]
    away = torch.tensor([[10.0, 12.0], [-40.0, -40.0], [-40.0, -40.0], [-40.0, -40.0]])
    away = away.double()[None]
    losses = [float(patch_motion_loss(frames, c, 7)) for c in (follow, still, away)]
    assert losses[0] == pytest.approx(0.0, abs=1e-9)
    assert 0.05 < losses[1] < 0.9
    assert losses[2] == pytest.approx(1.0, abs=1e-6)


def test_patch_motion_loss_rejects_centres_that_do_not_match_the_frames():
    with pytest.raises(ValueError, match=r"need \[n,3,2\]"):
        patch_motion_loss(torch.zeros(3, 8, 8), torch.zeros(2, 4, 2), 5)


def test_select_visible_skips_occluded_offscreen_and_behind_camera_gaussians():
    rendered = torch.full((10, 10), 2.0)
    rendered[:, 5:] = 0.0  # nothing rendered on the right half
    means2d = torch.tensor(
        [[1.5, 1.5], [2.5, 3.5], [3.5, 8.5], [11.0, 2.0], [7.5, 2.5], [4.0, 4.0], [-0.5, 1.0]]
    )
    depths = torch.tensor([2.1, 5.0, 1.9, 2.0, 2.0, -1.0, 2.0])
    # 0 on the surface (within 10 %), 1 occluded, 2 in front, 3 off-sensor, 4 on an empty pixel,
    # 5 behind the camera, 6 off-sensor.
    gen = torch.Generator().manual_seed(0)
    idx = select_visible(means2d, depths, rendered, 10, 0.1, gen)
    assert idx.tolist() == [0, 2]


def test_select_visible_returns_a_random_sample_of_n_distinct_visible_gaussians():
    rendered = torch.full((20, 20), 3.0)
    n_total = 200
    g = torch.Generator().manual_seed(1)
    means2d = torch.rand(n_total, 2, generator=g) * 20
    depths = torch.where(torch.arange(n_total) % 2 == 0, 3.0, 9.0)  # odd ones are occluded
    a = select_visible(means2d, depths, rendered, 16, 0.1, torch.Generator().manual_seed(5))
    b = select_visible(means2d, depths, rendered, 16, 0.1, torch.Generator().manual_seed(6))
    assert a.numel() == 16 and a.unique().numel() == 16
    assert bool((a % 2 == 0).all()) and not torch.equal(a, b)
