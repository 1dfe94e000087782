"""The motion module's steps, each against an independent oracle: rotations against scipy's,
regions and tracks against the shapes and paths they were drawn from, the turn against the
rate the events were made with, the path's ends against straight-line motion."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy import ndimage
from scipy.spatial.transform import Rotation

from evsplat.config import MoverConfig
from evsplat.model.motion import BEHIND, FREE, ObjectMotion, quat_multiply, rotvec_to_quat
from evsplat.motion import border, seed
from evsplat.motion.align import align
from evsplat.motion.paths import (
    circling,
    despiked,
    hops,
    steadied,
    turn_angles,
    turns,
    two_ends,
)
from evsplat.motion.seed import (
    between_placed,
    ends_offset,
    in_view,
    joined_ends,
    off_their_line,
    projected,
    reference,
    slid,
    smear,
    span,
)
from evsplat.motion.segment import Blob, _blob, apart, floor, made_by_events, pooled, regions
from evsplat.motion.tracks import Track, _rejoined, beside_line, chain, partial
from evsplat.motion.turn import (
    STEADY_P,
    WindowEvents,
    axis_rate,
    long_axis,
    steady,
    turn_rate,
    warped_variance,
)
from evsplat.projection import back_project, project, project_points, world_to_camera

SEGMENT = MoverConfig(pool=3, blur_px=1.0, low=3.0, high=9.0, close_px=2, min_area_px=12, join=0.5)
TRACKS = MoverConfig(gate=1.5, coast=3, min_windows=4, high=9.0, min_evidence=30.0, together=1.5)


def test_rotvec_to_quat_matches_scipy_and_is_finite_at_zero():
    v = np.random.default_rng(0).normal(size=(50, 3)) * np.array([[2.0], *[[1.0]] * 49])
    q = rotvec_to_quat(torch.tensor(v))
    want = Rotation.from_rotvec(v).as_quat()  # scipy: (x, y, z, w)
    want = np.concatenate([want[:, 3:], want[:, :3]], 1)
    want *= np.sign(want[:, :1])
    assert np.allclose(q.numpy() * np.sign(q.numpy()[:, :1]), want, atol=1e-12)
    zero = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    rotvec_to_quat(zero).sum().backward()
    assert torch.isfinite(zero.grad).all()
    assert torch.allclose(zero.grad, torch.tensor([[0.5, 0.5, 0.5]], dtype=torch.float64))


def test_quat_multiply_composes_rotations_as_scipy_does():
    a, b = Rotation.random(2, random_state=1)
    qa, qb = (torch.tensor(np.roll(r.as_quat(), 1)) for r in (a, b))
    got = quat_multiply(qa, qb).numpy()
    want = np.roll((a * b).as_quat(), 1)
    assert np.allclose(got * np.sign(got[0]), want * np.sign(want[0]), atol=1e-12)


def test_object_motion_moves_each_objects_gaussians_rigidly_and_leaves_the_scene():
    g = 5
    centres = torch.tensor([[0.0, 0.0, 3.0], [1.0, 0.0, 4.0]])
    trans = torch.zeros(2, g, 3)
    trans[0, :, 0] = torch.linspace(0, 1, g)  # object 0 slides 1 m along x over the sequence
    rot = torch.zeros(2, g, 3)
    rot[1, :, 2] = torch.linspace(0, np.pi, g)  # object 1 turns half a turn about z
    motion = ObjectMotion(centres, torch.tensor([0.5, 0.5]), trans, rot)
    means = torch.tensor([[0.1, 0.2, 3.0], [1.5, 0.0, 4.0], [9.0, 9.0, 9.0]])
    quats = torch.tensor([[1.0, 0, 0, 0]] * 3)
    ids = torch.tensor([0, 1, -1])
    moved, turned = motion.apply(means, quats, ids, 0.5)
    assert torch.allclose(moved[0], torch.tensor([0.6, 0.2, 3.0]), atol=1e-6)
    # A quarter turn about z at t = 0.5: (0.5, 0) about the centre goes to (0, 0.5).
    assert torch.allclose(moved[1], torch.tensor([1.0, 0.5, 4.0]), atol=1e-6)
    assert torch.equal(moved[2], means[2]) and torch.equal(turned[2], quats[2])
    want = np.roll(Rotation.from_rotvec([0, 0, np.pi / 2]).as_quat(), 1)
    assert np.allclose(turned[1].detach().numpy(), want, atol=1e-6)
    assert float(motion.prior_loss().detach()) == 0.0
    again = ObjectMotion.from_state(motion.state())
    assert torch.equal(
        again.apply(means, quats, ids, 0.3)[0], motion.apply(means, quats, ids, 0.3)[0]
    )


def _disc(shape, centre, radius):
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    return ((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) <= radius**2


def _disc_blob(shape, t_us, centre, radius, contrast=20.0):
    """A region that is the whole disc of ``radius`` at ``centre``."""
    mask = _disc(shape, centre, radius)
    return Blob(t_us, np.asarray(centre, dtype=np.float64), mask, float(mask.sum()), contrast)


def _seen_blob(shape, t_us, centre, radius, contrast=20.0):
    """A region that is the part of the disc of ``radius`` at ``centre`` inside the image,
    centred on that part (as the segmentation centres a disc the border cuts)."""
    mask = _disc(shape, centre, radius)
    return _blob(mask, mask.astype(np.float64), t_us, contrast)


def _ring_residual(shape, discs, seed=0):
    """A residual map: noise everywhere, and the outlines of ``discs`` (centre, radius)
    firing as a moving object's edges do."""
    rng = np.random.default_rng(seed)
    r = np.abs(rng.normal(0.0, 0.02, shape))
    for centre, radius in discs:
        r += 0.5 * (_disc(shape, centre, radius) & ~_disc(shape, centre, radius - 2))
    return r


def _camera_sliding(speed: float):
    """Camera-to-world poses at µs times: looking down +z, sliding along x at ``speed`` m/s."""

    def pose(t_us):
        t = np.asarray(t_us, dtype=np.float64)
        out = np.broadcast_to(np.eye(4), (*t.shape, 4, 4)).copy()
        out[..., 0, 3] = speed * t * 1e-6
        return out

    return pose


def _still_camera(f: float) -> SimpleNamespace:
    """The ``Views`` that ``seed.projected`` and ``seed.in_view`` read: a camera at the origin
    for good (focal ``f`` px, 96 x 96 px, principal point 48, 48), times in seconds."""
    K = np.array([[f, 0.0, 48.0], [0.0, f, 48.0], [0.0, 0.0, 1.0]])
    still = SimpleNamespace(pose=_camera_sliding(0.0))
    return SimpleNamespace(
        data=SimpleNamespace(trajectory=still, K=K, width=96, height=96),
        renderer=SimpleNamespace(time=lambda t_us: t_us / 1e6),
    )


def test_projected_gives_each_objects_pixel_centre_and_radius_on_its_path():
    # Two objects, 0.2 m and 0.1 m in radius, 2 m and 4 m in front of a camera at the origin
    # (f = 128 px, principal point 48, 48); the first slides 1 m along x over the sequence. At
    # its middle the first is at x = 0.5 m: 48 + 128 * 0.5 / 2 = 80 px, radius 128 * 0.2 / 2.
    g, f = 5, 128.0
    trans = torch.zeros(2, g, 3)
    trans[0, :, 0] = torch.linspace(0, 1, g)
    motion = ObjectMotion(
        torch.tensor([[0.0, 0.0, 2.0], [-1.0, 0.5, 4.0]]), torch.tensor([0.2, 0.1]), trans,
        torch.zeros(2, g, 3),
    )  # fmt: skip
    views = _still_camera(f)
    uv, radii = projected(motion, views, 500_000.0)
    assert np.allclose(uv, [[80.0, 48.0], [16.0, 64.0]], atol=1e-4)
    assert np.allclose(radii, [12.8, 3.2], atol=1e-5)
    # Carried 5 m back along the ray it is behind the camera: no place in the image, no size.
    trans[1, :, 2] = torch.linspace(0, -10, g)
    behind = ObjectMotion(motion.centres, motion.radii, trans, torch.zeros(2, g, 3))
    uv, radii = projected(behind, views, 500_000.0)
    assert np.allclose(uv[0], [80.0, 48.0], atol=1e-4) and np.isnan(uv[1]).all()
    assert radii[1] == 0.0 and np.isfinite(radii).all()


def test_regions_finds_every_object_at_its_place_and_none_in_noise():
    shape = (96, 128)
    discs = [((30.0, 40.0), 10.0), ((90.0, 60.0), 14.0)]
    blobs = regions(_ring_residual(shape, discs), 0, SEGMENT)
    assert len(blobs) == 2
    found = sorted(blobs, key=lambda b: b.centre[0])
    for blob, (centre, radius) in zip(found, discs):
        assert np.linalg.norm(blob.centre - centre) < 1.0
        assert radius <= blob.radius <= radius + 3  # the whole disc, and a blur's rim
    assert regions(_ring_residual(shape, []), 0, SEGMENT) == []


def test_a_still_cameras_empty_background_does_not_swell_the_regions():
    # Under a still camera only the movers fire: the residual is exactly zero elsewhere, its
    # MAD is zero, and the one-event floor keeps the blur's faint tails out of the regions.
    shape, c = (96, 96), 0.2
    residual = np.zeros(shape)
    discs = [((28.0, 48.0), 10.0), ((62.0, 48.0), 10.0)]
    for centre, radius in discs:
        residual += 2 * c * (_disc(shape, centre, radius) & ~_disc(shape, centre, radius - 2))
    least = floor(c, c, SEGMENT.pool)
    blobs = sorted(regions(residual, 0, SEGMENT, least), key=lambda b: b.centre[0])
    assert len(blobs) == 2
    for blob, (centre, radius) in zip(blobs, discs):
        assert np.linalg.norm(blob.centre - centre) < 1.0
        assert radius <= blob.radius <= radius + 3


def test_a_change_the_render_draws_where_no_event_fired_is_no_mover():
    # A still camera: a disc 1.0 brighter in log intensity than the wall (5 events of C = 0.2)
    # moves 4 px right and fires its leading and trailing edges. The
    # render has half of that change, and the whole of a disc that moves where nothing is (an
    # object's Gaussians strayed off it). Both leave a residual; only the first made events.
    shape, c = (96, 96), 0.2

    def moved(x, y):  # the log change as the disc moves from x to x + 4
        return _disc(shape, (x + 4, y), 10.0).astype(float) - _disc(shape, (x, y), 10.0)

    esi = torch.from_numpy(moved(28.0, 30.0))
    change = torch.from_numpy(0.5 * moved(28.0, 30.0) + moved(60.0, 70.0))
    found = regions(pooled(esi - change, SEGMENT.pool), 0, SEGMENT, floor(c, c, SEGMENT.pool))
    assert len(found) == 2
    kept = made_by_events(found, esi, change, SEGMENT.pool, 0.1)
    assert len(kept) == 1 and np.linalg.norm(kept[0].centre - (30.0, 30.0)) < 2.0


