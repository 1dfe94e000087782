"""Scenes drawn at random from a number (``drawn-N``): one to three movers of random shape
(sphere, box or card), size, depth, texture, path and turn, under a still or a hand-held camera,
before a room of random colours. They are for measuring the motion module on scenes that none
of its numbers were tuned on: each N is a new scene, never looked at before it is measured, and
a change tuned on one must say so (docs/experiments/objects.md, "Drawn scenes").

Every mover is its own object, at its own depth slot: slots are ``SLOT_M`` apart, more than any
mover's radius, so the evaluation's depth tolerance (``evsplat.motion_metrics``) tells an
object's Gaussians from those of one it passes. Each mover's centre is in view (the tiny
variant's image) for at least ``MIN_IN_VIEW`` of the tiny variant's 0.6 s; it may enter, leave,
cross another, only turn in place, or tumble about all three axes.
"""

from __future__ import annotations

import re

import numpy as np

from evsplat.scenes.geometry import (
    Primitive,
    Texture,
    checker,
    noise,
    rot,
    sphere_segments,
    static,
    trans,
)
from evsplat.scenes.library import camera_path, room

PATTERN = re.compile(r"drawn-(\d{1,9})")
SLOT_M = 0.6  # depth step between the movers' slots (m): more than any mover's radius
NEAREST_M = 2.0  # the nearest slot's depth (m); the back wall is at 5
INSIDE = 0.9  # of the tiny image's half width: a mover's centre within it counts as in view
MIN_IN_VIEW = 0.5  # of the tiny variant's duration, each mover's centre in view at least
TRIES = 200  # paths drawn per mover until one is in view long enough
STILL_CAMERA = 1 / 3  # the chance of a still camera (most real recordings)
TILT = 0.7  # most a mover starts tilted out of the image plane (rad): a card's face 0.76 seen


#: What ``evsplat simulate --help`` says of them.
SUMMARY = (
    "a scene drawn at random from N (0, 1, ...): one to three movers of random shape, size, "
    "depth, texture, path and turn, under a still or a hand-held camera"
)


def tiny_view() -> tuple[float, float]:
    """(half the tiny variant's (square) field of view per metre of depth, its duration in
    seconds), from ``evsplat.scenes``' constants (imported here: that package imports this one)."""
    from evsplat.scenes import FOCAL_PER_HEIGHT, TINY_DURATION_US, TINY_SIZE, TINY_ZOOM

    return (TINY_SIZE / 2) / (FOCAL_PER_HEIGHT * TINY_SIZE * TINY_ZOOM), TINY_DURATION_US * 1e-6


def seed_of(name: str) -> int | None:
    """N of a scene named ``drawn-N``, or None for any other name."""
    m = PATTERN.fullmatch(name)
    return int(m.group(1)) if m else None


def _colour(rng: np.random.Generator) -> list[float]:
    return rng.uniform(0.05, 0.95, 3).round(2).tolist()


