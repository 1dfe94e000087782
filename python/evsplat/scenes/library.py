"""The built-in dynamic scenes, echoing the paper's BlenderDynamicEvent set.

World frame follows the camera convention: x right, y down, z forward. Every scene has a tiled
static background wall and floor, a hand-held-like moving camera, and an object moving fast
enough to blur a 30 fps camera (tens of pixels per 33 ms). Poses are functions of time in seconds.
"""

from __future__ import annotations

import numpy as np

from evsplat.scenes.geometry import (
    Blob,
    Primitive,
    checker,
    clock_face,
    colour_blobs,
    feathers,
    noise,
    one_object,
    rot,
    solid,
    sphere_segments,
    static,
    trans,
    wall,
    wing_pattern,
)

TAU = 2 * np.pi
BACK_WALL_Z = 5.0
FLOOR_Y = 1.0


def camera_path(ax: float, ay: float, yaw: float, pitch: float, f: float):
    """A smooth hand-held-like camera: sinusoidal translation and rotation.

    The pan and tilt (a few degrees, several pixels per 10 ms at full size) move the static
    background in both image directions, so its edges of every orientation fire events: with
    a nearly still camera the background is barely observable from events at all.
    """

    def c2w(t: float) -> np.ndarray:
        m = trans(
            ax * np.sin(TAU * f * t),
            ay * np.sin(TAU * 1.3 * f * t + 0.7),
            0.05 * np.sin(TAU * 0.5 * f * t),
        )
        return (
            m
            @ rot("y", yaw * np.sin(TAU * f * t + 0.3))
            @ rot("x", pitch * np.sin(TAU * 0.8 * f * t))
        )

    return c2w


def room(palette: list, seed: int) -> list[Primitive]:
    """Static background: a tiled back wall and a checkered floor."""
    back = Primitive(
        "quad", (6.0, 6.0), static(trans(0, 0, BACK_WALL_Z)), wall(palette, 0.45, seed), False
    )
    floor_tex = checker(2.0, 2.0, (0.55, 0.5, 0.42), (0.18, 0.16, 0.14))
    floor = Primitive(
        "quad", (6.0, 4.0), static(trans(0, FLOOR_Y, 3.0) @ rot("x", np.pi / 2)), floor_tex, False
    )
    return [back, floor]


# ---------------------------------------------------------------- butterfly


def butterfly() -> dict:
    half = (0.32, 0.4)
    flap_hz, flap_amp = 4.0, 0.75

    def body_pose(t: float) -> np.ndarray:
        x = 0.45 * np.sin(TAU * 0.7 * t)
        y = -0.15 + 0.12 * np.sin(TAU * 1.4 * t)
        return trans(x, y, 3.0) @ rot("z", 0.25 * np.sin(TAU * 0.7 * t)) @ rot("x", -0.35)

    def wing_pose(side: float):
        def pose(t: float) -> np.ndarray:
            theta = flap_amp * np.sin(TAU * flap_hz * t)
            return body_pose(t) @ rot("y", side * theta) @ trans(side * half[0], 0, 0)

        return pose

    prims = room([(0.2, 0.45, 0.2), (0.35, 0.6, 0.25), (0.15, 0.3, 0.35), (0.5, 0.55, 0.3)], seed=1)
    body = Primitive(
        "box",
        (0.035, 0.32, 0.035),
        body_pose,
        checker(0, 12.0, (0.1, 0.08, 0.05), (0.4, 0.3, 0.15), scale=(1, 0.64)),
        True,
    )
    wings = [
        Primitive("wing", (*half, side), wing_pose(side), wing_pattern(half, side), True)
        for side in (1.0, -1.0)
    ]
    prims += one_object("butterfly", [body, *wings])
    return dict(
        description=(
            "butterfly with two thin quad wings flapping at 4 Hz (±43°) while "
            "drifting in a figure-8, in front of a tiled green wall"
        ),
        primitives=prims,
        camera=camera_path(0.18, 0.1, 0.06, 0.045, 1.3),
        base_size=(400, 400),
    )