@pytest.mark.parametrize("seed", range(5))
def test_a_slow_faint_object_is_found_by_a_longer_window_and_a_fast_one_only_once(seed):
    # A moving camera's residual noise everywhere; a small disc 0.3 brighter in log intensity
    # crawling at 0.1 px/ms, and a large one 1.0 brighter at 1 px/ms. In a 9 ms window the
    # crawler's edges move 0.9 px, a sliver that the pool and the blur spread under ``high``;
    # in 36 ms, 3.6 px. The fast disc's longer-window crescents lie on its short-window region.
    # The two lie apart by over ``SEPARATE`` x their regions' radii (about 17 and 8 px).
    shape = (96, 96)
    slow, fast = ((24.0, 24.0), 6.0, 0.1, 0.3), ((60.0, 64.0), 12.0, 1.0, 1.0)

    def window(ms):
        change = np.random.default_rng(seed).normal(0.0, 0.1, shape)
        for (x, y), radius, speed, contrast in (slow, fast):
            d = 0.5 * speed * ms
            change += contrast * (
                _cover(shape, (x + d, y), radius) - _cover(shape, (x - d, y), radius)
            )
        return regions(pooled(torch.from_numpy(change), SEGMENT.pool), 0, SEGMENT)

    short, longer = window(9), window(36)
    assert [np.linalg.norm(b.centre - fast[0]) < 1.0 for b in short] == [True]
    (added,) = apart(longer, short)
    assert np.linalg.norm(added.centre - slow[0]) < 1.0


def test_a_slow_objects_two_edges_only_a_longer_window_shows_are_one_region():
    # Where the short window shows nothing, a slow object's leading and trailing edges are two
    # regions of the longer window (the DAVIS346 sample's third car, 12 px apart, radii 4.4 and
    # 3.3): within ``SEPARATE`` x their radii they are one, centred between them by area; a
    # region farther off is another object.
    shape = (96, 96)
    leading, trailing = (
        _disc_blob(shape, 0, (40.0, 48.0), 5.0),
        _disc_blob(shape, 0, (56.0, 48.0), 5.0),
    )
    other = _disc_blob(shape, 0, (84.0, 48.0), 5.0)
    one, another = apart([leading, trailing, other], [])
    assert np.allclose(one.centre, (48.0, 48.0)) and one.area == leading.area + trailing.area
    assert (one.mask == (leading.mask | trailing.mask)).all()
    assert another is other


@pytest.mark.parametrize("seed", range(5))
def test_a_slow_objects_other_edge_in_a_longer_window_is_no_second_object(seed):
    # A large disc (radius 19 px) crawling right at 0.12 px/ms over a background whose step to it
    # is 0.6 in log intensity behind it and 0.15 ahead of it: a 9 ms window sees its trailing
    # edge only; over 36 ms its faint leading edge fires too, as a region of its own 30-40 px
    # from the trailing one's in most seeds (measured 2026-12-03: 3 of these 5).
    shape, (x, y), radius, speed = (96, 96), (48.0, 48.0), 19.0, 0.12
    behind = np.arange(shape[1])[None, :] + 0.5 < x

    def window(ms):
        d = 0.5 * speed * ms
        moved = _cover(shape, (x + d, y), radius) - _cover(shape, (x - d, y), radius)
        change = np.random.default_rng(seed).normal(0.0, 0.1, shape)
        change += np.where(behind, 0.6, 0.15) * moved
        return regions(pooled(torch.from_numpy(change), SEGMENT.pool), 0, SEGMENT)

    short, longer = window(9), window(36)
    assert len(short) == 1 and short[0].centre[0] < x - 0.5 * radius
    assert apart(longer, short) == []


def _cover(shape, centre, radius, k=4):
    """[H,W] the share of each pixel that the disc covers (``k`` x ``k`` samples per pixel)."""
    ys, xs = np.mgrid[0 : shape[0] * k, 0 : shape[1] * k] + 0.5
    inside = (xs / k - centre[0]) ** 2 + (ys / k - centre[1]) ** 2 <= radius**2
    return inside.reshape(shape[0], k, shape[1], k).mean((1, 3))


def test_pieces_of_one_object_are_one_region():
    shape = (96, 96)
    residual = _ring_residual(shape, [])
    residual[30:50, 30:45] += 0.5  # one object's texture in two pieces 6 px apart
    residual[30:50, 51:60] += 0.5
    (blob,) = regions(residual, 0, SEGMENT)
    assert abs(blob.area - 20 * 30) < 0.35 * 20 * 30


def _crossing_windows(n=30):
    """Two discs crossing in opposite directions, one hidden for two windows, plus a one-window
    noise region: the regions of each window and each object's true centres."""
    shape = (96, 128)
    per_window, truth = [], {0: {}, 1: {}}
    for k in range(n):
        a = (10.0 + 3.5 * k, 40.0)
        b = (118.0 - 3.5 * k, 56.0)
        discs = [(a, 8.0)] + ([] if k in (20, 21) else [(b, 8.0)])
        if k == 7:
            discs.append(((64.0, 10.0), 6.0))
        truth[0][k], truth[1][k] = np.array(a), np.array(b)
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    return per_window, truth


def test_tracks_keep_two_crossing_objects_apart_and_drop_noise():
    per_window, truth = _crossing_windows()
    tracks = chain(per_window, TRACKS)
    assert len(tracks) == 2
    for track in tracks:
        ks = sorted(track.blobs)
        who = min(truth, key=lambda o: np.linalg.norm(truth[o][ks[0]] - track.blobs[ks[0]].centre))
        # Where the two regions merged, the track's centre is its own path's, not the merged
        # region's (which lies between the objects).
        for k, centre in zip(ks, track.centres):
            assert np.linalg.norm(centre - truth[who][k]) < 1.0, (who, k)
    assert sum(len(t.blobs) for t in tracks) >= 2 * 30 - 2 - 6  # hidden twice, merged a few


def test_a_faint_track_is_noise_under_a_moving_camera_and_an_object_under_a_still_one():
    # A disc crossing for 14 windows whose regions peak 1 robust sigma over `high`: 14 of
    # evidence against `min_evidence` 30. A moving camera's static model can make such a track
    # of its own error; a still camera's draws no change, so its regions are events'.
    faint = TRACKS.high + 1.0
    per_window = [[_disc_blob((96, 128), k, (20.0 + 3.0 * k, 50.0), 8.0, faint)] for k in range(14)]
    assert chain(per_window, TRACKS) == []
    (track,) = chain(per_window, TRACKS, still=True)
    assert sorted(track.blobs) == list(range(14))


def test_a_track_never_clear_of_the_border_is_no_object_and_one_that_comes_in_is():
    # A region wobbling in the corner for 20 windows, cut by the border in every one (the
    # scene's edge coming into view as the camera moves), and a disc sliding in through the
    # left border until it is whole: both fire strongly; only the second is an object.
    shape = (96, 128)
    per_window = [
        [
            _disc_blob(shape, k, (124.0 + (k % 3), 92.0 - (k % 2)), 7.0),
            _disc_blob(shape, k, (-6.0 + 2.0 * k, 40.0), 8.0),
        ]
        for k in range(20)
    ]
    (track,) = chain(per_window, TRACKS)
    assert all(track.blobs[k].centre[1] == 40.0 for k in track.blobs)
    assert not all(border.touches_border(b.mask) for b in track.blobs.values())


def test_faint_spells_of_an_object_join_it_where_their_evidence_together_passes():
    # A disc is seen for 8 windows, lost for 12 (it passes something that fires more) and seen
    # again on its course for 8. Its first spell peaks 2 robust sigmas over `high` (16 of
    # evidence against `min_evidence` 30: noise by itself), its second 5 (40): the first is the
    # object's too. Two spells of 2 (32 together) are one object too; two of 1.5 (24) noise.
    seen = [*range(8), *range(20, 28)]

    def windows(later: float, first: float = 2.0) -> list[list]:
        peak = [TRACKS.high + (first if k < 8 else later) for k in range(28)]
        centres = [(15.0 + 3.0 * k, 50.0) for k in range(28)]
        return [
            [_disc_blob((96, 128), k, centres[k], 8.0, peak[k])] if k in seen else []
            for k in range(28)
        ]

    for later in (5.0, 2.0):
        (track,) = chain(windows(later), TRACKS)
        assert sorted(track.blobs) == seen
    assert chain(windows(1.5, first=1.5), TRACKS) == []


# A disc's centres, 2 px per window, out through the right border of a 96 x 128 image from k = 29.
LEAVING = [np.array([60.0 + 2.0 * k, 48.0]) for k in range(36)]


def _leaving_centred(track: Track, centres: np.ndarray, radius: float) -> int:
    """Asserts that every one of ``track``'s ``centres`` [F,2] whose disc of ``radius`` on
    ``LEAVING`` is at least 30% in view lies within 1.5 px of it; how many are under 80%."""
    cut = 0
    for k, centre in zip(sorted(track.blobs), centres):
        visible = _disc((96, 128), LEAVING[k], radius).sum() / (np.pi * radius**2)
        if visible < 0.3:
            continue  # a sliver: its shape says little
        cut += visible < 0.8
        assert np.linalg.norm(centre - LEAVING[k]) < 1.5, (k, centre, LEAVING[k])
    return cut


def test_an_object_leaving_the_image_is_centred_by_its_whole_shape():
    shape, radius = (96, 128), 10.0
    per_window = [
        regions(_ring_residual(shape, [(centre, radius)], seed=k), k, SEGMENT)
        for k, centre in enumerate(LEAVING)
    ]
    (track,) = chain(per_window, TRACKS)
    assert _leaving_centred(track, track.centres, radius) >= 3  # visible part's centre: 2-5 px in
    assert track.radius >= radius


def test_pieces_of_one_object_are_one_track_while_one_piece_fires_faintly():
    # One object seen as two regions 28 px apart: a large piece and a small one below it (the
    # demo's ball: its upper part and its lower edge). For a third of the windows the large
    # piece fires only near its centre and its region shrinks to half the size; the object's
    # size did not change, and the pieces still move together.
    shape = (96, 128)
    per_window = []
    for k in range(30):
        top = np.array([20.0 + 3 * k, 30.0])
        discs = [(top, 6.0 if 10 <= k < 20 else 12.0), (top + [0.0, 28.0], 4.0)]
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    assert sum(len(blobs) == 2 for blobs in per_window) >= 25  # apart, not closed into one
    (track,) = chain(per_window, TRACKS)
    assert sorted(track.blobs) == list(range(30))


def test_a_track_keeps_its_object_when_a_new_region_starts_beside_it():
    # The disc turns sharply at window 20 (as the demo's ball bounces) just as a small region
    # starts a track next to where it goes: nearer in pixels than the disc's own prediction,
    # but tentative, so the disc's track keeps the disc.
    shape, radius = (96, 128), 10.0
    per_window, truth = [], []
    for k in range(30):
        centre = np.array(
            [20.0 + 2 * k, 48.0] if k < 20 else [58.0 + 2 * (k - 20), 64.0 + 2 * (k - 20)]
        )
        discs = [(centre, radius)] + ([((58.0, 78.0), 4.0)] if k == 19 else [])
        truth.append(centre)
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    (track,) = chain(per_window, TRACKS)
    assert sorted(track.blobs) == list(range(30))
    assert all(np.linalg.norm(c - truth[k]) < 1.0 for k, c in zip(range(30), track.centres))


