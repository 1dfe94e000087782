"""The moving objects as a run hands them out (`evsplat export --tracks`, `evsplat render
--objects`), against closed forms: two discs of Gaussians facing a pinhole camera, one sliding
and turning on a known path, the other still and seen only in the sequence's first half. Each
object's pose is its path's (position, quaternion, pixel, depth), and its labelled pixels are its
disc's, the nearer one owning where they overlap."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evsplat.cli import main
from evsplat.config import preset
from evsplat.data.images import read_png
from evsplat.data.trajectory import Trajectory
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel
from evsplat.model.motion import ObjectMotion
from evsplat.object_output import TRACK_COLUMNS, object_labels, object_poses
from evsplat.render import Renderer
from evsplat.run_state import Camera, Poses, RunState
from evsplat.video import read_mp4_frame

W, H, F = 64, 48, 100.0  # image size (px) and focal length (px); the principal point central
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])
T_END = 1_000_000  # µs
# Object 0: a disc 2 m deep centred on pixel (24, 24), 8 px in radius, sliding 0.2 m along x
# and turning 1 rad about the viewing axis over the sequence. Object 1: a disc 3 m deep on
# pixel (36, 24), 8 px in radius, still, in view for the first half only.
DISCS = [((24.0, 24.0), 2.0), ((36.0, 24.0), 3.0)]
RADIUS_PX = 8.0
SLIDE, TURN = 0.2, 1.0  # m along x, rad about z, over the whole sequence
HALF_OUT = 0.5  # object 1's span ends here (normalised time)
EDGE = 1.5  # px: how far a labelled outline may lie from the disc's (the render's spread)


def _centre(pixel: tuple[float, float], depth: float) -> np.ndarray:
    return np.array([(pixel[0] - W / 2) * depth / F, (pixel[1] - H / 2) * depth / F, depth])


def _disc(pixel: tuple[float, float], depth: float, spacing: float) -> np.ndarray:
    """Points on a grid filling the disc, facing the camera."""
    r = RADIUS_PX * depth / F
    g = np.arange(-r, r + spacing / 2, spacing)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= r]
    return _centre(pixel, depth) + np.c_[xy, np.zeros(len(xy))]


def _scene() -> tuple[GaussianModel, torch.Tensor, ObjectMotion]:
    """The two discs and a wall 5 m deep behind them (the scene's Gaussians, object -1)."""
    wall = _disc((W / 2, H / 2), 5.0, 0.08)  # a disc wider than the image at 5 m (r 0.4 m)
    wall = np.concatenate([wall + [dx, dy, 0.0] for dx in (-1.0, 0, 1.0) for dy in (-1.0, 0, 1.0)])
    parts = [_disc(p, d, 0.004 * d) for p, d in DISCS] + [wall]
    ids = np.concatenate([np.full(len(p), k if k < 2 else -1) for k, p in enumerate(parts)])
    means = np.concatenate(parts)
    model = GaussianModel(len(means), 3)
    with torch.no_grad():
        model.means.copy_(torch.from_numpy(means).float())
        depth = torch.from_numpy(means[:, 2]).float()
        spacing = torch.where(depth >= 5.0, torch.tensor(0.08), 0.004 * depth)
        model.log_scales.copy_(torch.log(spacing)[:, None].expand(-1, 3))
        model.opacity_logits.fill_(math.log(0.99 / 0.01))
    centres = torch.from_numpy(np.stack([_centre(p, d) for p, d in DISCS])).float()
    knots = torch.linspace(0.0, 1.0, 3)
    translations = torch.zeros(2, 3, 3)
    translations[0, :, 0] = SLIDE * knots
    rotvecs = torch.zeros(2, 3, 3)
    rotvecs[0, :, 2] = TURN * knots
    spans = torch.tensor([[-math.inf, math.inf], [-math.inf, HALF_OUT]])
    motion = ObjectMotion(centres, torch.tensor([0.16, 0.24]), translations, rotvecs, spans, 0.01)
    return model, torch.from_numpy(ids).long(), motion


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    model, ids, motion = _scene()
    return Renderer(
        model, None, torch.from_numpy(K).float(), W, H, 0, T_END, motion=motion, object_id=ids
    )


def _still_camera() -> Trajectory:
    return Trajectory.fit(np.array([0, T_END]), np.stack([np.eye(4), np.eye(4)]))


def test_each_objects_pose_is_its_paths(renderer):
    # The path's closed form at a quarter of the sequence: slid a quarter of SLIDE, turned a
    # quarter of TURN about the viewing axis, projected by the pinhole.
    poses = object_poses(renderer, 250_000, _still_camera())
    assert [p.object for p in poses] == [0, 1]
    first, second = poses
    want = _centre(*DISCS[0]) + [SLIDE / 4, 0.0, 0.0]
    np.testing.assert_allclose(first.position, want, atol=1e-6)
    half = TURN / 4 / 2
    np.testing.assert_allclose(first.quaternion, [math.cos(half), 0, 0, math.sin(half)], atol=1e-6)
    np.testing.assert_allclose(first.pixel, [24.0 + F * SLIDE / 4 / 2.0, 24.0], atol=1e-4)
    assert first.depth == pytest.approx(2.0)
    assert first.visible == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(second.pixel, DISCS[1][0], atol=1e-4)
    np.testing.assert_allclose(second.quaternion, [1, 0, 0, 0], atol=1e-7)
    assert object_poses(renderer, 750_000, _still_camera())[1].visible < 1e-6  # after its span


def test_behind_the_camera_an_object_has_no_pixel(renderer):
    turned = np.diag([-1.0, 1.0, -1.0, 1.0])  # the camera looking the other way
    poses = object_poses(renderer, 0, Trajectory.fit(np.array([0, T_END]), np.stack([turned] * 2)))
    assert all(np.isnan(p.pixel).all() and p.depth < 0 for p in poses)


def _disc_mask(pixel: tuple[float, float], grow: float = 0.0) -> np.ndarray:
    """The pixels whose centres lie within the disc's radius + ``grow`` of ``pixel``."""
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    return np.hypot(xx - pixel[0], yy - pixel[1]) <= RADIUS_PX + grow


def _is_disc(labelled: np.ndarray, pixel: tuple[float, float]) -> bool:
    """Whether ``labelled`` holds the disc about ``pixel`` to within ``EDGE`` of its outline."""
    return bool(
        labelled[_disc_mask(pixel, -EDGE)].all() and not labelled[~_disc_mask(pixel, EDGE)].any()
    )


def test_labels_are_each_objects_disc_and_the_nearer_owns_the_overlap(renderer):
    labels = object_labels(renderer, 0, np.eye(4))
    (near, _), (far, _) = DISCS
    overlap = _disc_mask(near) & _disc_mask(far)
    assert overlap.sum() > 20  # the two discs overlap in the image
    assert _is_disc(labels == 1, near)
    assert (labels[overlap] == 1).all()
    assert (labels[_disc_mask(far, -EDGE) & ~_disc_mask(near, EDGE)] == 2).all()
    assert (labels[~_disc_mask(near, EDGE) & ~_disc_mask(far, EDGE)] == 0).all()  # the wall


def test_labels_follow_the_path_and_the_span(renderer):
    # At 0.75 object 0 has slid 0.15 m (7.5 px at 2 m) and turned (a disc looks the same);
    # object 1's span ended at 0.5: nothing of it is labelled.
    labels = object_labels(renderer, 750_000, np.eye(4))
    assert _is_disc(labels == 1, (24.0 + F * 0.75 * SLIDE / 2.0, 24.0))
    assert not (labels == 2).any()


def _saved_run(tmp_path) -> str:
    model, ids, motion = _scene()
    cfg = preset("tiny")
    mlp = DeformationMLP(cfg.model)
    state = RunState(
        iteration=1,
        config=cfg,
        camera=Camera(K, W, H, 0, T_END, 3, "RGGB"),
        poses=Poses(np.array([0, T_END]), np.stack([np.eye(4), np.eye(4)])),
        dataset=str(tmp_path / "no-dataset"),
        gaussians=model.state_for_checkpoint(),
        mlp=mlp.state_dict(),
        mlp_active=False,
        optimizer=torch.optim.Adam(model.parameters()).state_dict(),
        mlp_optimizer=torch.optim.Adam(mlp.parameters()).state_dict(),
        densifier={},
        static_mask=None,
        static_scene=False,
        objects={"motion": motion.state(), "object_id": ids},
        early_stop={"best": None, "since_best": 0, "stopped_at": None},
    )
    run = tmp_path / "run"
    state.save(run, keep=1)
    return str(run)


def test_export_tracks_and_render_objects_from_a_saved_run(tmp_path, renderer, capsys):
    run = _saved_run(tmp_path)
    csv = tmp_path / "tracks.csv"
    assert main(["export", run, "--tracks", str(csv), "--times", "0:1:0.25"]) == 0
    lines = csv.read_text().splitlines()
    assert lines[0] == TRACK_COLUMNS and len(lines) == 1 + 5 * 2
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    quarter = rows[(rows[:, 0] == 250_000) & (rows[:, 1] == 0)][0]
    np.testing.assert_allclose(quarter[10:12], [24.0 + F * SLIDE / 4 / 2.0, 24.0], atol=1e-3)

    out = tmp_path / "frames"
    assert (
        main(["render", run, "--out", str(out), "--times", "0,0.75", "--objects", "--video"]) == 0
    )
    assert "1 = object 0 (lime), 2 = object 1 (magenta)" in capsys.readouterr().out
    for i, t_us in enumerate((0, 750_000)):
        got = np.round(read_png(out / f"labels_{i:05d}.png") * 255).astype(int)
        np.testing.assert_array_equal(got, object_labels(renderer, t_us, np.eye(4)))
        assert read_png(out / f"objects_{i:05d}.png").shape == (H, W, 3)
    assert read_mp4_frame(out / "objects.mp4", 1).shape[2] == 3  # two frames, upscaled


def test_export_takes_one_output(tmp_path, capsys):
    run = _saved_run(tmp_path)
    code = main(["export", run, "--tracks", str(tmp_path / "t.csv"), "--ply", str(tmp_path / "a")])
    assert code == 2
    assert "give --ply OUT, or --times a:b:step with --ply-dir DIR, or --tracks" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "t.csv").exists()
