"""Camera flow, Gaussian flow and L_ef against analytic flows and numpy projections."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.losses.flow import (
    camera_flow,
    event_flow_loss,
    gaussian_flow_features,
    linearized_brightness_change,
)

K = torch.tensor([[50.0, 0.0, 16.0], [0.0, 55.0, 12.0], [0.0, 0.0, 1.0]])


def rigid(rx: float, ry: float, t, dtype=torch.float32) -> torch.Tensor:
    """World-to-camera 4x4 from rotations about x then y (radians) and translation t."""
    cx, sx, cy, sy = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry)
    r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    m = np.eye(4)
    m[:3, :3] = r_y @ r_x
    m[:3, 3] = t
    return torch.tensor(m, dtype=dtype)


def test_camera_flow_matches_f_tx_over_z_for_fronto_parallel_plane():
    z, tx = 4.0, 0.2
    depth = torch.full((24, 32), z)
    w2c_b = rigid(0, 0, [tx, 0, 0])
    flow = camera_flow(depth, K, torch.eye(4), w2c_b)
    # A point X in camera a is at X + t in camera b: it moves by f·tx/Z pixels in x, 0 in y.
    assert torch.allclose(flow[..., 0], torch.full((24, 32), 50.0 * tx / z), atol=1e-4)
    assert torch.allclose(flow[..., 1], torch.zeros(24, 32), atol=1e-4)


def test_camera_flow_is_zero_for_identical_poses():
    depth = torch.rand(24, 32) * 5 + 0.5
    pose = rigid(0.3, -0.2, [0.1, -0.4, 1.0])
    assert torch.allclose(camera_flow(depth, K, pose, pose), torch.zeros(24, 32, 2), atol=1e-4)


def test_camera_flow_matches_numpy_unprojection_for_general_motion():
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 6.0, (6, 7))
    a = rigid(0.1, 0.2, [0.3, -0.1, 0.5], torch.float64).numpy()
    b = rigid(-0.05, 0.25, [0.35, -0.05, 0.45], torch.float64).numpy()
    k = K.double().numpy()
    expected = np.zeros((6, 7, 2))
    for i in range(6):
        for j in range(7):
            p = np.array([j + 0.5, i + 0.5, 1.0])
            x_cam = np.linalg.inv(k) @ p * depth[i, j]
            x_world = np.linalg.inv(a) @ np.append(x_cam, 1.0)
            q = k @ (b @ x_world)[:3]
            expected[i, j] = q[:2] / q[2] - p[:2]
    got = camera_flow(
        torch.tensor(depth, dtype=torch.float64), K.double(), torch.tensor(a), torch.tensor(b)
    )
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-9)


def test_camera_flow_is_zero_and_has_finite_gradient_where_depth_is_zero():
    depth = torch.rand(8, 8) + 1.0
    depth[2:4, 2:4] = 0.0
    depth.requires_grad_(True)
    flow = camera_flow(depth, K, torch.eye(4), rigid(0.1, 0.0, [0.5, 0, 0]))
    assert torch.equal(flow[2:4, 2:4], torch.zeros(2, 2, 2))
    flow.sum().backward()
    assert torch.isfinite(flow).all() and torch.isfinite(depth.grad).all()


def test_camera_flow_is_zero_for_points_that_end_behind_camera_b():
    depth = torch.full((4, 4), 1.0)
    flow = camera_flow(depth, K, torch.eye(4), rigid(0, 0, [0, 0, -2.0]))
    assert torch.equal(flow, torch.zeros(4, 4, 2))


def test_gaussian_flow_features_match_manual_projection():
    rng = np.random.default_rng(1)
    m0 = rng.uniform(-1, 1, (5, 3)) + [0, 0, 4]
    m1 = m0 + rng.normal(0, 0.05, (5, 3))
    view = rigid(0.05, -0.1, [0.2, 0.1, 0.3], torch.float64).numpy()
    k = K.double().numpy()

    def proj(p):
        c = view[:3, :3] @ p + view[:3, 3]
        return np.array([k[0, 0] * c[0] / c[2] + k[0, 2], k[1, 1] * c[1] / c[2] + k[1, 2]])

    expected = np.stack([proj(b) - proj(a) for a, b in zip(m0, m1)])
    got = gaussian_flow_features(torch.tensor(m0), torch.tensor(m1), torch.tensor(view), K.double())
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-9)


def linear_field(h: int, w: int, a: float, b: float, c: float = 0.3) -> np.ndarray:
    """Log brightness a·x + b·y + c at the pixel centres."""
    y, x = np.mgrid[0:h, 0:w] + 0.5
    return a * x + b * y + c


def test_linearized_change_is_exact_for_a_linear_field_translated_by_the_flow():
    a, b, u, v = 0.03, -0.02, 1.5, -0.7
    log0 = linear_field(10, 12, a, b)
    # The pattern moved by (u, v): L1(x) = L0(x - F).
    log1 = linear_field(10, 12, a, b, c=0.3 - a * u - b * v)
    flow = torch.tensor([u, v]).expand(10, 12, 2).double()
    pred = linearized_brightness_change(torch.tensor(log0), flow)
    np.testing.assert_allclose(pred.numpy(), log1 - log0, atol=1e-12)


def test_event_flow_loss_is_zero_for_linear_field_moving_at_known_flow_and_positive_otherwise():
    h, w = 16, 20
    a, b = 0.04, 0.01
    log0 = torch.tensor(linear_field(h, w, a, b))
    # A non-uniform known flow (rotation about the image centre) so the change varies in space.
    y, x = np.mgrid[0:h, 0:w] + 0.5
    flow_np = 0.05 * np.stack([-(y - h / 2), x - w / 2], axis=-1)
    observed = torch.tensor(-(a * flow_np[..., 0] + b * flow_np[..., 1]))  # exact change
    flow = torch.tensor(flow_np)
    pred = linearized_brightness_change(log0, flow)
    assert float(event_flow_loss(observed, pred)) == pytest.approx(0.0, abs=1e-9)
    # The normalisation removes Δτ and the contrast threshold: any scale of either side agrees.
    assert float(event_flow_loss(0.2 * observed, 3.0 * pred)) == pytest.approx(0.0, abs=1e-4)
    wrong = linearized_brightness_change(log0, -flow.flip(-1))
    assert float(event_flow_loss(observed, wrong)) > 0.1
    # Opposite sign: |2·ΔI/RMS(ΔI)| averaged.
    o = observed.numpy()
    flipped = 2 * np.abs(o).mean() / np.sqrt((o**2).mean())
    assert float(event_flow_loss(observed, -pred)) == pytest.approx(flipped, abs=1e-6)


def test_event_flow_loss_matches_equation_13_up_to_sqrt_n_with_mask():
    rng = np.random.default_rng(2)
    obs, pred = rng.normal(size=(2, 9, 11))
    mask = rng.uniform(size=(9, 11)) > 0.4
    o, p = obs[mask], pred[mask]
    eq13 = np.abs(o / np.linalg.norm(o) - p / np.linalg.norm(p)).sum()
    got = event_flow_loss(torch.tensor(obs), torch.tensor(pred), torch.tensor(mask))
    assert float(got) == pytest.approx(eq13 / math.sqrt(mask.sum()), rel=1e-6)


def test_event_flow_loss_gradients_finite_for_all_zero_images_and_flow():
    log_img = torch.zeros(8, 8, requires_grad=True)
    flow = torch.zeros(8, 8, 2, requires_grad=True)
    loss = event_flow_loss(torch.zeros(8, 8), linearized_brightness_change(log_img, flow))
    loss.backward()
    assert float(loss.detach()) == 0.0
    assert torch.isfinite(log_img.grad).all() and torch.isfinite(flow.grad).all()
