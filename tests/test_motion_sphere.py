"""A round object's three-axis turn (``motion.sphere``) against analytic answers: a ring drawn
with known centre and radius, a textured sphere turned at a known angular velocity, and
integration of known rates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evsplat.motion.sphere import (
    CONTRAST,
    distances,
    is_round,
    on_outline,
    ring,
    rotvecs,
    sphere_rate,
)


def test_distances_are_numpys_norms_to_the_bit():
    rng = np.random.default_rng(4)
    points, centres = rng.normal(0, 20, (500, 2)), rng.normal(0, 5, (70, 2))
    expected = np.linalg.norm(points[None] - centres[:, None], axis=-1)
    assert np.array_equal(distances(points, centres), expected)
    assert np.array_equal(distances(points[::3], centres), expected[:, ::3])  # strided points


def test_ring_finds_a_balls_outline_among_its_inner_events():
    rng = np.random.default_rng(0)
    centre, radius = np.array([2.6, -1.4]), 20.5  # from the region's centre; the region: 16 px
    angle = rng.uniform(0, 2 * np.pi, 1500)
    outline = centre + (radius + rng.normal(0, 0.4, 1500))[:, None] * np.stack(
        [np.cos(angle), np.sin(angle)], 1
    )
    inner = centre + radius * np.sqrt(rng.random((1500, 1))) * np.stack(
        [np.cos(angle), np.sin(angle)], 1
    )
    found, rho, contrast = ring(np.concatenate([outline, inner]), 16.0)
    assert np.linalg.norm(found - centre) <= 1.0  # whole-pixel centres
    assert abs(rho - radius) <= 0.5
    # The ring's 2 px band holds about 1500 + 150 events; its sides about 4 x 75.
    assert 3.0 < contrast < 8.0
    disc = ring(inner, 16.0)  # a filled disc's edge is no ring
    assert disc is None or disc[2] < CONTRAST


def test_ring_says_none_where_the_events_pile_up_beyond_its_search():
    rng = np.random.default_rng(1)
    angle = rng.uniform(0, 2 * np.pi, 2000)
    small = 6.0 * np.stack([np.cos(angle), np.sin(angle)], 1)  # well inside 0.8 region radii
    assert ring(small + rng.normal(0, 0.3, small.shape), 16.0) is None


def test_on_outline_places_a_ball_cut_by_the_border_by_its_arc():
    rng = np.random.default_rng(3)
    rho, centre = 20.5, np.array([-6.3, 2.7])  # px from the first guess
    lo, hi = np.array([-60.0, -60.0]), np.array([8.0, 60.0])  # the border 14 px past its centre
    angle = rng.uniform(0, 2 * np.pi, 3000)
    unit = np.stack([np.cos(angle), np.sin(angle)], 1)
    outline = centre + (rho + rng.normal(0, 0.4, 3000))[:, None] * unit
    inner = centre + rho * np.sqrt(rng.random((3000, 1))) * unit
    events = np.concatenate([outline, inner])
    events = events[(events >= lo).all(1) & (events < hi).all(1)]  # what the camera sees
    found = on_outline(events, rho, lo, hi, 0.5 * rho)
    assert found is not None and np.linalg.norm(found - centre) <= 0.5  # quarter pixels
    assert on_outline(events, rho, lo, np.array([-35.0, 60.0]), 0.5 * rho) is None  # in view:
    # no circle within reach keeps a quarter of itself in the image.
    disc = inner[(inner >= lo).all(1) & (inner < hi).all(1)]
    assert on_outline(disc, rho, lo, hi, 0.5 * rho) is None  # a filled disc's edge is no ring
    assert on_outline(np.zeros((0, 2)), rho, lo, hi, 0.5 * rho) is None  # no events, no ring


def test_is_round_takes_rings_that_stand_out_and_hold_still():
    rng = np.random.default_rng(2)
    held = [np.array([3.0 + i % 2, 1.0]) for i in range(8)]  # 1 px back and forth
    assert is_round(held, [3.0] * 8)
    assert not is_round(held, [1.5] * 8)  # a box's outline seen as a ring: no ring
    assert not is_round([rng.integers(-4, 5, 2).astype(float) for _ in range(8)], [3.0] * 8)
    assert not is_round([np.zeros(2)], [3.0])  # one ring says nothing about holding still


@pytest.mark.parametrize("omega", [(4.0, -6.0, 7.0), (0.0, 9.0, 0.0), (-3.0, 0.0, -8.0)])
def test_sphere_rate_recovers_a_textured_balls_angular_velocity(omega):
    rng = np.random.default_rng(3)
    omega = np.array(omega)  # rad/s, camera frame (x right, y down, z forward)
    radius, centre = 20.0, np.array([48.0, 40.0])
    marks = Rotation.random(150, random_state=4).apply([0.0, 0.0, -radius])  # its texture
    dt = rng.uniform(-0.015, 0.015, (150, 20))
    at = np.stack(
        [Rotation.from_rotvec(omega[None] * t[:, None]).apply(m) for m, t in zip(marks, dt)]
    )  # [150,20,3]
    front = at[..., 2] < -0.3 * radius  # seen, and not edge-on
    off = at[front][:, :2] + rng.normal(0, 0.2, (front.sum(), 2))
    pol = np.repeat(np.where(rng.random(150) < 0.5, 1, -1)[:, None], 20, 1)[front]
    found = sphere_rate(off, dt[front], pol, centre, radius, 1.0 / 0.03, (96, 96))
    assert np.linalg.norm(found - omega) < 1.5  # the finest grid's step is 0.37 rad/s


def test_rotvecs_integrate_a_turn_past_half_a_revolution():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    times = np.array([0.0, 300_000.0, 600_000.0])
    rates = np.array([10.0, 10.0, 10.0])[:, None] * axis  # 6 rad over the sequence
    knots = np.linspace(0, 600_000, 61)
    got = rotvecs(times, rates, knots, t_ref=200_000)
    want = 10.0 * (knots - 200_000)[:, None] * 1e-6 * axis
    assert np.allclose(got, want, atol=1e-6)  # past π too: the turn carries on, no wrap


def test_rotvecs_hold_the_rates_beyond_their_sightings_and_ramp_between():
    times = np.array([200_000.0, 400_000.0])
    rates = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0]])
    got = rotvecs(times, rates, np.array([0.0, 200_000.0, 400_000.0, 600_000.0]), t_ref=200_000)
    # held at 2 rad/s before; 3 rad/s on average between; held at 4 after.
    assert np.allclose(got[:, 2], [-0.4, 0.0, 0.6, 1.4], atol=1e-6)
    assert np.allclose(got[:, :2], 0.0, atol=1e-9)