def test_two_tracked_objects_joined_into_one_region_are_split_again():
    # Two discs pass 22 px apart: at window 13 their rings are pieces that ``join`` unites (at
    # 14-16 one piece, which cannot be split). Each piece is the one a confirmed track predicts
    # nearest, so the region is split and each track keeps its own disc there.
    shape, dy = (96, 128), 22.0
    per_window, truth = [], []
    for k in range(30):
        a, b = (20.0 + 3 * k, 48.0 - dy / 2), (108.0 - 3 * k, 48.0 + dy / 2)
        truth.append((np.array(a), np.array(b)))
        per_window.append(regions(_ring_residual(shape, [(a, 8.0), (b, 8.0)], seed=k), k, SEGMENT))
    assert len(per_window[13]) == 1 and len(per_window[13][0].parts) == 2
    tracks = chain(per_window, TRACKS)
    assert len(tracks) == 2
    for track in tracks:
        own = np.argmin([np.linalg.norm(track.blobs[0].centre - c) for c in truth[0]])
        assert 13 in track.blobs and 13 not in track.shared
        assert np.linalg.norm(track.blobs[13].centre - truth[13][own]) < 1.0


def test_a_track_that_jumps_onto_noise_does_not_take_a_far_object():
    # A disc moving 2 px per window is lost at window 10, where a small noise region 22 px ahead
    # takes its track. Three windows on, another object appears 60 px further: at the jump's
    # speed the track would reach it, at its usual one it does not; they are two tracks.
    shape = (96, 128)
    per_window = []
    for k in range(30):
        discs = [((20.0 + 2 * k, 48.0), 8.0)] if k < 10 else []
        discs += [((60.0, 48.0), 4.0)] if k == 10 else []
        discs += [((120.0 - (k - 13), 48.0), 8.0)] if k >= 13 else []
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    tracks = chain(per_window, TRACKS)
    assert len(tracks) == 2
    assert not any(min(t.blobs) < 10 and max(t.blobs) >= 13 for t in tracks)


def test_an_object_keeps_its_track_as_it_turns_while_a_small_one_hides_in_it():
    # A disc goes right, then turns down at window 10, over a small still object seen in windows 4-8
    # and unseen from then: inside the disc's region in windows 11-15, which are shared. Predicted
    # from its last own sighting (window 10), the disc's track went on right and the small one's,
    # nearer, took the disc (`blobs`, docs/experiments/objects.md); predicted from its last
    # sighting, shared too, the disc's track keeps the disc.
    shape = (160, 128)
    disc = [(16.0 + 4 * k, 50.0) if k <= 10 else (56.0, 50.0 + 4 * (k - 10)) for k in range(30)]
    per_window = [[_disc_blob(shape, k, disc[k], 14.0)] for k in range(30)]
    for k in range(4, 9):
        per_window[k].append(_disc_blob(shape, k, (64.0, 62.0), 4.0))
    tracks = chain(per_window, TRACKS)
    assert sorted(len(t.blobs) for t in tracks) == [5, 30]
    assert sorted(tracks[0].hidden or tracks[1].hidden) == [11, 12, 13, 14, 15]
    assert all(b.radius > 10 for b in tracks[0].blobs.values())  # the longest first: the disc's


def test_the_two_edges_of_a_plain_object_are_one_track_and_a_faster_one_another():
    # A plain box fires only at its leading and trailing edges: two bars 26 px apart, each far
    # smaller than their distance, that keep their offset as they go. A disc beside them, going
    # right 3 px per window while they go 2.2 px down and right, is another object.
    shape = (96, 160)
    per_window, truth = [], []
    for k in range(30):
        box = np.array([20.0 + 2 * k, 30.0 + k])
        residual = _ring_residual(shape, [((30.0 + 3 * k, 75.0), 8.0)], seed=k)
        for edge in (-13, 13):
            x = int(box[0]) + edge
            residual[int(box[1]) - 10 : int(box[1]) + 10, x - 1 : x + 2] += 0.5
        truth.append(box + [0.5, 0.0])  # the bars' pixel centres
        per_window.append(regions(residual, k, SEGMENT))
    assert all(len(blobs) == 3 for blobs in per_window)  # the bars are apart in every window
    tracks = chain(per_window, TRACKS)
    assert len(tracks) == 2
    edges = min(tracks, key=lambda t: t.centres[0][1])  # the upper: the disc stays at y = 75
    assert sorted(edges.blobs) == list(range(30))
    assert all(np.linalg.norm(c - truth[k]) < 1.5 for k, c in zip(range(30), edges.centres))


@pytest.mark.parametrize("back_radius", [10.0, 20.0])
def test_an_object_that_leaves_and_comes_back_through_the_same_border_is_one_track(back_radius):
    # A disc leaves through the right border and comes back through it lower down 8 windows
    # later, while another enters through the left border. A region inside the image beside
    # where it left is not the disc, which can come back only through the border. Only a
    # returning object of the same size is the one that left; one twice as large is another.
    shape = (96, 128)
    per_window, truth = [], {}
    for k in range(30):
        out = np.array([84.0 + 4 * k, 40.0])  # gone from window 13
        back = np.array([136.0 - 4 * (k - 20), 70.0])  # in from window 20
        other = np.array([-6.0 + 4 * (k - 22), 20.0])  # in from window 22
        discs = [(out, 10.0)] if k < 15 else [(back, back_radius)] if k >= 20 else []
        discs += [(other, 8.0)] if k >= 22 else []
        discs += [((118.0, 44.0), 4.0)] if k == 16 else []  # noise near where it left
        truth[k] = (out if k < 15 else back, other)
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    tracks = chain(per_window, TRACKS)
    left = [t for t in tracks if min(t.blobs) < 15]
    assert len(left) == 1 and len(tracks) == (2 if back_radius == 10.0 else 3)
    (mover,) = left
    if back_radius == 10.0:
        assert min(mover.blobs) <= 1 and max(mover.blobs) == 29
        for k, centre in zip(sorted(mover.blobs), mover.centres):
            visible = _disc(shape, truth[k][0], 10.0).sum() / (np.pi * 10.0**2)
            if visible >= 0.3:
                assert np.linalg.norm(centre - truth[k][0]) < 1.5, (k, centre, truth[k][0])
    else:
        assert max(mover.blobs) < 15


def test_an_object_back_after_its_track_took_noise_at_the_border_is_one_track():
    # A disc leaves through the right border; while unseen, its track takes two small noise
    # regions on that border near where it left (a fit's residual there). It comes back 45 px
    # lower 7 windows after it left: its exit is its last sighting of itself, not the noise.
    shape = (96, 128)
    per_window, truth = [], {}
    for k in range(30):
        out = np.array([84.0 + 4 * k, 40.0])  # last seen at window 13
        back = np.array([138.0 - 4 * (k - 20), 85.0])  # in from window 20
        discs = [(out, 10.0)] if k < 15 else [(back, 10.0)] if k >= 20 else []
        discs += [((126.0, 44.0 + k - 15), 4.0)] if k in (15, 16) else []
        truth[k] = out if k < 15 else back
        per_window.append(regions(_ring_residual(shape, discs, seed=k), k, SEGMENT))
    (mover,) = chain(per_window, TRACKS)
    assert min(mover.blobs) <= 1 and set(range(21, 30)) <= set(mover.blobs)
    for k, centre in zip(sorted(mover.blobs), mover.centres):
        if _disc(shape, truth[k], 10.0).sum() / (np.pi * 10.0**2) >= 0.3:
            assert np.linalg.norm(centre - truth[k]) < 1.5, (k, centre, truth[k])


def test_an_object_back_through_a_track_that_took_the_borders_noise_before_it_left_is_one():
    # A disc leaves through the right border at window 13. Another track took noise on that border
    # from window 10, while the disc was still in view, and then the disc coming back lower down
    # from window 20. It comes back at its first sighting after the disc left: one object, without
    # the noise (the demo's ball, one warm-up of eight; docs/experiments/objects.md).
    shape = (96, 128)
    gone = Track({k: _disc_blob(shape, k, (76.0 + 4 * k, 40.0), 10.0) for k in range(14)})
    noise = {k: _disc_blob(shape, k, (126.0, 70.0 + k), 4.0, contrast=12.0) for k in range(10, 14)}
    back = {k: _disc_blob(shape, k, (132.0 - 4 * (k - 20), 80.0), 10.0) for k in range(20, 30)}
    joined = _rejoined([gone, Track(noise | back)], [], TRACKS)
    assert len(joined) == 1
    assert sorted(joined[0].blobs) == [*range(14), *range(20, 30)]
    assert all(joined[0].blobs[k].area == gone.blobs[k].area for k in range(10, 14))
    # A track seen clear of the border before the disc left is another object in view then.
    inside = {k: _disc_blob(shape, k, (100.0, 60.0 + 2 * k), 6.0) for k in range(10, 14)}
    assert len(_rejoined([gone, Track(inside | back)], [], TRACKS)) == 2


def test_an_object_back_after_its_track_took_faint_noise_to_the_end_is_one_track():
    # A disc leaves through the right border at window 13; its track takes five faint regions after
    # that, on the border and then across the image, to the last window, where the disc's return
    # ends too (the demo's ball, one warm-up of eight; docs/experiments/objects.md). Its exit is the
    # last sighting after which what it took is no object by itself: joined there, noise out.
    shape = (96, 128)
    seen = {k: _disc_blob(shape, k, (76.0 + 4 * k, 40.0), 10.0) for k in range(14)}
    faint = [(17, (126.0, 20.0)), (18, (125.0, 22.0)), (19, (100.0, 50.0)), (23, (50.0, 60.0))]
    noise = {k: _disc_blob(shape, k, c, 4.0, contrast=11.0) for k, c in faint}
    noise[29] = _disc_blob(shape, 29, (40.0, 62.0), 4.0, contrast=11.0)
    back = {k: _disc_blob(shape, k, (132.0 - 4 * (k - 20), 80.0), 10.0) for k in range(20, 30)}
    joined = _rejoined([Track(seen | noise), Track(back)], [], TRACKS)
    assert len(joined) == 1
    assert sorted(joined[0].blobs) == [*range(14), *range(20, 30)]
    assert all(joined[0].blobs[k].area == back[k].area for k in range(20, 30))
    # What it took after leaving is an object by itself (a second disc, strong): two objects.
    other = {
        k: _disc_blob(shape, k, (40.0 + 2 * k, 20.0), 8.0, contrast=30.0) for k in range(17, 30)
    }
    assert len(_rejoined([Track(seen | other), Track(back)], [], TRACKS)) == 2


def test_an_object_back_after_its_track_took_noise_at_the_border_it_left_by_is_one_track():
    # A disc leaves through the right border at window 14. Unseen for two windows, its track takes
    # two faint regions on that border (the static model's error there), then the disc coming back
    # lower down from window 21 (the demo's ball, one warm-up of eight;
    # docs/experiments/objects.md). The track is cut where it left: the noise is dropped, the return
    # joined.
    shape = (96, 128)
    per_window = [[] for _ in range(30)]
    for k in range(15):
        per_window[k].append(_seen_blob(shape, k, (76.0 + 4 * k, 40.0), 10.0))
    for k in (17, 18):
        per_window[k].append(_seen_blob(shape, k, (125.0, 48.0 + 2 * (k - 17)), 4.0, 11.0))
    for k in range(21, 30):
        per_window[k].append(_seen_blob(shape, k, (134.0 - 4 * (k - 21), 75.0), 10.0))
    (mover,) = chain(per_window, TRACKS)
    assert sorted(mover.blobs) == [*range(15), *range(21, 30)]


