"""Scene building blocks: primitives with time-dependent poses and procedural textures.

The ray casting itself (nearest hit of spheres, boxes, thin quads and wing-shaped quads, texture
lookup, Lambert shading) runs in Rust (`evsplat._core.SceneRenderer`, crates/sim/src/render.rs);
it is independent of the splatting rasterizer on purpose, so ground truth cannot share its bugs.
Here the scenes say what is where: shapes, sizes, textures and poses as functions of time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

Pose = Callable[[float], np.ndarray]  # time in seconds -> object-to-world 4x4
Texture = tuple[str, list[float]]  # (name, flat parameters) understood by the Rust renderer
Rgb = Sequence[float]


def rot(axis: str, angle: float) -> np.ndarray:
    """4x4 rotation about a coordinate axis by `angle` radians."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def trans(x: float, y: float, z: float) -> np.ndarray:
    """4x4 translation."""
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def static(m: np.ndarray) -> Pose:
    """A pose that does not change with time."""
    return lambda _t: m


@dataclass
class Primitive:
    """A shape in its object frame: 'sphere' (size (r,)), 'box' (half extents (a, b, c)),
    'quad' (plane z = 0, half sizes (a, b)) or 'wing' (a quad cut to butterfly-wing lobes,
    size (a, b, side) with side = +1 right wing, -1 left wing). Moving primitives with the same
    `group` are parts of one object (the first listed is its root, whose pose places it); a
    moving primitive without a group is an object of its own."""

    kind: str
    size: tuple[float, ...]
    pose: Pose
    texture: Texture
    moving: bool
    group: str | None = None

    def radius(self) -> float:
        """Radius of a sphere about the primitive's origin that holds it (a sphere's radius, a
        box's or quad's half diagonal)."""
        if self.kind == "sphere":
            return float(self.size[0])
        return float(np.linalg.norm(self.size[: 3 if self.kind == "box" else 2]))

    def spec(self) -> tuple[str, list[float], str, list[float], bool]:
        """The tuple `_core.SceneRenderer` takes."""
        name, params = self.texture
        return (
            self.kind,
            [float(v) for v in self.size],
            name,
            [float(v) for v in params],
            self.moving,
        )


def one_object(name: str, parts: Sequence[Primitive]) -> list[Primitive]:
    """The moving `parts` labelled as the one object `name` (the first is its root)."""
    return [replace(p, group=name) for p in parts]


def _flat(colours: Sequence[Rgb]) -> list[float]:
    return [float(c) for rgb in colours for c in rgb]


def solid(colour: Rgb) -> Texture:
    """One colour (linear RGB)."""
    return "solid", list(colour)


def checker(
    cells_u: float, cells_v: float, a: Rgb, b: Rgb, axes=(0, 1), scale=(1.0, 1.0)
) -> Texture:
    """Checkerboard: cell index floor(p[axis] / scale * cells) along two object-frame axes."""
    return "checker", [cells_u, cells_v, *scale, *axes, *a, *b]


def wall(palette: Sequence[Rgb], cell: float, seed: int) -> Texture:
    """Tiles of `cell` metres in pseudo-random palette colours with dark grout; every third tile
    carries diagonal stripes, so edges appear in all orientations."""
    return "wall", [cell, seed, *_flat(palette)]


def sphere_segments(n_lon: int, n_lat: int, colours: Sequence[Rgb]) -> Texture:
    """Beach-ball segments around the object z axis, alternate latitude bands darkened."""
    return "segments", [n_lon, n_lat, *_flat(colours)]


def wing_pattern(half: tuple[float, float], side: float) -> Texture:
    """Monarch-like wing: orange with black radial veins, black border with white spots."""
    return "wing", [half[0], half[1], side]


def clock_face(half: tuple[float, float]) -> Texture:
    """Red clock case; on its -z face a white dial with 12 ticks and a brass rim."""
    return "clock", list(half)


def feathers() -> Texture:
    """Yellow toy body with darker feather patches (a lon/lat checker)."""
    return "feathers", []


def noise(seed: int, freq: float, octaves: int, base: Rgb, amp: Rgb) -> Texture:
    """Dense multi-colour value noise: each channel is base ± amp times its own smooth random
    field (hashed lattice values every 1/`freq` metres in the object frame, `octaves` finer
    octaves at 2x the frequency and half the weight, clamped to [0, 1]); fixed by `seed`."""
    return "noise", [seed, freq, octaves, *base, *amp]


@dataclass
class Blob:
    """A round Gaussian blob of `colour` at (x, y) in the object frame, width `sigma` metres."""

    x: float
    y: float
    sigma: float
    colour: Rgb


def colour_blobs(base: Rgb, spots: Sequence[Blob]) -> Texture:
    """Broad smooth colour blobs over `base` in the object x-y plane: each blob in turn blends
    towards its colour by exp(-r² / 2σ²), so there are no edges anywhere."""
    return "blobs", [*base, *(v for b in spots for v in (b.x, b.y, b.sigma, *b.colour))]
