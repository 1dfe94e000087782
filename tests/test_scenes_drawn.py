"""Scenes drawn at random (``drawn-N``, ``evsplat.scenes.drawn``): the same scene for the same
N, movers in view in the tiny variant's real image (its own intrinsics and camera, not the
drawing's field-of-view constant) and apart in depth by more than their size."""

from __future__ import annotations

import numpy as np
import pytest

from evsplat.errors import EvsplatError
from evsplat.scenes import get_scene, is_scene
from evsplat.scenes.drawn import MIN_IN_VIEW

NUMBERS = range(40)


def _pixels(scene, k: int, t_us: float) -> tuple[np.ndarray, float]:
    """(pixel [2], camera depth) of object ``k``'s centre at ``t_us`` in ``scene``'s image."""
    c2w = scene.c2w(t_us)
    x = c2w[:3, :3].T @ (scene.object_centre(t_us, k) - c2w[:3, 3])
    return (scene.K @ (x / x[2]))[:2], float(x[2])


def test_a_drawn_scene_is_the_same_for_its_number_and_another_for_another():
    a, b, c = (get_scene(n, tiny=True) for n in ("drawn-5", "drawn-5", "drawn-6"))
    assert a.description == b.description != c.description
    for t_us in (0, 250_000, 600_000):
        for k in range(len(a.objects)):
            np.testing.assert_array_equal(a.object_centre(t_us, k), b.object_centre(t_us, k))
        np.testing.assert_array_equal(a.c2w(t_us), b.c2w(t_us))


@pytest.mark.parametrize("n", NUMBERS)
def test_every_mover_is_in_view_long_enough_and_apart_in_depth_from_the_others(n):
    scene = get_scene(f"drawn-{n}", tiny=True)
    assert 1 <= len(scene.objects) <= 3
    times = np.linspace(0, scene.duration_us, 31)
    depths = []
    for k in range(len(scene.objects)):
        seen = 0
        for t_us in times:
            uv, z = _pixels(scene, k, t_us)
            seen += z > 0 and 0 <= uv[0] < scene.width and 0 <= uv[1] < scene.height
        assert seen >= MIN_IN_VIEW * len(times), (n, k, seen)
        depths.append((scene.object_centre(0, k)[2], scene.object_radius(k)))
    depths.sort()
    for (z0, r0), (z1, r1) in zip(depths, depths[1:]):
        assert z1 - z0 > max(r0, r1)  # the evaluation's depth tolerance tells them apart


def test_the_drawn_scenes_hold_every_kind_of_mover_and_both_cameras():
    words = " ".join(get_scene(f"drawn-{n}", tiny=True).description for n in NUMBERS)
    for kind in ("sphere", "box", "card", "still camera", "hand-held camera", "entering",
                 "held in place", "tumbling", "turning at"):  # fmt: skip
        assert kind in words


def test_a_drawn_scenes_movers_are_drawn_in_its_frames():
    scene = get_scene("drawn-3", tiny=True)
    masks = scene.object_masks(scene.duration_us // 2)
    rgb, _, moving = scene.render(scene.duration_us // 2)
    assert all(m.sum() > 20 for m in masks)
    np.testing.assert_array_equal(np.logical_or.reduce(masks), moving)
    assert rgb[moving].mean(0).shape == (3,)


@pytest.mark.parametrize("name", ["drawn-", "drawn--1", "drawn-1x", "Drawn-1"])
def test_a_misspelt_drawn_name_is_one_error_that_names_the_pattern(name):
    assert not is_scene(name)
    with pytest.raises(EvsplatError, match="drawn-N"):
        get_scene(name, tiny=True)