# ---------------------------------------------------------------- duck


def duck() -> dict:
    bob_hz = 3.0

    def body_pose(t: float) -> np.ndarray:
        x = -0.7 + 1.4 * t  # paddles left to right over one second
        y = 0.35 + 0.18 * np.sin(TAU * bob_hz * t)
        return (
            trans(x, y, 3.2)
            @ rot("z", 0.3 * np.sin(TAU * bob_hz * t + 0.6))
            @ rot("x", 0.2 * np.sin(TAU * bob_hz * t + 1.3))
            @ rot("y", 0.5 * np.sin(TAU * 0.5 * t))
        )

    def part(offset: np.ndarray):
        return lambda t: body_pose(t) @ offset

    prims = room([(0.25, 0.4, 0.6), (0.15, 0.25, 0.5), (0.4, 0.55, 0.7), (0.2, 0.3, 0.35)], seed=2)
    prims += one_object(
        "duck",
        [
            Primitive("sphere", (0.42,), body_pose, feathers(), True),
            Primitive(
                "sphere",
                (0.26,),
                part(trans(0.3, -0.5, 0.0)),
                sphere_segments(8, 4, [(0.95, 0.8, 0.1), (0.85, 0.65, 0.05)]),
                True,
            ),
            Primitive(
                "box",
                (0.14, 0.045, 0.09),
                part(trans(0.6, -0.46, 0.0) @ rot("z", 0.15)),
                solid((0.95, 0.35, 0.02)),
                True,
            ),
            Primitive(
                "sphere", (0.05,), part(trans(0.42, -0.62, -0.18)), solid((0.1, 0.1, 0.12)), True
            ),
            Primitive(
                "box",
                (0.3, 0.08, 0.06),
                part(trans(-0.15, -0.1, -0.38) @ rot("z", -0.3)),
                checker(6.0, 1.0, (0.9, 0.6, 0.05), (0.6, 0.35, 0.02), scale=(0.6, 1)),
                True,
            ),
        ],
    )
    return dict(
        description=(
            "duck-like toy (body, head, beak, wing) bobbing at 3 Hz on a sinusoid "
            "while crossing the view, in front of a tiled blue wall"
        ),
        primitives=prims,
        camera=camera_path(0.2, 0.08, 0.06, 0.04, 1.2),
        base_size=(600, 400),
    )


# ---------------------------------------------------------------- alarm clock


def clock() -> dict:
    half = (0.45, 0.45, 0.16)
    shake_hz = 9.0

    def body_pose(t: float) -> np.ndarray:
        jitter = 0.04 * np.sin(TAU * 13.0 * t)
        return (
            trans(jitter, 0.05 + 0.02 * np.sin(TAU * 17.0 * t), 3.0)
            @ rot("z", 0.22 * np.sin(TAU * shake_hz * t))
            @ rot("y", 0.3)
        )

    def part(offset: np.ndarray):
        return lambda t: body_pose(t) @ offset

    def hand(length: float, width: float, rev_per_s: float, phase: float):
        def pose(t: float) -> np.ndarray:
            spin = rot("z", phase + TAU * rev_per_s * t)
            return body_pose(t) @ trans(0, 0, -half[2] - 0.01) @ spin @ trans(0, -length / 2, 0)

        return Primitive("quad", (width, length / 2), pose, solid((0.1, 0.1, 0.18)), True)

    bell = sphere_segments(10, 6, [(0.85, 0.75, 0.3), (0.55, 0.45, 0.15)])
    prims = room(
        [(0.6, 0.5, 0.35), (0.45, 0.35, 0.25), (0.7, 0.65, 0.5), (0.35, 0.25, 0.2)], seed=3
    )
    prims += one_object(
        "clock",
        [
            Primitive("box", half, body_pose, clock_face(half[:2]), True),
            Primitive("sphere", (0.17,), part(trans(-0.3, -0.55, 0.0)), bell, True),
            Primitive("sphere", (0.17,), part(trans(0.3, -0.55, 0.0)), bell, True),
            Primitive(
                "box", (0.05, 0.08, 0.05), part(trans(-0.3, 0.5, 0.0)), solid((0.1, 0.1, 0.1)), True
            ),
            Primitive(
                "box", (0.05, 0.08, 0.05), part(trans(0.3, 0.5, 0.0)), solid((0.1, 0.1, 0.1)), True
            ),
            hand(0.32, 0.025, 0.0, 1.0),
            hand(0.5, 0.012, 1.5, 0.0),
        ],
    )
    return dict(
        description=(
            "red alarm clock with bells shaking at 9 Hz (±13°) while its second "
            "hand sweeps 1.5 rev/s, in front of a tiled beige wall"
        ),
        primitives=prims,
        camera=camera_path(0.18, 0.1, 0.06, 0.045, 1.6),
        base_size=(400, 400),
    )


