"""The mover's spin by contrast maximisation (evsplat.train.spin), against analytic motion."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.train.spin import (
    SpinSettings,
    SpinWindow,
    estimate_spin,
    find_spin,
    integrate,
    rotation,
    sphere_hits,
)

K = np.array([[100.0, 0.0, 48.0], [0.0, 100.0, 48.0], [0.0, 0.0, 1.0]])
SIZE = (96, 96)
CENTRE = np.array([0.0, 0.0, 3.0])  # the sphere 3 m in front of a camera at the origin
RADIUS = 0.6


def test_rotation_matches_the_axis_angle_formula():
    r = rotation(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)).numpy()
    assert np.allclose(r, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert np.allclose(rotation(torch.zeros(3, dtype=torch.float64)).numpy(), np.eye(3))
    w = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)
    assert np.allclose((rotation(w) @ rotation(-w)).numpy(), np.eye(3), atol=1e-12)


def test_integrate_a_constant_rate_is_one_rotation():
    omega = np.array([1.0, -2.0, 4.0])
    times = np.array([0, 100_000])
    query = np.array([0, 20_000, 50_000, 100_000])
    turns = integrate(times, np.stack([omega, omega]), 50_000, query)
    for t, turn in zip(query, turns):
        want = rotation(torch.from_numpy(omega * (t - 50_000) * 1e-6)).numpy()
        assert np.allclose(turn, want, atol=1e-9)


def test_sphere_hits_land_on_the_front_surface_inside_the_rim():
    c2w = np.repeat(np.eye(4)[None], 3, axis=0)
    centre = np.repeat(CENTRE[None], 3, axis=0)
    # the centre's pixel, a pixel at half the disc's radius, one outside the rim
    r_px = 100.0 * RADIUS / math.sqrt(3.0**2 - RADIUS**2)
    uv = np.array([[48.0, 48.0], [48.0 + 0.5 * r_px, 48.0], [48.0 + 0.99 * r_px, 48.0]])
    hits, keep = sphere_hits(uv, c2w, K, centre, RADIUS, rim=0.9)
    assert keep.tolist() == [True, True, False]
    assert np.allclose(np.linalg.norm(hits, axis=1), RADIUS)
    assert np.allclose(hits[0], [0.0, 0.0, -RADIUS])  # facing the camera
    assert (hits[:, 2] < 0).all()


def _window(hits: np.ndarray, dt: np.ndarray, labels: np.ndarray) -> SpinWindow:
    return SpinWindow(
        0, torch.from_numpy(hits), torch.from_numpy(dt), torch.from_numpy(labels), np.eye(4), CENTRE
    )


def _texture_events(omega: np.ndarray, n_points: int, per_point: int, seed: int):
    """Events of texture points on the sphere's front turning at ``omega``: each point fires at
    random times in +-15 ms at its projection (pixel centres, no quantisation)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = -np.abs(d[:, 2])  # the front half
    points = RADIUS * d
    dt = rng.uniform(-0.015, 0.015, size=(n_points, per_point))
    turned = np.einsum(
        "pkij,pj->pki", rotation(torch.from_numpy(omega * dt[..., None])).numpy(), points
    )
    world = turned + CENTRE
    uv = world[..., :2] / world[..., 2:] * 100.0 + 48.0
    return uv.reshape(-1, 2), dt.reshape(-1)


@pytest.mark.parametrize("omega", [(4.0, 1.0, 9.0), (-6.0, 3.0, 0.0), (0.0, 0.0, -10.0)])
def test_estimate_spin_recovers_the_angular_velocity(omega):
    omega = np.array(omega)
    uv, dt = _texture_events(omega, 60, 30, seed=1)
    c2w = np.repeat(np.eye(4)[None], len(uv), axis=0)
    hits, keep = sphere_hits(uv, c2w, K, np.repeat(CENTRE[None], len(uv), 0), RADIUS, 0.95)
    window = _window(hits, dt[keep], np.zeros(len(hits), dtype=np.int64))
    found, gain = estimate_spin(window, K, SIZE, None, max_rate=15.0, steps=60)
    assert np.linalg.norm(found - omega) < 0.1 * np.linalg.norm(omega), found
    assert gain > 0.2  # warped back, each point's events gather onto one spot


def test_find_spin_holds_the_estimate_where_the_mover_is_not_seen():
    omega = np.array([3.0, -2.0, 8.0])
    uv, dt = _texture_events(omega, 60, 30, seed=2)
    t_ev = np.round(dt * 1e6).astype(np.int64) + 100_000
    order = np.argsort(t_ev)
    uv, t_ev = uv[order], t_ev[order]

    def events_in(t0: int, t1: int):
        i0, i1 = np.searchsorted(t_ev, [t0, t1])
        return uv[i0:i1], t_ev[i0:i1], np.zeros(i1 - i0, dtype=np.int64)

    out, gains = find_spin(
        events_in,
        lambda t: np.repeat(CENTRE[None], len(t), 0),
        lambda t: np.repeat(np.eye(4)[None], len(t), 0),
        RADIUS,
        K,
        SIZE,
        np.array([100_000, 300_000]),  # nothing happens at 300 ms
        15_000,
        SpinSettings(rim=0.95, max_events=2000, max_rate=15.0, min_gain=0.05, steps=60, seed=0),
    )
    assert np.linalg.norm(out[0] - omega) < 0.1 * np.linalg.norm(omega)
    assert np.isnan(gains[1]) and np.allclose(out[1], out[0])


def test_a_dense_texture_of_several_colours_is_found_through_one_image_per_label():
    # A dense texture: 1,200 points, each firing in one of six images (three colour channels,
    # two polarities). Warped right, each image holds sparse sharp spots; their sum is nearly
    # even, so one image of all the events sharpens much less under the right turn.
    omega = np.array([4.0, -3.0, 6.0])
    n_points, per_point = 1200, 4
    uv, dt = _texture_events(omega, n_points, per_point, seed=3)
    labels = np.repeat(np.arange(n_points) % 6, per_point)
    c2w = np.repeat(np.eye(4)[None], len(uv), axis=0)
    hits, keep = sphere_hits(uv, c2w, K, np.repeat(CENTRE[None], len(uv), 0), RADIUS, 0.95)
    gains = {}
    for name, lab in (("split", labels[keep]), ("one", np.zeros(keep.sum(), dtype=np.int64))):
        window = _window(hits, dt[keep], lab)
        found, gains[name] = estimate_spin(window, K, SIZE, omega * 0.8, max_rate=15.0, steps=60)
        if name == "split":
            assert np.linalg.norm(found - omega) < 0.1 * np.linalg.norm(omega), found
    assert gains["split"] > 2.0 * gains["one"], gains
    assert gains["one"] < 0.05  # under `mover.spin_min_gain`: one image would not use it
