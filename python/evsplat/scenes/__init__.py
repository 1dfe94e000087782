"""Built-in synthetic dynamic scenes with ground truth (RGB, depth, moving-object mask, poses,
and per moving object its mask, centre and radius), rendered by an analytic ray caster that
shares no code with the splatting rasterizer."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from evsplat import _core
from evsplat.errors import EvsplatError
from evsplat.scenes import drawn, held_out, library, multi_object
from evsplat.scenes.geometry import Primitive

SCENES = library.SCENES | multi_object.SCENES | held_out.SCENES

FULL_DURATION_US = 1_000_000
TINY_DURATION_US = 600_000
TINY_SIZE = 96  # longer side of the tiny variant
# Render rate at speed 1 for a 400-pixel-high image (the paper renders at 1000 fps); it scales
# with resolution so per-frame motion in pixels stays the same at every size.
BASE_FPS = 1000.0
BASE_HEIGHT = 400
# Rays per pixel side: a pixel's colour is the mean of 3x3 rays over its area, as a sensor's
# pixel integrates the light on it (Blender, which renders the paper's scenes, filters over the
# pixel too). One ray per pixel drew every edge as a staircase that crawls as things move: 17%
# (ball) to 37% (duck) of the tiny scenes' events came from that crawl, and a model with smooth
# edges lost ~1.7 dB on the ball's mask against aliased ground truth
# (docs/experiments/training.md, "The simulator's pixels integrate their area").
PIXEL_SAMPLES = 3
# Focal length in units of the image height (a ~51° vertical field of view).
FOCAL_PER_HEIGHT = 1.05
# The tiny variant zooms in so the moving object covers a good part of its few pixels.
TINY_ZOOM = 1.6
RADIUS_SAMPLES = 11  # times over the sequence at which an object's parts are bounded


@dataclass(frozen=True)
class SceneObject:
    """One moving object: its name and its primitives' indices (the first is its root)."""

    name: str
    parts: tuple[int, ...]


def scene_objects(primitives: list[Primitive]) -> list[SceneObject]:
    """The moving objects in order of their first primitive: primitives sharing a ``group``
    form one object; a moving primitive without one is an object named ``object<k>``."""
    parts: dict[str, list[int]] = {}
    for i, p in enumerate(primitives):
        if p.moving:
            parts.setdefault(p.group or f"object{len(parts)}", []).append(i)
    return [SceneObject(name, tuple(idx)) for name, idx in parts.items()]


@dataclass
class Scene:
    """A dynamic scene: camera pose and rendered ground truth at any time (µs)."""

    name: str
    description: str
    width: int
    height: int
    K: np.ndarray
    duration_us: int
    fps: float  # render rate at speed 1
    primitives: list[Primitive]
    camera: Callable[[float], np.ndarray]  # seconds -> camera-to-world 4x4
    samples: int = PIXEL_SAMPLES  # rays per pixel side; a pixel's colour is their mean
    objects: list[SceneObject] = field(init=False)
    _renderer: _core.SceneRenderer = field(init=False, repr=False)
    _object_renderers: list[_core.SceneRenderer] | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.objects = scene_objects(self.primitives)
        self._renderer = self._make_renderer(None, self.samples)
        self._object_renderers = None

    def _make_renderer(self, only: SceneObject | None, samples: int) -> _core.SceneRenderer:
        """A ray caster whose moving mask marks every moving primitive, or ``only``'s."""
        k = (self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2])
        specs = [p.spec() for p in self.primitives]
        if only is not None:
            specs = [(*s[:4], i in only.parts) for i, s in enumerate(specs)]
        return _core.SceneRenderer(specs, self.width, self.height, k, samples)

    def c2w(self, t_us: int | float | np.ndarray) -> np.ndarray:
        """Camera-to-world pose(s) float64[..., 4, 4] at `t_us`."""
        t = np.asarray(t_us, dtype=np.float64)
        out = np.stack([self.camera(float(s) * 1e-6) for s in t.reshape(-1)])
        return out.reshape(*t.shape, 4, 4)

    def object_pose(self, t_us: int | float, k: int = 0) -> np.ndarray | None:
        """Pose float64[4,4] (object to world) of moving object `k` at `t_us`: its root
        primitive's; None when the scene has no such object."""
        if k >= len(self.objects):
            return None
        root = self.primitives[self.objects[k].parts[0]]
        return np.asarray(root.pose(float(t_us) * 1e-6), dtype=np.float64)

    def object_centre(self, t_us: int | float, k: int = 0) -> np.ndarray | None:
        """World position float64[3] (metres) of moving object `k` at `t_us` (its root
        primitive's origin), or None when the scene has no such object."""
        pose = self.object_pose(t_us, k)
        return None if pose is None else pose[:3, 3].copy()

    def object_radius(self, k: int = 0) -> float | None:
        """Radius (metres) of a sphere about object `k`'s centre that holds all its parts at
        every one of ``RADIUS_SAMPLES`` times over the sequence (a part's own bound: a sphere's
        radius, a box's or quad's half diagonal); None when there is no such object."""
        if k >= len(self.objects):
            return None
        reach = 0.0
        for t_us in np.linspace(0, self.duration_us, RADIUS_SAMPLES):
            centre = self.object_centre(t_us, k)
            for i in self.objects[k].parts:
                part = self.primitives[i]
                offset = np.linalg.norm(part.pose(t_us * 1e-6)[:3, 3] - centre)
                reach = max(reach, float(offset) + part.radius())
        return reach

    def render(self, t_us: int | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rgb float32[H,W,3] linear in [0,1], depth float32[H,W] camera z (0 = nothing hit),
        moving-object mask bool[H,W]) at time `t_us`."""
        t_s = float(t_us) * 1e-6
        poses = np.stack([p.pose(t_s) for p in self.primitives]).astype(np.float64)
        return self._renderer.render(np.asarray(self.camera(t_s), np.float64), poses)

    def object_masks(self, t_us: int | float) -> list[np.ndarray]:
        """Per moving object, bool[H,W]: the pixels whose centre ray hits that object first
        (what covers it, hides it); together they are ``render``'s moving mask."""
        if self._object_renderers is None:
            # One ray per pixel: masks are the centre ray's at any sample count.
            self._object_renderers = [self._make_renderer(o, 1) for o in self.objects]
        t_s = float(t_us) * 1e-6
        poses = np.stack([p.pose(t_s) for p in self.primitives]).astype(np.float64)
        c2w = np.asarray(self.camera(t_s), np.float64)
        return [r.render(c2w, poses)[2] for r in self._object_renderers]


