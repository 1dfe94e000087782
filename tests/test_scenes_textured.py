"""The textured scenes: `camo` (a sphere wearing the wall's dense noise, an orbiting camera) and
`blobs` (the ball scene in front of a smooth wall). Tiny variants only, so the file runs in
a few seconds."""

from functools import cache

import numpy as np
import pytest

from evsplat.cli import main
from evsplat.scenes import Scene, get_scene
from evsplat.scenes.library import BACK_WALL_Z

TIMES = (0, 150_000, 300_000, 450_000)  # spread over the tiny variant's 0.6 s


@cache
def tiny(name: str) -> Scene:
    return get_scene(name, tiny=True)


@cache
def frames(name: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(rgb, depth, mover mask, back-wall mask) of the tiny scene at TIMES, rendered once."""
    s = tiny(name)
    out = []
    for t in TIMES:
        rgb, depth, mask = s.render(t)
        out.append((rgb, depth, mask, back_wall(s, t, depth) & ~mask))
    return out


def back_wall(scene: Scene, t_us: int, depth: np.ndarray) -> np.ndarray:
    """Pixels whose hit point lies on the world plane z = BACK_WALL_Z (not the floor)."""
    h, w = depth.shape
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([j, i, np.ones_like(j)], -1) @ np.linalg.inv(scene.K).T
    c2w = scene.c2w(t_us)
    world = (rays * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]
    return np.abs(world[..., 2] - BACK_WALL_Z) < 1e-3


def mean_abs_gradient(rgb: np.ndarray, keep: np.ndarray) -> float:
    """Mean |difference| between neighbouring pixels that are both kept, averaged over the
    colour channels (each channel on its own: colour edges count, not only brightness)."""
    dx = np.abs(np.diff(rgb, axis=1)).mean(-1)[keep[:, 1:] & keep[:, :-1]]
    dy = np.abs(np.diff(rgb, axis=0)).mean(-1)[keep[1:] & keep[:-1]]
    return float(np.concatenate([dx, dy]).mean())


def wall_gradient(name: str) -> float:
    return float(np.mean([mean_abs_gradient(rgb, wall) for rgb, _, _, wall in frames(name)]))


@pytest.mark.parametrize("name", ["camo", "blobs"])
def test_textured_scenes_render_finite_unit_range_images_with_the_wall_behind(name):
    s = tiny(name)
    assert max(s.width, s.height) == 96
    for rgb, depth, mask, wall in frames(name):
        assert rgb.shape == (s.height, s.width, 3) and depth.shape == mask.shape
        assert np.isfinite(rgb).all() and 0 <= rgb.min() and rgb.max() <= 1
        assert np.isfinite(depth).all() and depth.min() > 0  # every ray hits something
        assert wall.mean() > 0.5  # the back wall fills most of the view


@pytest.mark.parametrize("name", ["camo", "blobs"])
def test_the_moving_object_crosses_many_pixels_of_the_tiny_view(name):
    centres = [np.argwhere(m).mean(0) for _, _, m, _ in frames(name) if m.sum() > 20]
    assert len(centres) >= 3
    travel = max(np.linalg.norm(a - b) for a in centres for b in centres)
    assert travel > 25, f"the mover's mask centre spans only {travel:.1f} px of 96"


def test_camo_mover_has_the_walls_colour_statistics():
    # Camouflage: per channel, the sphere's mean and spread match the wall's, so neither
    # colour nor contrast sets it apart in a single frame (measured: means within 0.03,
    # spreads within 15%).
    fr = frames("camo")
    mover = np.concatenate([rgb[m] for rgb, _, m, _ in fr])
    wall = np.concatenate([rgb[w] for rgb, _, _, w in fr])
    assert len(mover) > 1000
    np.testing.assert_allclose(mover.mean(0), wall.mean(0), atol=0.06)
    ratio = mover.std(0) / wall.std(0)
    assert ((0.75 < ratio) & (ratio < 1.33)).all(), ratio


def test_camo_texture_is_dense_on_the_wall_and_on_the_mover():
    # Measured at tiny size: the ball scene's tiled wall 0.038; camo's wall and sphere 0.12.
    ball = wall_gradient("ball")
    assert wall_gradient("camo") > 2.5 * ball
    mover = np.mean([mean_abs_gradient(rgb, m) for rgb, _, m, _ in frames("camo")])
    assert mover > 2.0 * ball


def test_camo_camera_orbits_the_scene_centre_looking_at_it():
    s = tiny("camo")
    centre = np.array([0.0, 0.0, 3.0])
    ts = np.linspace(0, s.duration_us, 61)
    poses = s.c2w(ts)
    to_centre = centre - poses[:, :3, 3]
    dist = np.linalg.norm(to_centre, axis=1)
    forward = poses[:, :3, 2]
    miss = np.degrees(np.arccos(np.sum(forward * to_centre, 1) / dist))
    assert np.ptp(dist) < 0.15 and miss.max() < 2.0  # on the orbit, aimed at the centre
    azimuth = np.degrees(np.arctan2(to_centre[:, 0], to_centre[:, 2]))
    assert np.ptp(azimuth) > 15  # it really turns around the scene, not only jitters


def test_blobs_wall_is_smooth_with_the_ball_scenes_ball_and_camera():
    assert wall_gradient("blobs") < 0.15 * wall_gradient("ball")  # measured 0.002 vs 0.038
    ball, blobs = tiny("ball"), tiny("blobs")
    np.testing.assert_array_equal(ball.c2w(np.array(TIMES)), blobs.c2w(np.array(TIMES)))
    for (_, _, m_ball, _), (_, _, m_blobs, _) in zip(frames("ball"), frames("blobs")):
        np.testing.assert_array_equal(m_ball, m_blobs)  # the same ball on the same path


def test_simulate_help_lists_the_new_scenes_with_their_descriptions(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # undo the line wrapping
    assert "camo camouflaged sphere: dense multi-colour noise" in text
    assert "blobs the ball scene (beach ball" in text