def test_an_object_whole_at_the_border_unseen_for_two_windows_is_still_its_track():
    # A disc reaches the right border with most of it in view, fires in no region for two
    # windows, then goes back to the left looking smaller (turned): it did not leave, so its
    # track coasts on and takes its next regions. Only a sliver's track is ended after two
    # unseen windows, and a return that much smaller would not be joined to it again.
    shape = (96, 128)
    per_window = [[] for _ in range(24)]
    for k in range(10):  # at the border at window 9
        per_window[k].append(_seen_blob(shape, k, (80.0 + 4 * k, 50.0), 12.0))
    for k in range(12, 24):
        per_window[k].append(_seen_blob(shape, k, (122.0 - 4 * (k - 12), 54.0), 7.0))
    (mover,) = chain(per_window, TRACKS)
    assert sorted(mover.blobs) == [*range(10), *range(12, 24)]


def test_an_object_lost_inside_the_image_longer_than_a_track_coasts_is_one_track():
    # A disc goes unseen for 8 windows (twice `coast` + 1) in the middle of the image, as an
    # object that fires too little beside a brighter one does, and is found again on its
    # course: one track. Another of its size lost in the image, and one first seen later
    # beyond where that one could have gone (its gate), are two objects.
    shape = (96, 128)
    paths = {
        "resumed": lambda k: np.array([15.0 + 3.0 * k, 30.0]),
        "lost": lambda k: np.array([110.0 - 2.0 * k, 80.0]),
        "new": lambda k: np.array([15.0 + 1.0 * (k - 20), 65.0]),
    }
    seen = {
        "resumed": [*range(10), *range(18, 30)],
        "lost": range(9),
        "new": range(20, 30),
    }
    per_window = [
        [_disc_blob(shape, k, paths[name](k), 8.0) for name in paths if k in seen[name]]
        for k in range(30)
    ]
    tracks = chain(per_window, TRACKS)
    assert sorted(sorted(t.blobs) for t in tracks) == sorted(list(w) for w in seen.values())
    for track in tracks:
        ks = sorted(track.blobs)
        name = next(n for n in seen if list(seen[n]) == ks)
        for k, centre in zip(ks, track.centres):
            assert np.linalg.norm(centre - paths[name](k)) < 1e-6, (name, k)


def test_a_balls_centres_not_placed_by_its_outline_lie_between_those_that_are():
    # A ball thrown across the view (4 px a window right, falling 0.3 px a window faster each
    # window), sighted in windows 0-24 but 9, 10 and 18; its outline places it in some of them
    # (the truth, within a tenth of a pixel), its region's usual offset in the others (8 px
    # low, as where the border leaves a sliver). An unplaced one with placed ones at most 4
    # windows apart on both sides is put on the line between them; the others keep theirs
    # unless the border cuts them.
    windows = np.array([k for k in range(25) if k not in (9, 10, 18)])
    times = 12_500 * windows + 6_000
    truth = np.stack([20.0 + 4.0 * windows, 70.0 - 6.0 * windows + 0.15 * windows**2], 1)
    rng = np.random.default_rng(0)
    placed = ~np.isin(windows, [3, 4, 5, 6, 12, 16, 17, 22, 24])
    centres = truth + np.where(placed[:, None], rng.uniform(-0.1, 0.1, truth.shape), [0.0, 8.0])
    out = between_placed(centres, placed, times, windows, 4, np.zeros(len(windows), dtype=bool))
    between = np.isin(windows, [12, 16, 17, 22])  # placed neighbours 2-4 windows apart
    assert np.all(np.linalg.norm(out[between] - truth[between], axis=1) < 1.0)
    kept = ~between  # placed; or unplaced with placed neighbours 5 apart (3-6) or none after (24)
    assert np.array_equal(out[kept], centres[kept])
    # Cut by the border there (going out, coming in), those are read from the line through the
    # two placed ones on the nearer side: at most two windows out, under a pixel of the curve.
    cut = np.isin(windows, [3, 4, 5, 6, 24])
    out = between_placed(centres, placed, times, windows, 4, cut)
    assert np.all(np.linalg.norm(out[cut] - truth[cut], axis=1) < 1.5)
    assert np.array_equal(out[placed], centres[placed])


def test_an_outline_off_the_line_of_the_placed_ones_beside_it_is_dropped():
    # The thrown ball again, every sighting placed, those in windows 8-9 and 17-19 by a cut
    # outline's arc: those arcs within a tenth of a pixel of the truth but windows 8 and 9's,
    # side by side 15 px off along the border, and the last (19), 28 px off where nothing
    # comes after it. The three are dropped; 18, beside the bad 19, is kept.
    windows = np.arange(20)
    times = 12_500 * windows + 6_000
    truth = np.stack([20.0 + 4.0 * windows, 70.0 - 6.0 * windows + 0.15 * windows**2], 1)
    centres = truth + np.random.default_rng(1).uniform(-0.1, 0.1, truth.shape)
    centres[8:10] += [0.0, 15.0]
    centres[19] += [-20.0, 20.0]
    placed = np.ones(len(windows), dtype=bool)
    outlined = np.isin(windows, [8, 9, 17, 18, 19])
    off = off_their_line(centres, placed, outlined, times, windows, gap=4)
    assert np.flatnonzero(off).tolist() == [8, 9, 19]
    # With no arc off, none is dropped.
    assert not off_their_line(truth, placed, outlined, times, windows, gap=4).any()


def test_align_gives_a_one_sided_objects_true_displacements():
    # A shaded ball: its outline fires mostly on one side, and that side turns from window to
    # window, so each region's residual-weighted centre leans 2-4 px a different way. Only
    # the displacements matter to the path: after the alignment they are the true ones.
    shape, radius = (96, 128), 12.0
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    per_window, energy, truth = [], [], []
    for k in range(24):
        centre = np.array([24.0 + 3.3 * k, 40.0 + 0.6 * k])
        lit = 0.9 * k  # the side that fires most (rad)
        side = np.cos(np.arctan2(ys - centre[1], xs - centre[0]) - lit)
        edge = _disc(shape, centre, radius) & ~_disc(shape, centre, radius - 2)
        residual = _ring_residual(shape, [], seed=k) + edge * (0.1 + 0.6 * np.maximum(side, 0))
        per_window.append(regions(residual, k, SEGMENT))
        energy.append(residual)
        truth.append(centre)
    (track,) = chain(per_window, TRACKS)
    ks = sorted(track.blobs)
    truth = np.array([truth[k] for k in ks])

    def spread(centres):  # how far each offset from the truth lies from their median
        off = centres - truth
        return np.linalg.norm(off - np.median(off, 0), axis=1)

    assert np.median(spread(track.centres)) > 1.5  # the leaning centres
    aligned = align(track, energy, 0.5).centres
    assert np.median(spread(aligned)) < 0.5
    assert spread(aligned).max() < 1.0


def test_align_leaves_a_view_cut_by_the_border_where_its_whole_shape_put_it():
    # A textured object fires over its whole body, most towards its middle. Where the border
    # cuts it, its partial view correlates best with the template's middle, inwards of where
    # it is (5 px at 38% in view); border.uncut's centre from its whole shape is kept.
    shape, radius = (96, 128), 10.0
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    energy = [
        _ring_residual(shape, [], seed=k)
        + 0.6 * np.maximum(1.0 - np.hypot(xs - c[0], ys - c[1]) / radius, 0.0)
        for k, c in enumerate(LEAVING)
    ]
    (track,) = chain([regions(e, k, SEGMENT) for k, e in enumerate(energy)], TRACKS)
    assert _leaving_centred(track, align(track, energy, 0.5).centres, radius) >= 3


def test_turn_rate_recovers_the_spin_of_a_translating_textured_card():
    rng = np.random.default_rng(3)
    rate, velocity = 12.0, np.array([300.0, -100.0])  # rad/s, px/s
    texture = rng.uniform(-12, 12, size=(60, 2)) * np.array([1.0, 0.4])  # a card's marks
    centre = np.array([48.0, 40.0])
    dt = rng.uniform(-0.015, 0.015, size=(60, 40)).reshape(-1)
    marks = np.repeat(texture, 40, axis=0)
    ang = rate * dt
    rotated = np.stack(
        [np.cos(ang) * marks[:, 0] - np.sin(ang) * marks[:, 1],
         np.sin(ang) * marks[:, 0] + np.cos(ang) * marks[:, 1]], 1
    )  # fmt: skip
    xy = centre + rotated + velocity * dt[:, None] + rng.normal(0, 0.3, size=rotated.shape)
    ev = WindowEvents(xy, dt, np.where(rng.random(len(dt)) < 0.5, 1, -1))
    found, gain = turn_rate(ev, centre, velocity, 1.0 / 0.03, (96, 96))
    assert abs(found - rate) < 1.0
    assert gain > 0.1  # seeding uses a turn from 0.05
    still = WindowEvents(centre + marks + velocity * dt[:, None], dt, ev.p)
    found, _ = turn_rate(still, centre, velocity, 1.0 / 0.03, (96, 96))
    assert abs(found) < 1.0


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_warped_variance_is_the_whole_images_variance_of_the_bilinear_votes(dtype):
    # Oracle: each polarity's image of bilinear votes drawn over the whole sensor with numpy,
    # votes off the image dropped; events near and across its border, one batch wholly off it.
    rng = np.random.default_rng(5)
    h, w, e = 70, 90, 400
    x = torch.tensor(rng.uniform(-3.0, 20.0, size=(3, e)) + [[0.0], [70.0], [500.0]], dtype=dtype)
    y = torch.tensor(rng.uniform(-2.0, 12.0, size=(3, e)) + [[0.0], [58.0], [0.0]], dtype=dtype)
    p = np.where(rng.random(e) < 0.4, 1, -1)
    expected = []
    for xs, ys in zip(x.double().numpy(), y.double().numpy()):
        images = np.zeros((2, h, w))
        x0, y0 = np.floor(xs), np.floor(ys)
        for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            vote = (1 - abs(xs - x0 - dx)) * (1 - abs(ys - y0 - dy))
            xi, yi = (x0 + dx).astype(int), (y0 + dy).astype(int)
            on = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            np.add.at(images, ((p[on] > 0).astype(int), yi[on], xi[on]), vote[on])
        expected.append(images.var(ddof=1))
    got = warped_variance(x, y, p, (h, w))
    tol = 1e-12 if dtype == torch.float64 else 1e-6
    assert np.allclose(got, expected, rtol=tol, atol=0.0)
    assert got[2] == 0.0


