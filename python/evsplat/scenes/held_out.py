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


def slalom() -> dict:
    """A checkered box weaving across the view while it turns in the image plane, and a
    mottled ball crossing the other way above it, farther off, under a hand-held camera."""

    def box_pose(t: float) -> np.ndarray:
        y = 0.12 + 0.12 * np.sin(2 * np.pi * 1.6 * t)
        return trans(-0.55 + 1.5 * t, y, 3.2) @ rot("z", 1.2 * t) @ rot("x", 0.3)

    def ball_pose(t: float) -> np.ndarray:
        return trans(0.5 - 1.0 * t, -0.4 + 0.3 * t, 3.6) @ rot("x", 5.0 * t)

    prims = room(
        [(0.5, 0.45, 0.55), (0.3, 0.28, 0.35), (0.65, 0.6, 0.7), (0.2, 0.2, 0.25)], seed=29
    )
    box = checker(3.0, 3.0, (0.9, 0.8, 0.2), (0.2, 0.3, 0.6), scale=(0.32, 0.24))
    ball = noise(31, 5.0, 2, (0.35, 0.75, 0.7), (0.25, 0.2, 0.2))
    prims += [
        Primitive("box", (0.16, 0.12, 0.1), box_pose, box, True, "box"),
        Primitive("sphere", (0.15,), ball_pose, ball, True, "ball"),
    ]
    return dict(
        description=(
            "held out: a yellow-and-blue checkered box weaving across the view while it turns, "
            "and a mottled teal ball crossing the other way above it, on a tiled mauve wall"
        ),
        primitives=prims,
        camera=camera_path(0.14, 0.1, 0.05, 0.045, 1.45),
        base_size=(400, 400),
    )


SCENES = {"paddle": paddle, "slalom": slalom}