# ---------------------------------------------------------------- bouncing ball


def ball() -> dict:
    r = 0.38
    bounce_hz = 2.5

    def pose(t: float) -> np.ndarray:
        height = 1.1 * np.abs(np.sin(np.pi * bounce_hz * t))  # parabola-like arcs, sharp at contact
        return (
            trans(0.9 * np.sin(TAU * 0.6 * t), FLOOR_Y - r - height, 3.0)
            @ rot("z", 9.0 * t)
            @ rot("x", 5.0 * t)
        )

    colours = [
        (0.9, 0.1, 0.1),
        (0.95, 0.95, 0.9),
        (0.1, 0.3, 0.9),
        (0.95, 0.8, 0.1),
        (0.1, 0.7, 0.2),
        (0.95, 0.95, 0.9),
    ]
    prims = room([(0.5, 0.3, 0.5), (0.35, 0.2, 0.4), (0.6, 0.45, 0.6), (0.25, 0.15, 0.3)], seed=4)
    prims.append(Primitive("sphere", (r,), pose, sphere_segments(6, 4, colours), True, "ball"))
    return dict(
        description=(
            "textured beach ball bouncing 2.5 times a second (up to 3.3 m/s) and "
            "spinning, in front of a tiled purple wall"
        ),
        primitives=prims,
        camera=camera_path(0.2, 0.12, 0.07, 0.05, 1.5),
        base_size=(400, 400),
    )


# ---------------------------------------------------------------- static counterpart


def still() -> dict:
    """The ball scene with the ball at rest on the floor: only the camera moves. Not in the
    paper; it is the scene where skipping the deformation MLP must cost no accuracy."""
    spec = ball()
    rest = trans(-0.5, FLOOR_Y - 0.38, 3.0) @ rot("z", 0.4)
    ball_prim = spec["primitives"][-1]
    spec["primitives"][-1] = Primitive(
        ball_prim.kind, ball_prim.size, static(rest), ball_prim.texture, False
    )
    spec["description"] = "the ball scene's room and ball, with the ball at rest: a static scene"
    return spec


# ---------------------------------------------------------------- camouflage


def orbit(centre: tuple[float, float, float], radius: float, azimuth: float, f: float):
    """A camera on a small orbit around `centre`, always looking at it: ±`azimuth` radians about
    the vertical at `f` Hz, a little elevation, and a slight hand-held jitter on top.

    Unlike `camera_path` it turns around the scene rather than about itself, so near and far
    surfaces shift against each other (parallax) by more than the jitter alone gives.
    """
    hand = camera_path(0.03, 0.02, 0.01, 0.01, 1.7)

    def c2w(t: float) -> np.ndarray:
        turn = rot("y", azimuth * np.sin(TAU * f * t))
        tilt = rot("x", 0.05 * np.sin(TAU * f * t + 1.2))
        return trans(*centre) @ turn @ tilt @ trans(0, 0, -radius) @ hand(t)

    return c2w


