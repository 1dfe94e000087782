"""Held-out scenes: made to test the motion module (``evsplat.motion``) on scenes that none of
its numbers were tuned on (docs/motion.md). Keep them that way: a change tuned on one of these
must move it to ``multi_object`` and add a new held-out scene in its place.

Same world frame and room as ``library``; every mover is its own object (``Primitive.group``).
"""

from __future__ import annotations

import numpy as np

from evsplat.scenes.geometry import Primitive, checker, noise, rot, trans
from evsplat.scenes.library import camera_path, room


def paddle() -> dict:
    """A short, wide card with a noise texture turning the other way from ``spinner``'s, more
    slowly, while its centre drifts, in front of a blue tiled wall."""

    def pose(t: float) -> np.ndarray:
        return trans(-0.25 + 0.3 * t, 0.1 - 0.1 * t, 3.1) @ rot("z", -6.0 * t + 1.2)

    prims = room([(0.3, 0.35, 0.55), (0.2, 0.25, 0.4), (0.5, 0.5, 0.6), (0.15, 0.2, 0.3)], seed=11)
    tex = noise(3, 6.0, 3, (0.6, 0.55, 0.2), (0.4, 0.4, 0.2))
    prims.append(Primitive("quad", (0.36, 0.14), pose, tex, True, "paddle"))
    return dict(
        description=(
            "held out: a yellow noise-textured paddle (0.72 x 0.28 m) turning at -6 rad/s while "
            "it drifts, in front of a tiled blue wall"
        ),
        primitives=prims,
        camera=camera_path(0.16, 0.1, 0.06, 0.04, 1.5),
        base_size=(400, 400),
    )


def pair() -> dict:
    """A long checkered bar sliding diagonally down while it tilts, and a mottled ball behind
    it crossing the other way, green on a grey-green wall."""

    def bar_pose(t: float) -> np.ndarray:
        return trans(-0.55 + 1.6 * t, -0.35 + 0.7 * t, 2.7) @ rot("z", 0.4 + 1.5 * t)

    def ball_pose(t: float) -> np.ndarray:
        return trans(0.6 - 1.9 * t, 0.3 - 0.15 * t, 3.2) @ rot("y", 4.0 * t)

    prims = room(
        [(0.35, 0.45, 0.35), (0.25, 0.32, 0.27), (0.55, 0.6, 0.5), (0.18, 0.22, 0.2)], seed=13
    )
    bar = checker(6.0, 2.0, (0.95, 0.5, 0.1), (0.15, 0.1, 0.1), scale=(0.6, 0.14))
    ball = noise(7, 5.0, 2, (0.3, 0.7, 0.35), (0.35, 0.3, 0.3))
    prims += [
        Primitive("quad", (0.3, 0.07), bar_pose, bar, True, "bar"),
        Primitive("sphere", (0.2,), ball_pose, ball, True, "ball"),
    ]
    return dict(
        description=(
            "held out: an orange-and-black bar (0.6 x 0.14 m) sliding diagonally while it tilts, "
            "and a mottled green ball crossing the other way behind it, on a grey-green wall"
        ),
        primitives=prims,
        camera=camera_path(0.14, 0.09, 0.05, 0.04, 1.35),
        base_size=(400, 400),
    )


SCENES = {"paddle": paddle, "pair": pair}
