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


def approach() -> dict:
    """A box that slides, halts and slides on (a mover that stops: its halt fires only the
    camera's events, as the wall does), and a ball coming toward the camera along its ray, so
    it grows (4.3 m to 2.7 m over the tiny variant's 0.6 s) while its bearing barely turns: it
    moves in the picture about as much as the camera's motion moves the wall."""

    def ease(u: float) -> float:
        u = min(max(u, 0.0), 1.0)
        return u * u * (3.0 - 2.0 * u)

    def box_pose(t: float) -> np.ndarray:
        x = (
            -0.55
            + 0.45 * ease(t / 0.22)
            + 0.4 * ease((t - 0.4) / 0.22)
            - 0.3 * ease((t - 0.75) / 0.2)
        )
        return trans(x, 0.25, 3.0) @ rot("y", 0.5 + 1.2 * x) @ rot("x", 0.25)

    def ball_pose(t: float) -> np.ndarray:
        return trans(0.35 - 0.3 * t, -0.3 + 0.25 * t, 4.3 - 2.6 * t) @ rot("y", 4.0 * t)

    prims = room(
        [(0.45, 0.42, 0.3), (0.3, 0.28, 0.2), (0.6, 0.58, 0.45), (0.2, 0.2, 0.15)], seed=19
    )
    box = checker(4.0, 3.0, (0.1, 0.6, 0.65), (0.5, 0.1, 0.2), scale=(0.4, 0.26))
    ball = noise(23, 6.0, 2, (0.8, 0.35, 0.3), (0.2, 0.25, 0.2))
    prims += [
        Primitive("box", (0.2, 0.13, 0.1), box_pose, box, True, "box"),
        Primitive("sphere", (0.18,), ball_pose, ball, True, "ball"),
    ]
    return dict(
        description=(
            "held out: a checkered box that slides, halts for 0.18 s and slides on, and a "
            "mottled red ball coming toward the camera (4.3 to 2.7 m in 0.6 s) while its bearing "
            "barely turns, on a tiled olive wall"
        ),
        primitives=prims,
        camera=camera_path(0.15, 0.1, 0.055, 0.04, 1.25),
        base_size=(400, 400),
    )


SCENES = {"paddle": paddle, "approach": approach}
