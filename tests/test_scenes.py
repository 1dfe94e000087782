"""Built-in scenes: sizes, ground truth consistent with analytic geometry, real motion."""

import numpy as np
import pytest

from evsplat.errors import EvsplatError
from evsplat.scenes import get_scene, scene_names
from evsplat.scenes.library import BACK_WALL_Z, FLOOR_Y

NAMES = ["butterfly", "duck", "clock", "ball"]


def test_the_four_paper_like_scenes_exist_with_paper_sizes():
    assert scene_names()[:7] == [*NAMES, "still", "camo", "blobs"]
    sizes = {n: (get_scene(n).width, get_scene(n).height) for n in NAMES}
    assert sizes == {
        "butterfly": (400, 400),
        "duck": (600, 400),
        "clock": (400, 400),
        "ball": (400, 400),
    }
    for n in NAMES:
        s = get_scene(n, tiny=True)
        assert max(s.width, s.height) <= 96 and s.duration_us <= 1_000_000
        # the demo input: a clearly visible moving object
        assert s.render(300_000)[2].mean() > 0.1


def test_the_still_scene_is_the_ball_room_with_nothing_moving_but_the_camera():
    s = get_scene("still", tiny=True)
    a, b = s.render(100_000), s.render(500_000)
    assert not a[2].any() and not b[2].any()  # no moving-object mask
    # Only the camera moves: every primitive's pose is the same at any two times.
    assert all(np.array_equal(p.pose(0.1), p.pose(0.5)) for p in s.primitives)
    assert not np.allclose(s.c2w(100_000), s.c2w(500_000))


def test_size_override_scales_the_intrinsics():
    s = get_scene("ball", size=(200, 100))
    assert (s.width, s.height) == (200, 100)
    assert np.allclose(s.K[:2, 2], [100, 50]) and s.K[0, 0] == s.K[1, 1]
    with pytest.raises(EvsplatError, match="--size 4x4"):
        get_scene("ball", size=(4, 4))


def test_unknown_scene_is_a_one_line_error_listing_the_choices():
    with pytest.raises(EvsplatError, match="unknown scene 'cat'; choose one of: butterfly, duck"):
        get_scene("cat")


def world_ray_depth_to_plane(scene, t_us, pixels, plane_axis, plane_value):
    """Camera-z depth at which each pixel's ray meets the world plane x[axis] = value."""
    c2w = scene.c2w(t_us)
    kinv = np.linalg.inv(scene.K)
    out = []
    for i, j in pixels:
        d_cam = kinv @ [j + 0.5, i + 0.5, 1.0]
        d = c2w[:3, :3] @ d_cam
        out.append((plane_value - c2w[plane_axis, 3]) / d[plane_axis])
    return np.array(out)


@pytest.mark.parametrize("name", NAMES)
def test_static_background_depth_matches_the_analytic_wall_and_floor(name):
    s = get_scene(name, tiny=True)
    t = 250_000
    rgb, depth, mask = s.render(t)
    h, w = s.height, s.width
    assert rgb.shape == (h, w, 3) and depth.shape == mask.shape == (h, w)
    assert rgb.dtype == depth.dtype == np.float32 and mask.dtype == bool
    assert 0 <= rgb.min() and rgb.max() <= 1 and depth.min() > 0
    top = [(0, 0), (0, w - 1), (1, w // 2)]  # upper corners see the back wall
    bottom = [(h - 1, 0), (h - 1, w - 1)]  # lower corners see the floor
    assert np.allclose(
        depth[tuple(np.array(top).T)],
        world_ray_depth_to_plane(s, t, top, 2, BACK_WALL_Z),
        rtol=1e-5,
    )
    assert np.allclose(
        depth[tuple(np.array(bottom).T)],
        world_ray_depth_to_plane(s, t, bottom, 1, FLOOR_Y),
        rtol=1e-5,
    )


@pytest.mark.parametrize("name", NAMES)
def test_object_moves_fast_enough_to_blur_a_30fps_camera(name):
    # Within one 30 fps exposure (33 ms) most object pixels change by more than one event
    # threshold (0.2 in log intensity): such a frame would be visibly blurred.
    s = get_scene(name)
    s = get_scene(name, size=(s.width // 4, s.height // 4))
    (a, _, m0), (b, _, m1) = (s.render(t) for t in (400_000, 433_333))
    assert 0.04 < m0.mean() < 0.6
    dl = np.abs(np.log(a.mean(-1) + 1e-3) - np.log(b.mean(-1) + 1e-3))
    assert (dl[m0 | m1] > 0.2).mean() > 0.4


def test_camera_moves_smoothly():
    s = get_scene("ball", tiny=True)
    a, b = s.c2w(0), s.c2w(300_000)
    assert np.abs(a - b).max() > 0.01
    assert s.c2w(np.array([0, 1000])).shape == (2, 4, 4)