def test_a_slow_turn_in_place_is_read_in_the_held_window_from_events_at_whole_pixels():
    # A textured disc held in place turning at -3 rad/s, a 0.6 s sequence: in a short (30 ms)
    # window its marks move at most 0.9 px. The sensor gives each event its pixel, so with no
    # motion every unwarped vote lands on one pixel and no turn looks the sharpest. An object
    # held in place (its centres still) is read in ``held_window`` windows, its events spread
    # within their pixels: the rate it was made with (the oracle).
    rng = np.random.default_rng(4)
    rate, centre = -3.0, np.array([48.0, 44.0])
    marks = rng.uniform(-11.0, 11.0, size=(400, 2))
    marks = np.repeat(marks[np.linalg.norm(marks, axis=1) < 11.0], 120, axis=0)
    t_us = rng.integers(0, 600_000, size=len(marks))
    order = np.argsort(t_us)  # the events in time order, each mark's spread over the sequence
    marks, t_us = marks[order], t_us[order]
    angle = rate * t_us * 1e-6
    turned = np.stack([np.cos(angle) * marks[:, 0] - np.sin(angle) * marks[:, 1],
                       np.sin(angle) * marks[:, 0] + np.cos(angle) * marks[:, 1]], 1)  # fmt: skip
    pixel = np.floor(centre + turned).astype(np.int64)
    p = np.where(rng.random(len(t_us)) < 0.5, 1, -1)

    def read(t0, t1, most):
        i0, i1 = np.searchsorted(t_us, [t0, t1])
        return SimpleNamespace(x=pixel[i0:i1, 0], y=pixel[i0:i1, 1], t=t_us[i0:i1], p=p[i0:i1])

    data = SimpleNamespace(t_start_us=0, t_end_us=600_000, events=SimpleNamespace(read=read))
    views = SimpleNamespace(data=data, allowed=lambda t0, t1: True, hot=None)
    windows = range(6, 43)  # 12.5 ms apart, clear of the sequence's ends
    track = Track({k: _disc_blob((96, 96), k * 12_500, centre, 13.0) for k in windows})
    held = seed.turn_rates(views, track, MoverConfig(held_window=0.2))
    assert seed.turned(held).all() and abs(np.median(held) - rate) < 0.3
    short = seed.turn_rates(views, track, MoverConfig(held_window=0.0))
    assert abs(np.nanmedian(short)) < 1.0  # read in short windows: no turn, or a weak one


def test_a_piece_going_round_a_held_object_gives_its_centre_and_turn():
    # A card held in place turning at 7.5 rad/s (3.7 rad over the track), seen only at one tip
    # 14 px from its centre (the other hidden): the tip's region wobbles by up to 1 px. The
    # circle its centres lie on gives the card's centre and rate (the oracle: what the track was
    # drawn from); the seeded shape adds the tip mirrored through that centre, its other end.
    rng = np.random.default_rng(2)
    windows = np.arange(40)
    t_us = 100_000 + windows * 12_500
    centre, rate = np.array([50.0, 40.0]), 7.5
    angle = 0.3 + rate * (t_us - t_us[0]) * 1e-6
    tips = centre + 14.0 * np.stack([np.cos(angle), np.sin(angle)], 1)
    tips += rng.uniform(-1.0, 1.0, tips.shape)
    found = circling(t_us, tips, 5.0, 4)
    assert found is not None
    assert np.linalg.norm(found[0] - centre) < 0.5 and abs(found[2] - rate) < 0.2
    assert np.allclose(found[1], angle - angle[0], atol=0.15)
    # An object crossing with a sway, one sitting still and too short a track: no circle.
    sway = np.stack([10.0 + 1.8 * windows, 40.0 + 3.0 * np.sin(windows / 6.0)], 1)
    assert circling(t_us, sway, 5.0, 4) is None
    assert circling(t_us, centre + rng.uniform(-1.0, 1.0, tips.shape), 5.0, 4) is None
    assert circling(t_us[:7], tips[:7], 5.0, 4) is None
    track = Track(
        {int(k): _disc_blob((96, 96), int(t), c, 4.0) for k, t, c in zip(windows, t_us, tips)}
    )
    mask = seed.shape(track, 0, np.tile(centre, (40, 1)), np.zeros(40), np.zeros(40))
    other = _disc((96, 96), 2.0 * centre - tips[0], 4.0)
    assert mask[track.blobs[0].mask].all() and mask[other].mean() > 0.9
    assert mask.sum() < 2.2 * track.blobs[0].mask.sum()


def test_a_sighting_that_jumps_off_and_straight_back_is_read_from_its_neighbours():
    # An object sliding 2 px per window (windows 0-19, one missed) and wobbling by up to half a
    # pixel; at window 8 its track took a region 28 px off (a piece of it, or of another).
    rng = np.random.default_rng(0)
    windows = np.array([k for k in range(20) if k != 12])
    truth = np.stack([10.0 + 2.0 * windows, 40.0 + 0.5 * windows], 1)
    seen = truth + rng.uniform(-0.5, 0.5, truth.shape)
    spiked = seen.copy()
    spiked[8] += [3.0, -28.0]
    whole = np.zeros(len(windows), dtype=bool)  # no region a piece of the object
    out = despiked(windows, spiked, 3, whole)
    assert np.linalg.norm(out[8] - truth[8]) < 1.0
    assert np.array_equal(np.delete(out, 8, 0), np.delete(spiked, 8, 0))  # the rest as seen
    # Motion, not a spike: a bounce (it turns back) and a jump to a new line are kept.
    bounce = np.stack([10.0 + 2.0 * np.minimum(windows, 20 - windows), 40.0 + 0 * windows], 1)
    assert np.array_equal(despiked(windows, bounce, 3, whole), bounce)
    moved = seen.copy()
    moved[8:] += [0.0, -28.0]
    assert np.array_equal(despiked(windows, moved, 3, whole), moved)
    # Three sightings off in a row (across the missed window) are put back too; four, longer
    # than ``longest``, are kept.
    thrice = seen.copy()
    thrice[9:12] += [0.0, -28.0]
    out = despiked(windows, thrice, 3, whole)
    assert np.abs(out[9:12] - truth[9:12]).max() < 1.5
    assert np.array_equal(np.delete(out, [9, 10, 11], 0), np.delete(thrice, [9, 10, 11], 0))
    four = seen.copy()
    four[8:12] += [0.0, -28.0]
    assert np.array_equal(despiked(windows, four, 3, whole), four)


def test_a_last_sighting_of_a_piece_that_jumps_off_is_held_at_the_one_before():
    # `pair`'s bar (about 400 px) sliding 2 px per window: its last region is a piece of it, 95
    # px, 14 px off. It is held at the sighting before; a whole region that jumps, or a piece
    # in line, is the object's and kept; likewise at the first sighting. A region cut by the
    # border is no piece here (``steadied`` reads those from the line).
    windows = np.arange(20)
    truth = np.stack([10.0 + 2.0 * windows, 40.0 + 0.5 * windows], 1)
    areas, cut = np.full(20, 400.0), np.zeros(20, dtype=bool)
    spiked, small = truth.copy(), areas.copy()
    spiked[-1] += [-5.0, -14.0]
    small[-1] = 95.0
    piece = partial(small, cut) & ~cut
    out = despiked(windows, spiked, 3, piece)
    assert np.array_equal(out[-1], truth[-2])
    assert np.array_equal(out[:-1], truth[:-1])
    assert np.array_equal(despiked(windows, spiked, 3, partial(areas, cut)), spiked)  # whole
    assert np.array_equal(despiked(windows, truth, 3, piece), truth)  # a piece in line
    cut[-1] = True
    assert np.array_equal(despiked(windows, spiked, 3, partial(small, cut) & ~cut), spiked)
    first, first_small = truth.copy(), areas.copy()
    first[:2] += [0.0, 12.0]
    first_small[:2] = 120.0
    out = despiked(windows, first, 3, partial(first_small, np.zeros(20, dtype=bool)))
    assert np.array_equal(out[:2], truth[[2, 2]])


def test_first_sightings_beside_the_objects_line_are_told_from_a_region_holding_it():
    # A disc (radius 6) sliding 2 px per window; its track's first regions lie 20 px off its
    # line (`approach` seed 2's box: regions beside it, then a jump onto it). A region that holds
    # the object with another (a large one about both) is its own, as is a run over ``longest``.
    shape, windows = (64, 96), np.arange(16)
    truth = np.stack([10.0 + 2.0 * windows, 30.0 + 0.0 * windows], 1)

    def sighted(off, radius=6.0):
        centres = truth + np.asarray(off)
        return centres, [_disc(shape, c, radius) for c in centres]

    off = np.zeros((16, 2))
    off[:2] = [20.0, 0.0]
    centres, masks = sighted(off)
    flags = beside_line(windows, centres, masks, 3, 4)
    assert flags.tolist() == [True, True] + [False] * 14
    last = off[::-1].copy()
    assert beside_line(windows, *sighted(last), 3, 4).tolist() == [False] * 14 + [True, True]
    # Joined with a neighbour: the region's centre is off, the object inside it.
    off[:2] = [10.0, 0.0]
    centres, _ = sighted(off)
    masks = [_disc(shape, c, 16.0) for c in centres]
    assert not beside_line(windows, centres, masks, 3, 4).any()
    off[:4] = [20.0, 0.0]  # four off: longer than ``longest``, a motion of its own
    assert not beside_line(windows, *sighted(off), 3, 4).any()
    assert not beside_line(windows, *sighted(np.zeros((16, 2))), 3, 4).any()  # on its line
    # Leaving through the right border, its last region cut to a sliver whose centre is read
    # off: the line puts it beyond the image, where no region can hold it, so it is not told.
    leaving = np.stack([60.0 + 2.5 * windows, 30.0 + 0.0 * windows], 1)
    masks = [_disc(shape, c, 6.0) for c in leaving]
    leaving[-1] += [12.0, 0.0]
    assert not beside_line(windows, leaving, masks, 3, 4).any()


def _bar(shape, centre, angle, length=30.0, width=6.0):
    """A filled bar's region: ``length`` x ``width`` px about ``centre``, its long side at
    ``angle`` (rad, x towards y)."""
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    u = (xs - centre[0]) * np.cos(angle) + (ys - centre[1]) * np.sin(angle)
    v = -(xs - centre[0]) * np.sin(angle) + (ys - centre[1]) * np.cos(angle)
    return (np.abs(u) <= length / 2) & (np.abs(v) <= width / 2)


def test_long_axis_is_a_bars_angle_and_a_disc_has_none():
    for angle in np.radians([-80.0, -30.0, 0.0, 20.0, 65.0, 90.0]):
        got, ratio = long_axis(_bar((96, 96), (48.0, 40.0), angle))
        assert abs(np.angle(np.exp(2j * (got - angle)))) / 2 < np.radians(1.5)
        assert ratio > 10.0
    assert long_axis(_disc((96, 96), (40.0, 50.0), 12.0))[1] < 1.1


def test_a_steady_turn_is_read_from_the_long_axes_of_an_elongated_objects_regions():
    # A bar sliding across the image while it turns, 40 windows 12 ms apart (the tiny preset's
    # spacing), each region's edge ragged by a pixel: its rate is read within 5% at 1.5 rad/s
    # (`pair`'s bar: 40 degrees over the track) and at 8 rad/s (over 200 degrees: the axes
    # wrap past a half turn). A disc, a bar that does not turn, one that turns only in the
    # second half of its windows, and a round object's moving edge (a crescent across its
    # motion) show no steady turn.
    rng = np.random.default_rng(0)
    times = np.arange(40) * 12_000
    centres = np.stack([20.0 + 1.4 * np.arange(40), 30.0 + 0.6 * np.arange(40)], 1)

    def ragged(mask):
        edge = mask ^ ndimage.binary_erosion(mask)
        return mask ^ (edge & (rng.random(mask.shape) < 0.3))

    def bars(angles):
        return [ragged(_bar((96, 96), c, a)) for c, a in zip(centres, angles)]

    t = times * 1e-6
    for rate in (1.5, -1.5, 8.0):
        got = axis_rate(times, bars(0.4 + rate * t), 3, 40.0)
        assert got is not None and abs(got - rate) < 0.05 * abs(rate)
    assert axis_rate(times, bars(np.full(40, 0.4)), 3, 40.0) is None
    # A tumbling object's silhouette, its axis every which way: some rate lines up a few of
    # them, and about it the halves' test alone passed all of 20 draws.
    for _ in range(5):
        assert axis_rate(times, bars(rng.uniform(-np.pi / 2, np.pi / 2, 40)), 3, 40.0) is None
    assert axis_rate(times, bars(0.4 + 3.0 * np.maximum(t - t[20], 0.0)), 3, 40.0) is None
    discs = [ragged(_disc((96, 96), c, 10.0)) for c in centres]
    assert axis_rate(times, discs, 3, 40.0) is None
    edges = [_disc((96, 96), c, 10.0) & ~_disc((96, 96), c - [3.0, 1.3], 10.0) for c in centres]
    assert axis_rate(times, [ragged(m) for m in edges], 3, 40.0) is None


