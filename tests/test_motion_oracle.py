"""``mover.oracle``: the found objects take the simulator's true motion. The oracle is the scene's
own pose functions (``evsplat.scenes``): a point fixed to a true object at its reference time
must land where that object's pose carries it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from evsplat.errors import EvsplatError
from evsplat.model.motion import ObjectMotion
from evsplat.scenes import get_scene
from evsplat.train.motion_oracle import apply_oracle, true_scene

KNOTS = 61


def _dataset(name: str) -> SimpleNamespace:
    """What the oracle reads of a simulated dataset of built-in scene ``name`` (tiny)."""
    scene = get_scene(name, tiny=True)
    meta = {"generator": "evsplat simulate", "scene": name, "tiny": True}
    meta |= {"width": scene.width, "height": scene.height}
    return SimpleNamespace(
        root=Path("data") / name,
        meta=meta,
        t_start_us=0,
        t_end_us=scene.duration_us,
        K=scene.K,
        trajectory=SimpleNamespace(pose=scene.c2w),
    )


def _seeded(centres: np.ndarray) -> ObjectMotion:
    """Objects at ``centres`` [K,3] that the seeding left still and unturned."""
    k = len(centres)
    zeros = torch.zeros(k, KNOTS, 3)
    return ObjectMotion(torch.from_numpy(centres), torch.full((k,), 0.1), zeros, zeros)


def _true_pose(name: str, obj: int, t_us: float) -> np.ndarray:
    scene = get_scene(name, tiny=True)
    return scene.primitives[scene.objects[obj].parts[0]].pose(t_us * 1e-6)


@pytest.mark.parametrize("mode", ["turn", "path", "both"])
def test_a_point_on_a_found_object_moves_as_the_true_object_moves_it(mode: str) -> None:
    name, t_ref = "crossing", 180_000
    data = _dataset(name)
    scene = get_scene(name, tiny=True)
    truths = np.stack([scene.object_centre(t_ref, i) for i in range(len(scene.objects))])
    # Found objects a little off the true centres (as a region's centre is), listed out of order.
    order = [2, 0, 1]
    centres = truths[order] + np.array([0.02, -0.01, 0.0])
    motion = _seeded(centres)
    stats = apply_oracle(motion, {k: t_ref for k in range(3)}, mode, scene, data)

    assert [stats[f"object{k}_oracle_match"] for k in range(3)] == order
    knots = np.linspace(0, scene.duration_us, KNOTS)
    rng = np.random.default_rng(0)
    for k, obj in enumerate(order):
        # Points fixed to the object at the reference time: about its found centre.
        points = centres[k] + rng.normal(0, 0.1, (5, 3))
        ref = _true_pose(name, obj, t_ref)
        for g in (0, 17, 40, KNOTS - 1):
            now = _true_pose(name, obj, knots[g])
            carried = now[:3, :3] @ ref[:3, :3].T
            ids = torch.full((5,), k, dtype=torch.long)
            quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(5, 1)
            moved, _ = motion.apply(torch.from_numpy(points).float(), quats, ids, g / (KNOTS - 1))
            moved = moved.detach().double().numpy()
            true_centre = carried @ (centres[k] - ref[:3, 3]) + now[:3, 3]
            if mode == "both":
                want = (points - ref[:3, 3]) @ carried.T + now[:3, 3]
                np.testing.assert_allclose(moved, want, atol=1e-4)
            elif mode == "path":  # the found centre rides the true path, unturned
                want = points - centres[k] + true_centre
                np.testing.assert_allclose(moved, want, atol=1e-4)
            else:  # turned as the object turns, about the found centre, which stays
                want = (points - centres[k]) @ carried.T + centres[k]
                np.testing.assert_allclose(moved, want, atol=1e-4)
    # The track prior holds the paths at the truth, not at the seeding's.
    assert torch.equal(motion.translations, motion.prior_translations)
    assert torch.equal(motion.rotvecs, motion.prior_rotvecs)


def test_a_turn_past_half_a_revolution_is_unwrapped_from_the_reference_time() -> None:
    # spinner's card turns 8 rad/s: 4.8 rad over the 0.6 s, so its rotation vectors pass pi.
    name, t_ref = "spinner", 300_000
    data = _dataset(name)
    centre = get_scene(name, tiny=True).object_centre(t_ref, 0)
    motion = _seeded(centre[None])
    apply_oracle(motion, {0: t_ref}, "turn", get_scene(name, tiny=True), data)
    # It turns about the world's z axis.
    angles = motion.rotvecs[0].detach().double().numpy() @ np.array([0.0, 0.0, 1.0])
    steps = np.diff(angles)
    assert np.abs(steps).max() < 0.2  # no jump of a whole turn between knots
    np.testing.assert_allclose(angles[-1] - angles[0], 8.0 * 0.6, rtol=1e-3)
    assert abs(angles[KNOTS // 2]) < 1e-6  # no turn at the reference time


def test_the_oracle_refuses_other_data_and_unknown_modes() -> None:
    real = SimpleNamespace(root=Path("data/davis"), meta={"generator": "evsplat convert"})
    with pytest.raises(EvsplatError, match="needs a built-in synthetic scene"):
        true_scene("both", real)
    assert true_scene("none", real) is None
    with pytest.raises(EvsplatError, match="expected one of none, turn, path, both"):
        true_scene("true", _dataset("ball"))