def camo() -> dict:
    """A sphere painted with the same dense noise as the wall behind it: in a single frame it is
    hard to see; only its motion (and shading) gives it away."""
    r, depth = 0.38, 3.0
    base, amp = (0.5, 0.45, 0.38), (0.95, 0.9, 0.8)  # clamped to [0, 1]: strong contrast
    wall_freq = 12.0  # lattice cells per metre on the wall: ~3 px at tiny size, 7 px at full
    # The sphere is nearer (3 m vs 5 m): a finer lattice gives the same cells in pixels.
    sphere_freq = wall_freq * BACK_WALL_Z / depth

    def pose(t: float) -> np.ndarray:
        return (
            trans(
                0.7 * np.sin(TAU * 1.1 * t),  # up to 4.8 m/s sideways
                0.32 * np.sin(TAU * 1.7 * t + 0.6),
                depth + 0.25 * np.sin(TAU * 0.8 * t),
            )
            @ rot("z", 6.0 * t)
            @ rot("x", 4.0 * t)
        )

    back = Primitive(
        "quad",
        (6.0, 6.0),
        static(trans(0, 0, BACK_WALL_Z)),
        noise(11, wall_freq, 2, base, amp),
        False,
    )
    # Lambert shading darkens the sphere on average (0.71 of full light vs the wall's 0.77):
    # a slightly brighter base keeps the two mean colours alike (1.05, not 0.77 / 0.71, as
    # clamping to [0, 1] already shifts the means; measured on the tiny frames).
    sphere_base = tuple(1.05 * c for c in base)
    ball_prim = Primitive(
        "sphere", (r,), pose, noise(12, sphere_freq, 2, sphere_base, amp), True, "sphere"
    )
    return dict(
        description=(
            "camouflaged sphere: dense multi-colour noise on the sphere and on the wall behind "
            "it, the sphere flying a Lissajous path (up to 5 m/s) and spinning, the camera "
            "orbiting ±13° around it"
        ),
        primitives=[back, ball_prim],
        camera=orbit((0.0, 0.0, depth), depth, 0.22, 1.0),
        base_size=(400, 400),
    )


# ---------------------------------------------------------------- smooth wall


def blobs() -> dict:
    """The ball scene with a back wall of broad smooth colour blobs instead of tiles: under the
    small camera motion the wall makes few events, so the background is weakly observed."""
    spec = ball()
    spots = [
        Blob(-2.2, -1.6, 0.8, (0.7, 0.35, 0.55)),
        Blob(-0.6, -2.0, 0.7, (0.3, 0.35, 0.65)),
        Blob(1.2, -1.3, 0.9, (0.65, 0.55, 0.3)),
        Blob(2.6, -0.2, 0.7, (0.35, 0.6, 0.55)),
        Blob(-1.5, 0.2, 0.75, (0.25, 0.15, 0.35)),
        Blob(0.4, 0.0, 0.8, (0.6, 0.45, 0.65)),
        Blob(-3.0, 1.0, 0.8, (0.55, 0.5, 0.3)),
        Blob(1.8, 1.2, 0.8, (0.3, 0.2, 0.45)),
    ]
    wall_prim = spec["primitives"][0]
    spec["primitives"][0] = Primitive(
        wall_prim.kind,
        wall_prim.size,
        wall_prim.pose,
        colour_blobs((0.45, 0.3, 0.45), spots),
        False,
    )
    spec["description"] = (
        "the ball scene (beach ball bouncing 2.5 times a second, same camera) in front of a "
        "wall of broad, smooth colour blobs with no edges"
    )
    return spec


SCENES = {
    "butterfly": butterfly,
    "duck": duck,
    "clock": clock,
    "ball": ball,
    "still": still,
    "camo": camo,
    "blobs": blobs,
}