def test_turn_angles_integrate_the_rates():
    times = np.array([0, 100_000, 200_000])
    angles = turn_angles(
        times, np.array([2.0, 2.0, 4.0]), np.array([0, 100_000, 200_000, 300_000]), 100_000
    )
    # 2 rad/s for 0.1 s before the reference; 3 rad/s on average after; held at 4 beyond.
    assert np.allclose(angles, [-0.2, 0.0, 0.3, 0.7])


def test_two_ends_finds_the_centre_of_a_card_whose_track_hops_between_its_tips():
    # A card turning 0.1 rad per window about a centre drifting 0.5 px per window; its region
    # is the tip at +d (body frame) except in windows 12-25, where it is the other tip.
    windows = np.delete(np.arange(40), [27])  # one window unseen
    angles = 0.1 * windows
    centre = np.stack([30.0 + 0.5 * windows, 40.0 + 0.2 * windows], 1)
    d = np.array([14.0, 3.0])
    end = np.where((windows >= 12) & (windows <= 25), -1.0, 1.0)
    seen = centre + end[:, None] * (turns(angles) @ d)
    clear = np.zeros(len(windows), dtype=bool)  # no region cut by the image border
    middle, found, turned = two_ends(windows, seen, angles, radius=8.0, coast=3, cut=clear)
    assert np.array_equal(found, end)
    # d is fitted to the hops as if the centre stood still over each: off by its drift there.
    assert np.linalg.norm(middle - centre, axis=1).max() < np.hypot(0.5, 0.2)
    assert np.abs(turned - angles).max() < 0.02  # the hops read the measured turn
    # A measured turn that drifts (its rate 20% slow from window 10 on) is read again at the
    # hops and its drift taken out between them (linear there): up to a constant, the angles
    # then hold within the hops' reading error (the centre's own drift over a hop).
    slow = angles - 0.02 * np.maximum(windows - 10, 0)
    middle, found, turned = two_ends(windows, seen, slow, radius=8.0, coast=3, cut=clear)
    between = (windows >= 12) & (windows <= 25)
    assert np.array_equal(found, end)
    assert np.ptp((turned - angles)[between]) < 0.04 < 0.25 < np.ptp((slow - angles)[between])
    assert np.linalg.norm(middle - centre, axis=1)[between].max() < 0.6
    # The same tips without hops, a single hop (two unknowns fit any one step) and tips that
    # would overlap (|d| under the region's radius) are left as they are.
    for track, radius in (
        (centre + turns(angles) @ d, 8.0),
        (centre + np.where(windows < 12, 1.0, -1.0)[:, None] * (turns(angles) @ d), 8.0),
        (seen, 20.0),
    ):
        kept, ends, turned = two_ends(windows, track, angles, radius, coast=3, cut=clear)
        assert np.array_equal(kept, track) and (ends == 1).all()
        assert np.array_equal(turned, angles)
    # A ball bouncing off a wall (its path turns sharply, no tip to hop to) is left alone.
    bounce = np.stack([np.abs(windows - 20.0) * 4.0, 2.0 * windows], 1)
    kept, ends, _ = two_ends(windows, bounce, angles, 8.0, coast=3, cut=clear)
    assert np.array_equal(kept, bounce) and (ends == 1).all()
    # The same hops between regions cut by the image border (an object gone out, its track
    # taking the border's noise there) are no ends: a cut region's centre is the least sure.
    at_border = (windows >= 10) & (windows <= 27)
    kept, ends, _ = two_ends(windows, seen, angles, radius=8.0, coast=3, cut=at_border)
    assert np.array_equal(kept, seen) and (ends == 1).all()


def _tip_track(centre, d, windows, end, drift=(0.3, 0.1), radius=5.0):
    """A track whose region in each of ``windows`` is the disc at ``centre`` + ``end`` d,
    the centre moving by ``drift`` px per window."""
    blobs = {}
    for k, e in zip(windows, end):
        c = centre + e * d + k * np.array(drift)
        blobs[int(k)] = _disc_blob((96, 96), int(k) * 20_000, c, radius, contrast=12.0)
    return Track(blobs)


def test_a_card_broken_into_tracks_at_its_hops_is_one_object_and_its_other_end_no_other():
    # A card that does not turn (no turn measured) fires at its tips (+d, -d) by turns, and the
    # chaining broke it at a hop: windows 0-19 (a hop at 10), 18-39 (a hop at 30, and windows
    # 18-19 shared with the first); windows 32-36 also show the other tip, a track of its own.
    centre, d = np.array([40.0, 45.0]), np.array([14.0, 3.0])
    mc = MoverConfig(turn=False, coast=3, together=1.5, min_windows=4)
    first = _tip_track(centre, d, range(20), np.where(np.arange(20) < 10, 1.0, -1.0))
    later = np.arange(18, 40)
    second = _tip_track(centre, d, later, np.where(later < 30, -1.0, 1.0))
    other = _tip_track(centre, d, range(32, 37), -np.ones(5))
    alone = _tip_track(np.array([20.0, 80.0]), np.zeros(2), range(0, 40, 2), np.ones(20), (1, 0))
    found = joined_ends([first, second, other, alone], views=None, mc=mc)
    assert [id(t) for t, _ in found] == [id(first), id(alone)]
    assert sorted(first.blobs) == list(range(40))
    _, middle, end, _ = found[0][1]
    assert (end[10:30] == -1).all() and (end[:10] == 1).all() and (end[30:] == 1).all()
    drift = np.stack([0.3 * np.arange(40), 0.1 * np.arange(40)], 1)
    assert np.linalg.norm(middle - centre - drift, axis=1).max() < 0.5
    # Its tips lie |d| from its centre: the seeding sizes the card by that, not by a tip's region.
    assert abs(ends_offset(first, middle) - np.linalg.norm(d)) < 0.5
    # Without its hops the lone object is one end, where it was seen, and no larger.
    assert (found[1][1][2] == 1).all()
    assert ends_offset(alone, found[1][1][1]) == 0.0


def test_a_cards_tail_in_its_middle_after_its_arm_stops_firing_is_dropped():
    # A card's tips (+d, -d) by turns, hops at 10 and 30 (windows 0-37); then its track, unseen,
    # took two small regions of the card's middle (windows 39 and 41): a third "hop" that no
    # two ends explain. Without that tail the track is the card's two ends, and the object
    # ends at window 37 (held after it, as any object after its last sighting).
    centre, d = np.array([40.0, 45.0]), np.array([14.0, 3.0])
    mc = MoverConfig(turn=False, coast=3, together=1.5, min_windows=4)
    ks = np.arange(38)
    card = _tip_track(centre, d, ks, np.where((ks >= 10) & (ks < 30), -1.0, 1.0))
    card.blobs |= _tip_track(centre, d, [39, 41], np.zeros(2), radius=2.5).blobs
    ((track, (_, middle, end, _)),) = joined_ends([card], views=None, mc=mc)
    assert sorted(track.blobs) == list(range(38))
    assert (end[10:30] == -1).all() and (end[:10] == 1).all() and (end[30:] == 1).all()
    drift = np.stack([0.3 * ks, 0.1 * ks], 1)
    assert np.linalg.norm(middle - centre - drift, axis=1).max() < 0.5
    # A tail longer than a track coasts unseen is the object's own: the track is left whole.
    long = _tip_track(centre, d, ks, np.where((ks >= 10) & (ks < 30), -1.0, 1.0))
    long.blobs |= _tip_track(centre, d, range(39, 47, 2), np.zeros(4), radius=2.5).blobs
    ((track, (_, _, end, _)),) = joined_ends([long], views=None, mc=mc)
    assert len(track.blobs) == 42 and (end == 1).all()


def test_a_step_shorter_than_the_objects_radius_is_no_hop_between_its_ends():
    # A region moving 2.5 px per window with one step of 6.5 px: over twice the median step,
    # but ends at least a radius (9.9 px) from the centre lie two radii apart.
    windows = np.arange(12)
    centres = np.stack([2.5 * windows, np.zeros(12)], 1)
    centres[6:, 0] += 4.0
    clear = np.zeros(12, dtype=bool)
    hop, limit = hops(windows, centres, radius=9.9, coast=3, cut=clear)
    assert limit == 5.0 and not hop.any()
    centres[9:, 0] += 25.0  # a hop to the other end, and one over a gap longer than coast + 1
    assert np.flatnonzero(hops(windows, centres, 9.9, 3, clear)[0]).tolist() == [8]
    assert not hops(np.r_[windows[:9], windows[9:] + 5], centres, 9.9, 3, clear)[0].any()


def test_an_objects_cut_sightings_as_it_comes_in_and_goes_out_are_read_from_its_line():
    # An object crossing at 3 px per window along a line; its first three and last two
    # sightings are cut by the border, their region centres off by up to 8 px (slivers) and
    # their areas a tenth to a half of its whole one.
    rng = np.random.default_rng(0)
    times = np.arange(14) * 12_500
    truth = np.stack([3.0 * np.arange(14) - 6.0, 40.0 + 0.5 * np.arange(14)], 1)
    cut = np.zeros(14, bool)
    cut[[0, 1, 2, 12, 13]] = True
    seen = truth + rng.normal(0.0, 0.3, truth.shape)
    seen[cut] += np.array([[2.0, 8.0], [-3.0, -6.0], [1.0, 4.0], [0.0, -5.0], [4.0, 3.0]])
    areas = np.where(cut, [40.0, 90.0, 180.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 150.0, 60.0], 400.0)
    out = steadied(times, seen, areas, cut, n=4)
    assert np.abs(out[cut] - truth[cut]).max() < 1.5  # from 8 px off
    assert np.array_equal(out[~cut], seen[~cut])  # its clear sightings as they were
    # Too few clear sightings beside a run to fit through, or a run longer than they span:
    # the run is left as it was.
    short = steadied(times[:6], seen[:6], areas[:6], cut[:6], n=4)
    assert np.array_equal(short, seen[:6])
    long = steadied(times, seen, areas, cut, n=2)
    assert np.array_equal(long[:3], seen[:3]) and np.abs(long[12:] - truth[12:]).max() < 2.5


def test_a_card_track_resumed_on_its_other_tip_is_still_joined_at_its_hop():
    # As above, but the chaining resumed the first track after a gap (``tracks._resumes``) on
    # the other tip firing at once (windows 32-36): up to the gap it is the card's, joined at
    # the hop with the second track; its resumed windows are the other end, no object.
    centre, d = np.array([40.0, 45.0]), np.array([14.0, 3.0])
    mc = MoverConfig(turn=False, coast=3, together=1.5, min_windows=4)
    first = _tip_track(centre, d, range(20), np.where(np.arange(20) < 10, 1.0, -1.0))
    first.blobs |= _tip_track(centre, d, range(32, 37), -np.ones(5)).blobs
    later = np.arange(18, 40)
    second = _tip_track(centre, d, later, np.where(later < 30, -1.0, 1.0))
    ((track, (_, middle, end, _)),) = joined_ends([first, second], views=None, mc=mc)
    assert track is first and sorted(first.blobs) == list(range(40))
    assert (end[10:30] == -1).all() and (end[:10] == 1).all() and (end[30:] == 1).all()
    drift = np.stack([0.3 * np.arange(40), 0.1 * np.arange(40)], 1)
    assert np.linalg.norm(middle - centre - drift, axis=1).max() < 0.5


