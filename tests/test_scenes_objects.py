"""Scenes with several movers: per-object masks against analytic silhouettes and the full
render's moving mask, the new scenes' motions, and their ground truth in a dataset folder."""

import json
from dataclasses import replace

import numpy as np
import pytest

from evsplat.data.dataset import load_dataset
from evsplat.data.images import read_png
from evsplat.data.simulator import simulate_dataset
from evsplat.scenes import get_scene
from tests.test_eval import sphere_silhouette

NEW = ["crossing", "tumble", "spinner", "enter_leave", "watch"]
MEET_US = 300_000  # `crossing`: the sphere is in front of the box, both mid-view


def test_object_masks_partition_the_moving_mask_and_the_front_sphere_hides_the_box():
    scene = get_scene("crossing", tiny=True)
    assert [o.name for o in scene.objects] == ["sphere", "box", "card"]
    moving = scene.render(MEET_US)[2]
    sphere, box, card = scene.object_masks(MEET_US)
    assert not (sphere & box).any() and not (sphere & card).any() and not (box & card).any()
    np.testing.assert_array_equal(sphere | box | card, moving)
    # The sphere is nearest: its mask is its analytic silhouette (edge pixels aside).
    disc = sphere_silhouette(scene.object_centre(MEET_US, 0), 0.26, scene.c2w(MEET_US), scene)
    assert disc.sum() > 300 and (disc ^ sphere).sum() <= 0.03 * disc.sum()
    # Without the sphere the box shows more: exactly what the sphere's silhouette covered.
    alone = replace(scene, primitives=[p for p in scene.primitives if p.group != "sphere"])
    box_alone = alone.object_masks(MEET_US)[0]
    hidden = box_alone & disc
    assert hidden.sum() > 0.3 * box_alone.sum() and box.sum() < 0.7 * box_alone.sum()
    assert (box ^ (box_alone & ~sphere)).sum() == 0


def test_each_object_group_is_one_object_and_ungrouped_movers_are_their_own():
    scene = get_scene("ball", tiny=True)
    ball = scene.primitives[-1]
    prims = [*scene.primitives, replace(ball, group=None), replace(ball, group=None)]
    grouped = replace(scene, primitives=prims)
    assert [o.name for o in grouped.objects] == ["ball", "object1", "object2"]
    assert [o.parts for o in grouped.objects] == [(2,), (3,), (4,)]


@pytest.mark.parametrize("name", [*NEW, "pair", "paddle", "approach", "slalom"])
def test_new_scenes_movers_are_visible_at_tiny_size_and_move(name):
    scene = get_scene(name, tiny=True)
    assert (scene.width, scene.height) == (96, 96) and scene.description
    times = np.linspace(0, scene.duration_us, 7).astype(int)
    for k, obj in enumerate(scene.objects):
        masks = [scene.object_masks(int(t))[k] for t in times]
        widest = max(np.ptp(np.nonzero(m)[1]) + 1 if m.any() else 0 for m in masks)
        assert widest >= 10, f"{obj.name} is at most {widest} px across"
        centres = np.stack([scene.object_centre(int(t), k) for t in times])
        moved = np.linalg.norm(centres - centres[0], axis=1).max()
        changed = max((m ^ masks[0]).sum() for m in masks)
        assert moved > 0.3 or (name in ("spinner", "paddle") and changed > 0.5 * masks[0].sum())