def is_scene(name: str) -> bool:
    """Whether ``name`` is a built-in scene or a drawn one (``drawn-N``)."""
    return name in SCENES or drawn.seed_of(name) is not None


def scene_spec(name: str) -> dict:
    """The built-in scene ``name``'s primitives, camera and words, or a drawn one's."""
    if name in SCENES:
        return SCENES[name]()
    n = drawn.seed_of(name)
    if n is None:
        raise EvsplatError(
            f"unknown scene '{name}'; choose one of: {', '.join(SCENES)}, or drawn-N "
            "(N = 0, 1, ...: a scene drawn at random)"
        )
    return drawn.drawn(n)


def scene_names() -> list[str]:
    """Names of the built-in scenes."""
    return list(SCENES)


def scene_descriptions() -> dict[str, str]:
    """One-line description of each built-in scene, by name (nothing is rendered)."""
    return {name: make()["description"] for name, make in SCENES.items()}


def get_scene(
    name: str,
    size: tuple[int, int] | None = None,
    tiny: bool = False,
    samples: int = PIXEL_SAMPLES,
) -> Scene:
    """The built-in scene `name` at its full size (400x400; duck 600x400), at `size` = (W, H),
    or as the tiny variant (longer side 96 px, zoomed in 1.6x, 0.6 s) for tests and the demo;
    each pixel the mean of `samples` x `samples` rays over its area. `name` may be drawn-N, a
    scene drawn at random (``scenes.drawn``)."""
    spec = scene_spec(name)
    top = _core.MAX_PIXEL_SAMPLES
    if (
        isinstance(samples, bool)
        or not isinstance(samples, int)
        or samples not in range(1, top + 1, 2)
    ):
        raise EvsplatError(
            f"--samples {samples!r}: rays per pixel side must be an odd number from 1 to {top} "
            "(1 = one ray through each pixel centre)"
        )
    bw, bh = spec["base_size"]
    if size is not None:
        w, h = (int(v) for v in size)
        if w < 8 or h < 8 or w > 8192 or h > 8192:
            raise EvsplatError(
                f"--size {w}x{h}: width and height must be between 8 and 8192 pixels"
            )
    elif tiny:
        scale = TINY_SIZE / max(bw, bh)
        w, h = round(bw * scale), round(bh * scale)
    else:
        w, h = bw, bh
    f = FOCAL_PER_HEIGHT * h * (TINY_ZOOM if tiny and size is None else 1.0)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], dtype=np.float64)
    return Scene(
        name=name,
        description=spec["description"],
        width=w,
        height=h,
        K=K,
        duration_us=TINY_DURATION_US if tiny else FULL_DURATION_US,
        fps=BASE_FPS * h / BASE_HEIGHT,
        primitives=spec["primitives"],
        camera=spec["camera"],
        samples=samples,
    )