def test_an_object_is_placed_at_its_clearest_region_of_its_own():
    # A disc's track whose clearest region (window 5) is shared with another object passing
    # (``Track.shared``: that region holds both): it is placed at its clearest own region,
    # clear of the border; with every region shared, at the clearest of all.
    blobs = {k: _disc_blob((64, 64), k * 1000, (20.0 + k, 30.0), 6.0, 10.0 + k) for k in range(8)}
    blobs[7] = _disc_blob((64, 64), 7000, (3.0, 30.0), 6.0, 30.0)  # cut by the border
    track = Track(blobs, shared={5, 6})
    assert reference(track) == 4
    assert reference(Track(blobs, shared=set(range(8)))) == 6


def test_a_balls_rim_read_as_two_ends_about_its_centre_is_a_piece_of_the_ball():
    # A ball (20 px radius) seen whole in windows 0-29; a small region on its rim, now on one
    # side, now on the other (hops at 8 and 16), reads as a two-ended object whose centre is
    # the ball's. It explains less of the events than the ball: it is the piece, not the ball.
    centre, d = np.array([40.0, 45.0]), np.array([17.0, 4.0])
    mc = MoverConfig(turn=False, coast=3, together=1.5, min_windows=4)
    ball = _tip_track(centre, np.zeros(2), range(30), np.ones(30), radius=20.0)
    later = np.arange(4, 26)
    rim = _tip_track(centre, d, later, np.where((later >= 8) & (later < 16), -1.0, 1.0))
    assert (joined_ends([rim], views=None, mc=mc)[0][1][2] < 0).any()  # alone: two ends
    found = joined_ends([ball, rim], views=None, mc=mc)
    assert [id(t) for t, _ in found] == [id(ball)]
    assert (found[0][1][2] == 1).all()


def test_joined_objects_keep_their_refined_paths_and_priors():
    first = ObjectMotion(
        torch.zeros(1, 3), torch.ones(1), torch.zeros(1, 3, 3), torch.zeros(1, 3, 3)
    )
    with torch.no_grad():
        first.translations += 1.0  # refined since its start
    later = ObjectMotion(
        torch.ones(1, 3), 2 * torch.ones(1), torch.full((1, 3, 3), 5.0), torch.zeros(1, 3, 3)
    )
    both = first.joined(later)
    means = torch.zeros(2, 3)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2)
    moved, _ = both.apply(means, quats, torch.tensor([0, 1]), 0.5)
    assert torch.allclose(moved, torch.tensor([[1.0, 1.0, 1.0], [5.0, 5.0, 5.0]]))
    # Each keeps its own prior: the first object's refinement costs (sqrt(3) radii per knot,
    # beyond FREE, squared, three knots), the second's start not; averaged over the two objects.
    beyond = math.sqrt(3.0) - FREE
    assert torch.allclose(both.prior_loss(), torch.tensor(3 * beyond**2 / 2))
    # A single knot off costs what it would alone, not diluted by the knots that are not.
    with torch.no_grad():
        both.translations.copy_(both.prior_translations)
        both.translations[1, 0, 0] += 2.0 * 3.0  # knot 0 of the second, three of its radii
    assert torch.allclose(both.prior_loss(), torch.tensor((3.0 - FREE) ** 2 / 2))
    # Within FREE of its seeded place a knot is free, its gradient finite (0 there too).
    with torch.no_grad():
        both.translations.copy_(both.prior_translations)
        both.translations[1, 2, 1] += 2.0 * 0.9 * FREE
    both.translations.grad = None
    loss = both.prior_loss()
    loss.backward()
    assert float(loss.detach()) == 0.0
    assert torch.isfinite(both.translations.grad).all() and not both.translations.grad.any()
    # A turn off at one knot is averaged over the knots (0.3 rad at one of three).
    with torch.no_grad():
        both.translations.copy_(both.prior_translations)
        both.rotvecs[0, 1, 2] += 0.3
    assert torch.allclose(both.prior_loss(), torch.tensor(0.09 / 3 / 2))


@pytest.mark.parametrize("batch", [16_384, 3])  # rows tested at once (all, or in batches)
def test_the_space_an_object_passes_through_or_hides_holds_only_the_scenes_gaussians_in_it(
    batch, monkeypatch
):
    monkeypatch.setattr("evsplat.model.motion.SWEPT_ROWS", batch)
    # One object of radius 0.3 centred at the origin, sliding along x by 2 m over knots at
    # t = 0, 0.25, ..., 1 and in view over [0.25, 0.75] only: its path in view runs from
    # x = 0.5 to x = 1.5, seen from a camera 4 m in front of it (z = -4), so the space it
    # hides runs BEHIND radii (0.6 m) behind it, to z = 0.6 (as under a still camera), and the
    # space that would hide it is the cone from the camera to its disc. A second object, always
    # in view, stays at (0, 5, 0).
    slide = torch.zeros(2, 5, 3)
    slide[0, :, 0] = torch.linspace(0.0, 2.0, 5)
    paths = (
        torch.tensor([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0]]),
        torch.tensor([0.3, 0.3]),
        slide,
        torch.zeros(2, 5, 3),
        torch.tensor([[0.25, 0.75], [-float("inf"), float("inf")]]),
    )
    motion = ObjectMotion(*paths, behind=BEHIND)
    eyes = slide[0] + torch.tensor([0.0, 0.0, -4.0])  # the camera follows it: rays along z
    reach = BEHIND * 0.3
    means = torch.tensor(
        [
            [1.0, 0.29, 0.0],  # beside the middle of the path, inside its radius
            [1.0, 0.31, 0.0],  # just beyond it
            [1.0, 0.0, -0.31],  # in front of it, where it would hide it
            [1.0, 0.25, -2.0],  # halfway to the camera: within its radius, beyond its cone's
            [1.0, 0.05, -3.0],  # a quarter of the way from the camera, within its cone's
            [1.0, 0.2, reach + 0.05],  # behind it, within a radius of the end of its ray
            [1.0, 0.0, reach + 0.31],  # beyond the end of its ray
            [0.3, 0.0, 0.0],  # 0.2 before where it comes into view: inside the radius
            [0.1, 0.0, 0.0],  # on its path, but where it was out of view
            [1.9, 0.0, 0.0],  # likewise after it went out
            [0.0, 5.2, 0.0],  # inside the still object's ball
            [1.0, 0.0, 0.0],  # on the path, but one of the object's own Gaussians
        ]
    )
    object_id = torch.tensor([-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0])
    swept = motion.swept(means, object_id, eyes)
    want = [True, False, True, False, True, True, False, True, False, False, True, False]
    assert swept.tolist() == want
    # Nothing behind it (as under a moving camera): the point behind it is the scene's.
    want[5] = False
    assert ObjectMotion(*paths).swept(means, object_id, eyes).tolist() == want
    # A checkpoint written before the reach was kept swept BEHIND radii behind.
    old = {k: v for k, v in ObjectMotion(*paths).state().items() if k != "behind"}
    assert ObjectMotion.from_state(old).swept(means, object_id, eyes).tolist() == swept.tolist()


def test_an_object_is_visible_only_inside_its_span():
    motion = ObjectMotion(
        torch.zeros(2, 3),
        torch.ones(2),
        torch.zeros(2, 3, 3),
        torch.zeros(2, 3, 3),
        torch.tensor([[0.4, 0.6], [-float("inf"), float("inf")]]),
        fade=0.02,
    )
    ids = torch.tensor([-1, 0, 1])
    assert torch.allclose(motion.visibility(ids, 0.5), torch.ones(3), atol=1e-6)
    early = motion.visibility(ids, 0.1)
    assert early[0] == 1 and early[1] < 1e-6 and early[2] == 1
    assert abs(float(motion.visibility(ids, 0.4)[1]) - 0.5) < 1e-6  # half faded at the edge


def test_an_object_is_hidden_only_beyond_where_it_came_in_or_went_out_through_the_border():
    h, w, inf = 40, 48, float("inf")
    times = np.linspace(0.0, 1.0, 20)  # the windows' normalised times
    half = 0.5 / 19  # half a window spacing

    def track(first, last, cut_ends=True):  # a disc on row 20, at the borders at its ends
        xs = {k: 24.0 for k in range(first, last + 1)}
        if cut_ends:
            xs |= {first: 2.0, last: 46.0}
        return Track(
            {
                k: Blob(k, np.array([x, 20.0]), _disc((h, w), (x, 20.0), 5), 78.0, 20.0)
                for k, x in xs.items()
            }
        )

    assert span(track(6, 13), times, coast=3) == pytest.approx([times[6] - half, times[13] + half])
    # Clear of the border at its ends: it was there all along, still.
    assert span(track(6, 13, cut_ends=False), times, coast=3) == [-inf, inf]
    # Within ``coast`` windows of the sequence's ends it may have been in view, unseen.
    assert span(track(3, 16), times, coast=3) == [-inf, inf]
    assert span(track(4, 15), times, coast=3) == pytest.approx([times[4] - half, times[15] + half])


def test_an_object_that_came_in_and_went_out_is_drawn_sliding_while_partly_in_view():
    # A still camera (f = 128 px, 96 x 96 px) sees an object 0.1 m in radius (6.4 px) 2 m away
    # slide along x at 2 m/s: its centre at u = -16 + 128 t px. Its sightings, 0.3-0.7 s, are
    # where it was whole; its disc overlaps the image for -6.4 < u < 102.4, 0.075 < t < 0.925 s:
    # it is drawn from the knot before (0.07 s) to the knot after (0.93 s), faded outside them.
    sighted = np.linspace(300_000, 700_000, 5)
    path = np.stack([-1.0 + 2.0 * sighted * 1e-6, np.zeros(5), np.full(5, 2.0)], 1)
    knots = np.linspace(0, 1_000_000, 101)
    truth = np.stack([-1.0 + 2.0 * knots * 1e-6, np.zeros(101), np.full(101, 2.0)], 1)
    inf, still = float("inf"), _camera_sliding(0.0)
    held = slid(path, sighted, knots, [inf, inf], 4, still)
    assert np.allclose(held, truth, atol=1e-9)  # carried on at its velocity both ways
    stays = slid(path, sighted, knots, [0.0, inf], 4, still)
    assert np.allclose(stays[knots < 300_000], path[0]) and np.allclose(stays[-1], truth[-1])
    # Carried on for at most 0.1 s (as long as a track may go unseen), then held.
    brief = slid(path, sighted, knots, [100_000.0, 100_000.0], 4, still)
    early, late = knots <= 200_000, knots >= 800_000
    assert np.allclose(brief[early], truth[knots == 200_000]) and np.allclose(
        brief[late], truth[knots == 800_000]
    )
    assert np.allclose(brief[~early & ~late], truth[~early & ~late], atol=1e-9)
    views = _still_camera(128.0)
    assert in_view(held, knots, [0.28, 0.72], 0.1, views) == pytest.approx([0.07, 0.93])
    assert in_view(held, knots, [-inf, 0.72], 0.1, views) == pytest.approx([-inf, 0.93])
    # Held at its first sighting, in view: unseen there so long, it was not there yet.
    assert in_view(stays, knots, [0.28, 0.72], 0.1, views) == pytest.approx([0.28, 0.93])