@pytest.mark.parametrize("name", NEW)
def test_new_scenes_movers_blur_a_30fps_camera(name):
    # As tests/test_scenes.py: within one 33 ms exposure most mover pixels change by more than
    # one event threshold (0.2 in log intensity).
    s = get_scene(name)
    s = get_scene(name, size=(s.width // 4, s.height // 4))
    for t in (100_000, 400_000):
        (a, _, m0), (b, _, m1) = (s.render(t) for t in (t, t + 33_333))
        dl = np.abs(np.log(a.mean(-1) + 1e-3) - np.log(b.mean(-1) + 1e-3))
        assert m0.any() and (dl[m0 | m1] > 0.2).mean() > 0.4


def test_spinner_turns_in_place_and_watch_has_a_still_camera():
    spinner = get_scene("spinner", tiny=True)
    np.testing.assert_array_equal(spinner.object_centre(0), spinner.object_centre(600_000))
    watch = get_scene("watch", tiny=True)
    poses = watch.c2w(np.linspace(0, watch.duration_us, 9))
    np.testing.assert_array_equal(poses, np.broadcast_to(np.eye(4), poses.shape))


def test_enter_leave_one_object_enters_and_the_other_leaves():
    scene = get_scene("enter_leave", tiny=True)
    start, end = scene.object_masks(0), scene.object_masks(scene.duration_us)
    assert not start[0].any() and end[0].sum() > 100  # the sphere enters
    assert start[1].sum() > 100 and not end[1].any()  # the box leaves


def test_approach_box_halts_and_ball_grows_along_its_ray():
    scene = get_scene("approach", tiny=True)
    box, ball = (p for p in scene.primitives if p.moving)
    np.testing.assert_array_equal(box.pose(0.23), box.pose(0.39))  # the halt
    assert not np.allclose(box.pose(0.1), box.pose(0.23))
    assert not np.allclose(box.pose(0.39), box.pose(0.5))
    first, last = scene.object_masks(0)[1], scene.object_masks(scene.duration_us)[1]
    assert last.sum() > 2 * first.sum()  # 4.3 m to 2.7 m: (4.3 / 2.7)^2 = 2.5 times the area
    # Seen from the camera path's centre, its bearing turns by less than its first angular
    # radius: it moves along its ray (the camera's own motion still moves it in the picture).
    (x0, y0, z0), (x1, y1, z1) = ball.pose(0.0)[:3, 3], ball.pose(0.6)[:3, 3]
    assert np.hypot(x1 / z1 - x0 / z0, y1 / z1 - y0 / z0) < scene.object_radius(1) / z0


@pytest.fixture(scope="module")
def crossing_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("objects") / "crossing"
    return simulate_dataset("crossing", out, tiny=True, seed=0, progress=False)


def test_a_dataset_holds_each_objects_mask_centre_and_path(crossing_data):
    scene = get_scene("crossing", tiny=True)
    data = load_dataset(crossing_data)
    assert [t.name for t in data.tracks] == ["sphere", "box", "card"] and data.track is data.tracks[
        0
    ]
    np.testing.assert_allclose(
        [t.radius for t in data.tracks], [0.26, scene.object_radius(1), scene.object_radius(2)]
    )
    for k, track in enumerate(data.tracks):
        want = np.stack([scene.object_centre(int(t), k) for t in track.times_us])
        np.testing.assert_allclose(track.centres, want, atol=1e-12)
    for f in data.test_frames:
        assert [o.name for o in f.objects] == ["sphere", "box", "card"]
        masks = [read_png(o.mask_path) > 0.5 for o in f.objects]
        np.testing.assert_array_equal(np.sum(masks, axis=0) > 0, read_png(f.mask_path) > 0.5)
        assert np.sum(masks, axis=0).max() <= 1
        for k, o in enumerate(f.objects):
            np.testing.assert_allclose(o.centre, scene.object_centre(f.time_us, k), atol=1e-12)
        np.testing.assert_array_equal(f.object_centre, f.objects[0].centre)


def test_a_dataset_listing_different_objects_per_frame_is_reported(crossing_data, tmp_path):
    import shutil

    from evsplat.data.dataset import check_dataset

    broken = tmp_path / "broken"
    shutil.copytree(crossing_data, broken)
    frames = json.loads((broken / "test" / "frames.json").read_text())
    frames[1]["objects"] = frames[1]["objects"][:2]
    frames[2]["objects"][0]["mask"] = "nowhere.png"
    (broken / "test" / "frames.json").write_text(json.dumps(frames))
    problems = check_dataset(broken)
    assert any("frame 1 lists objects ['sphere', 'box'] but frame 0" in p for p in problems)
    assert any("nowhere.png: missing" in p for p in problems)


@pytest.mark.parametrize("name", ["crossing", "enter_leave", "watch"])
def test_a_mover_passing_in_front_of_another_is_more_than_its_radius_nearer(name):
    """Where two movers overlap in the picture, the farther one's surface lies more than the
    nearer one's radius behind the nearer one's (the depth tolerance of
    ``evsplat.motion_metrics``), so each object's Gaussians are told apart; each mover rendered
    alone gives its depth everywhere it covers."""
    scene = get_scene(name, tiny=True)
    alone = [
        replace(scene, primitives=[p for p in scene.primitives if p.group == o.name])
        for o in scene.objects
    ]
    radii = [scene.object_radius(k) for k in range(len(scene.objects))]
    overlaps = 0
    for t in np.linspace(0, scene.duration_us, 13).astype(int):
        depths = [s.render(int(t))[1] for s in alone]
        for a in range(len(depths)):
            for b in range(len(depths)):
                both = (depths[a] > 0) & (depths[b] > 0) & (depths[a] < depths[b])
                overlaps += int(both.sum())
                assert np.all(depths[b][both] > depths[a][both] + radii[a]), (t, a, b)
    assert overlaps > 0 or name == "enter_leave"