def _pair(rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """Two colours whose brightness differs by a quarter at least (a texture the events see)."""
    while True:
        a, b = _colour(rng), _colour(rng)
        if abs(np.mean(a) - np.mean(b)) >= 0.25:
            return a, b


def _texture(rng: np.random.Generator, kind: str, size: tuple[float, ...]) -> tuple[Texture, str]:
    """(texture, its words): checkered, mottled, or (a sphere) beach-ball segments."""
    a, b = _pair(rng)
    choice = rng.choice(
        ["checker", "noise", "segments"] if kind == "sphere" else ["checker", "noise"]
    )
    if choice == "segments":
        return sphere_segments(int(rng.integers(3, 8)), int(rng.integers(1, 4)), [a, b]), "striped"
    if choice == "noise":
        amp = rng.uniform(0.2, 0.5, 3).round(2).tolist()
        return noise(int(rng.integers(1000)), float(rng.uniform(3, 10)), 2, a, amp), "mottled"
    cells = rng.integers(2, 7, 2).astype(float)
    scale = (2 * size[0], 2 * size[1 if len(size) > 1 else 0])
    return checker(cells[0], cells[1], a, b, scale=scale), "checkered"


def _path(rng: np.random.Generator, depth: float, camera, mode: str):
    """(centre at time t in seconds, speed m/s): straight with a sideways sway, from a start
    in view (or beside it, when it ``enter``s), or held still (``turn`` in place); drawn again
    until its centre is in view for ``MIN_IN_VIEW`` of the tiny duration."""
    half_view, duration = tiny_view()
    half = half_view * depth
    for _ in range(TRIES):
        start = rng.uniform(-0.8, 0.8, 2) * half
        if mode == "enter":
            start[0] = rng.choice([-1.0, 1.0]) * 1.3 * half
        speed = 0.0 if mode == "turn" else float(rng.uniform(0.4, 3.0))
        heading = rng.uniform(0, 2 * np.pi)
        if mode == "enter":  # towards the middle, give or take 45 degrees
            heading = np.arctan2(-start[1], -start[0]) + rng.uniform(-0.8, 0.8)
        v = speed * np.array([np.cos(heading), np.sin(heading)])
        sway, freq = float(rng.uniform(0, 0.15)) * (speed > 0), float(rng.uniform(0.5, 2.0))
        side = np.array([-v[1], v[0]]) / max(speed, 1e-9)

        def centre(t: float, start=start, v=v, sway=sway, freq=freq, side=side) -> np.ndarray:
            xy = start + v * t + sway * np.sin(2 * np.pi * freq * t) * side
            return np.array([xy[0], xy[1], depth])

        seen = 0
        times = np.linspace(0.0, duration, 31)
        for t in times:
            c2w = camera(float(t))
            x, y, z = c2w[:3, :3].T @ (centre(float(t)) - c2w[:3, 3])
            seen += z > 0 and max(abs(x), abs(y)) <= INSIDE * half_view * z
        if seen >= MIN_IN_VIEW * len(times):
            return centre, speed
    raise RuntimeError("no path in view: the drawing's ranges are wrong")  # a bug, not input


def drawn(n: int) -> dict:
    """The scene ``drawn-n`` (module docstring)."""
    rng = np.random.default_rng([n, 7919])
    still = bool(rng.random() < STILL_CAMERA)
    camera = (
        static(np.eye(4))
        if still
        else camera_path(*rng.uniform([0.08, 0.05, 0.03, 0.03, 1.0], [0.18, 0.1, 0.07, 0.05, 1.6]))
    )
    base = np.array(_colour(rng))
    palette = [np.clip(base * f, 0, 1).round(2).tolist() for f in (1.0, 0.7, 1.3, 0.5)]
    prims = room(palette, int(rng.integers(1000)))
    count = int(rng.integers(1, 4))
    words = []
    for k, slot in enumerate(sorted(rng.choice(4, count, replace=False))):
        depth = NEAREST_M + SLOT_M * slot + float(rng.uniform(0, 0.1))
        kind = str(rng.choice(["sphere", "box", "quad"]))
        size: tuple[float, ...]
        if kind == "sphere":
            size = (float(rng.uniform(0.12, 0.28)),)
        elif kind == "box":
            size = tuple(float(s) for s in rng.uniform(0.07, 0.24, 3))
        else:
            size = (float(rng.uniform(0.12, 0.4)), float(rng.uniform(0.05, 0.18)))
        mode = str(rng.choice(["cross", "cross", "enter", "turn"]))
        centre, speed = _path(rng, depth, camera, mode)
        spin = rng.uniform(-8, 8, 3) * (rng.random(3) < [0.25, 0.25, 0.7])
        if mode == "turn":
            spin[2] = rng.choice([-1.0, 1.0]) * rng.uniform(3, 8)
        phase = rng.uniform(0, 2 * np.pi, 3)
        phase[:2] = (phase[:2] / np.pi - 1.0) * TILT  # a card never starts edge-on

        def pose(t: float, centre=centre, spin=spin, phase=phase) -> np.ndarray:
            a = spin * t + phase
            return trans(*centre(t)) @ rot("x", a[0]) @ rot("y", a[1]) @ rot("z", a[2])

        texture, look = _texture(rng, kind, size)
        name = f"{'card' if kind == 'quad' else kind}{k}"
        prims.append(Primitive(kind, size, pose, texture, True, name))
        how = {"cross": f"moving at {speed:.1f} m/s", "enter": f"entering at {speed:.1f} m/s"}
        turn = "tumbling" if (spin[:2] != 0).any() else f"turning at {spin[2]:.1f} rad/s"
        turn = turn if spin.any() else "not turning"
        words.append(f"a {look} {name} at {depth:.1f} m {how.get(mode, 'held in place')}, {turn}")
    camera_words = "a still camera" if still else "a hand-held camera"
    return dict(
        description=f"drawn at random (N = {n}): {camera_words}; " + "; ".join(words),
        primitives=prims,
        camera=camera,
        base_size=(400, 400),
    )