def test_an_object_unseen_inside_the_image_is_held_where_the_camera_saw_it():
    # Seen 0-0.2 s sliding along x at 0.5 m/s, 2 m away, while the camera slides at 1 m/s;
    # lost inside the image after. For 0.06 s (as long as a track may go unseen) it is carried
    # on at its velocity, then it keeps the pixel it had then: unseen, it fired no events, so it
    # moved little in the image (the camera followed it), though the camera slides on 0.34 m.
    K = np.array([[100.0, 0, 48], [0, 100.0, 48], [0, 0, 1]])
    sighted = np.linspace(0, 200_000, 11)
    path = np.stack([0.5 * sighted * 1e-6, np.zeros(11), np.full(11, 2.0)], 1)
    knots = np.linspace(0, 600_000, 61)
    panning = _camera_sliding(1.0)
    held = slid(path, sighted, knots, [float("inf"), 60_000.0], 4, panning)
    carried = (knots > 200_000) & (knots <= 260_000)
    assert np.allclose(held[carried, 0], 0.5 * knots[carried] * 1e-6, atol=1e-9)
    then = project(np.array([[0.13, 0.0, 2.0]]), panning(260_000.0), K)[0]
    past = knots > 260_000
    seen = np.concatenate(
        [project(p[None], panning(t), K)[0] for p, t in zip(held[past], knots[past])]
    )
    assert np.allclose(seen, then, atol=1e-9)
    # Under a still camera it is held where it was in the world.
    still = slid(path, sighted, knots, [float("inf"), 60_000.0], 4, _camera_sliding(0.0))
    assert np.allclose(still[past], [0.13, 0.0, 2.0], atol=1e-9)


def test_back_project_inverts_the_projection():
    K = np.array([[100.0, 0, 48], [0, 100.0, 40], [0, 0, 1]])
    c2w = np.eye(4)
    c2w[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    c2w[:3, 3] = [0.5, -0.2, 1.0]
    uv = np.array([[10.0, 20.0], [60.0, 70.0]])
    world = back_project(uv, np.array([2.0, 3.0]), c2w, K)
    cam = (world - c2w[:3, 3]) @ c2w[:3, :3]
    assert np.allclose(cam[:, 2], [2.0, 3.0])
    assert np.allclose((K @ (cam / cam[:, 2:]).T).T[:, :2], uv)
    # project, the numpy projection, against the rasterizer's (torch) one and back.
    uv_np, z = project(world, c2w, K)
    uv_torch = project_points(
        torch.from_numpy(world), torch.from_numpy(world_to_camera(c2w)), torch.from_numpy(K)
    )
    assert np.allclose(uv_np, uv) and np.allclose(uv_torch.numpy(), uv) and np.allclose(z, [2, 3])


def test_the_smear_is_what_the_objects_regions_hold_in_front_of_its_back():
    # Oracle: points put on known pixels at known depths by back-projection, two windows seen
    # from two camera positions; held are those in either window's region, nearer than the back.
    K = np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]])
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = 0.5  # the camera moved right: a static point moves left in the image
    track = Track(
        {
            k: Blob(k, np.array([x, 32.0]), _disc((64, 64), (x, 32), 6), 113.0, 20.0)
            for k, x in ((0, 20.0), (1, 44.0))
        }
    )
    pixels = np.array([[20.5, 32.5], [20.5, 32.5], [44.5, 32.5], [32.5, 10.5], [20.5, 32.5]])
    depths = np.array([2.0, 3.5, 2.0, 2.0, 2.9])  # the back is at 3
    pose = np.array([0, 0, 1, 0, 0])  # the window whose pose each point is placed from
    points = np.concatenate(
        [
            back_project(px[None], np.array([d]), poses[p], K)
            for px, d, p in zip(pixels, depths, pose)
        ]
    )
    assert smear(points, track, poses, K, back=3.0).tolist() == [True, False, True, False, True]
    # Seen from the other window, the first point lies outside that window's region.
    assert not smear(points[:1], Track({1: track.blobs[1]}), poses[1:], K, back=3.0)[0]


def test_a_cut_regions_whole_pixel_search_matches_pixel_by_pixel_overlaps():
    # Oracle: every shift's intersection over union counted pixel by pixel (``border._best``).
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:48, :64]
    for _ in range(40):
        r, cx, cy = rng.uniform(3, 10), rng.uniform(-5, 69), rng.uniform(-5, 53)
        centre = np.array([rng.uniform(r, 64 - r), rng.uniform(r, 48 - r)])
        whole = (xx + 0.5 - centre[0]) ** 2 / 1.5 + (yy + 0.5 - centre[1]) ** 2 < r * r
        cut = (xx + 0.5 - cx) ** 2 / 1.5 + (yy + 0.5 - cy) ** 2 < r * r
        if not cut.any():
            continue
        shape = Blob(0, centre + rng.uniform(-0.5, 0.5, 2), whole, float(whole.sum()), 1.0)
        seen = Blob(0, np.array([cx, cy]) + rng.uniform(-2, 2, 2), cut, float(cut.sum()), 1.0)
        ys, xs = np.nonzero(whole)
        offsets = np.stack([xs + 0.5, ys + 0.5], 1) - shape.centre[None]
        reach = int(np.ceil(2.0 * shape.radius))
        steps = np.arange(-reach, reach + 1, dtype=np.float64)
        want = border._best(offsets, seen, seen.centre, steps)
        np.testing.assert_allclose(border._coarse(shape, seen, reach), want)


def test_a_turn_seen_in_a_few_windows_is_not_held_across_those_that_show_none(monkeypatch):
    # A bar whose windows mostly show no turn (its events sharpen by under turn_min_gain) and
    # 4.5 rad/s in three (where the border cuts it, `pair`): the turn is integrated with no
    # turn between, not 4.5 rad/s held over the whole track. Where the middle windows hold no
    # events, nothing is known there and the rate is carried.
    windows = np.arange(20)
    track = _tip_track(np.array([20.0, 40.0]), np.zeros(2), windows, np.ones(20), (1, 0))
    views = SimpleNamespace(data=SimpleNamespace(t_start_us=0, t_end_us=400_000))
    clear = {0, 20_000, 380_000}  # the windows whose events a turn sharpens
    now = []

    def carried(views, t_us, half_us, velocity, spread=False):  # 60 events on the region's centre
        now.append(t_us)
        xy = np.tile(track.blobs[t_us // 20_000].centre, (60, 1))
        return (xy, np.zeros(60), np.ones(60), xy) if events or t_us in clear else None

    def turn_rate(window, centre, velocity, top, shape):
        return (4.5, 1.0) if now[-1] in clear else (0.4, 0.01)

    monkeypatch.setattr(seed, "turn_rate", turn_rate)
    monkeypatch.setattr(seed, "carried", carried)
    spacing_s = 20_000 * 1e-6
    events = True
    assert abs(seed.turning(views, track, MoverConfig())[3][-1]) <= 4.5 * 3 * spacing_s
    events = False
    assert np.isclose(seed.turning(views, track, MoverConfig())[3][-1], 4.5 * 19 * spacing_s)


def test_an_elongated_objects_turn_that_its_events_do_not_sharpen_is_read_from_its_shape(
    monkeypatch,
):
    # `pair`'s bar turns 1.5 rad/s, 2.6 degrees in a turn window: its events are sharpened by
    # a turn in 5 windows of 39. Its regions' long axes turn with it, and ``turning`` reads the
    # turn from them (``mover.turn_axes``), not from the few windows' rates.
    windows = np.arange(30)
    centres = np.stack([20.0 + 1.5 * windows, 30.0 + 0.5 * windows], 1)
    angles = 0.4 + 1.5 * windows * 0.02
    track = Track(
        {
            int(k): Blob(int(k) * 20_000, c, m, float(m.sum()), 12.0)
            for k, c, m in zip(
                windows, centres, (_bar((96, 96), c, a) for c, a in zip(centres, angles))
            )
        }
    )
    views = SimpleNamespace(data=SimpleNamespace(t_start_us=0, t_end_us=600_000))

    def carried(views, t_us, half_us, velocity, spread=False):
        xy = np.tile(centres[t_us // 20_000], (60, 1))
        return xy, np.zeros(60), np.ones(60), xy

    monkeypatch.setattr(seed, "turn_rate", lambda *args: (0.4, 0.01))  # sharpens none
    monkeypatch.setattr(seed, "carried", carried)
    rates, _, _, seen = seed.turning(views, track, MoverConfig(turn_axes=True))
    assert np.allclose(rates, 1.5, rtol=0.03)
    assert np.abs(seen - (angles - angles[0])).max() < np.radians(2.0)
    assert not seed.turning(views, track, MoverConfig(turn_axes=False))[3].any()


def test_turn_rates_of_no_turn_pass_as_one_near_the_tests_level_and_a_steady_turn_always():
    # Over many windows the median's standard error is the normal one and rates scattered about
    # zero pass in about STEADY_P of draws (4000 draws: a binomial sigma of 0.35%); a steady
    # 8 rad/s turn seen with 1 rad/s of scatter passes always, with a few wild rates too (a
    # test on the mean would not pass it: its spread grows with them).
    rng = np.random.default_rng(0)
    noise = np.mean([steady(rng.normal(0.0, 5.0, 40), 3) for _ in range(4000)])
    assert abs(noise - STEADY_P) < 0.015
    for n in (3, 6, 20):
        assert all(steady(rng.normal(8.0, 1.0, n), 3) for _ in range(200))
    assert steady(np.array([3.6, 3.9, 3.2, 4.1, 3.5, -17.0, 30.0, 3.8]), 3)
    assert steady(np.full(3, 4.5), 3)  # no spread: the turn seen
    assert not steady(np.array([8.0, 8.5]), 3)  # fewer than the least windows


def test_a_turn_whose_windows_disagree_in_sign_is_no_turn(monkeypatch):
    # `approach` seed 1's box (it turns about the vertical only): six windows sharpened by
    # in-plane turns of +24, -11, +5, -6, -7 and -12 rad/s; the others by none.
    windows = np.arange(12)
    track = _tip_track(np.array([20.0, 40.0]), np.zeros(2), windows, np.ones(12), (1, 0))
    views = SimpleNamespace(data=SimpleNamespace(t_start_us=0, t_end_us=240_000))
    shown = dict(zip([20_000, 60_000, 100_000, 140_000, 180_000, 220_000],
                     [24.3, -10.8, 4.7, -5.7, -7.4, -11.8]))  # fmt: skip
    now = []

    def carried(views, t_us, half_us, velocity, spread=False):
        now.append(t_us)
        xy = np.tile(track.blobs[t_us // 20_000].centre, (60, 1))
        return xy, np.zeros(60), np.ones(60), xy

    def turn_rate(window, centre, velocity, top, shape):
        return (shown[now[-1]], 1.0) if now[-1] in shown else (0.4, 0.01)

    monkeypatch.setattr(seed, "turn_rate", turn_rate)
    monkeypatch.setattr(seed, "carried", carried)
    rates = seed.turn_rates(views, track, MoverConfig())
    assert np.array_equal(rates, np.zeros(12))
