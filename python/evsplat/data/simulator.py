"""ESIM-style event simulation from log-intensity frames (the hot loop is Rust, crates/sim).

Log intensity is L = log(I + LOG_EPS) with I linear in [0, 1]; LOG_EPS keeps black pixels
finite and sets how much sensor noise-like activity dark regions get (a real sensor's dark
current plays the same role). Every pixel keeps a reference level; when |L - L_ref| reaches its
threshold (C+ up, C- down) an event is emitted at the time the linear interpolation between the
two bracketing frames crosses the level, and the reference moves by one threshold, so a change
spanning several thresholds gives several events. Thresholds are drawn once per pixel from
N(C, sigma_c) (floored at 0.1·C). A colour sensor (bayer="RGGB") sees only its pixel's channel.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from evsplat import _core
from evsplat.data.atomic import write_text_atomic
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError, core_call
from evsplat.intensity import LOG_EPS, LUMA

if TYPE_CHECKING:
    from evsplat.scenes import Scene

BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG", "mono")


def sensor_log_image(img: np.ndarray, bayer: str = "RGGB") -> np.ndarray:
    """L = log(I + LOG_EPS) as the sensor sees it: [H,W,3] for colour (the simulator picks each
    pixel's channel), [H,W] for mono (RGB input is converted with Rec. 709 luma first)."""
    i = np.asarray(img, dtype=np.float32)
    if bayer == "mono" and i.ndim == 3:
        i = i @ LUMA
    return np.log(np.maximum(i, 0) + np.float32(LOG_EPS))


@dataclass(frozen=True)
class SensorConfig:
    """Event sensor parameters; defaults follow ESIM's common settings (C = 0.2, σ = 0.03)."""

    c_pos: float = 0.2
    c_neg: float = 0.2
    sigma_c: float = 0.03
    refractory_us: int = 0
    noise_rate_hz: float = 0.0
    hot_pixels: int = 0
    hot_rate_hz: float = 1000.0
    bayer: str = "RGGB"
    seed: int = 0


def _frames(source) -> Iterator[tuple[int, np.ndarray]]:
    """(t_us, log_frame) pairs from an iterable of pairs or from (times_us, log_frames) arrays."""
    if isinstance(source, tuple) and len(source) == 2 and isinstance(source[0], np.ndarray):
        times, frames = source
        if len(times) != len(frames):
            raise EvsplatError(f"simulate_events: {len(times)} times but {len(frames)} frames")
        return zip((int(t) for t in times), frames)
    return ((int(t), f) for t, f in source)


def simulate_events(
    frames: Iterable[tuple[int, np.ndarray]] | tuple[np.ndarray, np.ndarray],
    c_pos: float = SensorConfig.c_pos,
    c_neg: float = SensorConfig.c_neg,
    sigma_c: float = SensorConfig.sigma_c,
    refractory_us: int = SensorConfig.refractory_us,
    noise_rate_hz: float = SensorConfig.noise_rate_hz,
    hot_pixels: int = SensorConfig.hot_pixels,
    hot_rate_hz: float = SensorConfig.hot_rate_hz,
    bayer: str = SensorConfig.bayer,
    seed: int = SensorConfig.seed,
    source: str = "<simulated>",
) -> EventStream:
    """Events from log-intensity frames at increasing int64 µs times.

    `frames` is an iterable of (t_us, L) or a pair of arrays (times_us [N], L [N,H,W(,3)]);
    L is [H,W,3] for bayer="RGGB" and [H,W] for "mono" (see `sensor_log_image`). The first frame
    sets the reference levels. Same inputs and seed give identical events."""
    if bayer not in BAYER_PATTERNS:
        raise EvsplatError(f"bayer pattern '{bayer}' is not supported; use one of {BAYER_PATTERNS}")
    want_ndim = 2 if bayer == "mono" else 3
    sim = None
    chunks: list[tuple[np.ndarray, ...]] = []
    shape = None
    for t, frame in _frames(frames):
        f = np.ascontiguousarray(frame, dtype=np.float32)
        if f.ndim != want_ndim or (want_ndim == 3 and f.shape[2] != 3):
            raise EvsplatError(
                f"simulate_events: frame at {t} µs has shape {f.shape}; bayer={bayer} needs "
                f"{'[H,W,3]' if want_ndim == 3 else '[H,W]'} log intensities"
            )
        if sim is None:
            shape = f.shape[:2]
            try:
                sim = _core.EventSimulator(
                    shape[1],
                    shape[0],
                    c_pos,
                    c_neg,
                    sigma_c,
                    refractory_us,
                    noise_rate_hz,
                    hot_pixels,
                    hot_rate_hz,
                    bayer,
                    seed,
                )
            except (ValueError, OverflowError) as e:
                raise EvsplatError(f"simulate_events: {e}") from None
        chunks.append(core_call("simulate_events", sim.push, t, f))
    if sim is None:
        raise EvsplatError("simulate_events: no frames given; need at least two")
    x, y, t, p = (np.concatenate([c[k] for c in chunks]) for k in range(4))
    return EventStream.from_arrays(x, y, t, p, width=shape[1], height=shape[0], source=source)


# ----------------------------------------------------------------- dataset generation

# 2: test frames carry the tracked object's centre, test/track.json; 3: pixels integrate their
# area (`samples` rays per side, meta.json's `pixel_samples`); 4: every moving object's mask,
# centre and radius (test frames' `objects`, track.json's `objects`)
GENERATOR_VERSION = 4
MEASURED_POSE_HZ = 100  # "measured" poses, as from a motion-capture system
GT_POSE_HZ = 1000  # dense ground-truth poses
TEST_FRAMES_FULL = 12
TEST_FRAMES_TINY = 6
MAX_SPEED = 64


def _times(duration_us: int, step_us: float) -> np.ndarray:
    n = int(np.floor(duration_us / step_us + 1e-9))
    t = np.round(np.arange(n + 1) * step_us).astype(np.int64)
    return t if t[-1] == duration_us else np.append(t, duration_us)


def _write_track(path: Path, scene: Scene, times_us: np.ndarray) -> None:
    """Every moving object's centre at `times_us` (the dense ground-truth pose times), for path
    plots, and the radius that bounds it around its centre; the first object's also at the top
    level, as datasets with one tracked object have it."""
    objects = [
        {
            "name": obj.name,
            "centres": [scene.object_centre(int(t), k).tolist() for t in times_us],
            "radius": scene.object_radius(k),
        }
        for k, obj in enumerate(scene.objects)
    ]
    doc = {"times_us": [int(t) for t in times_us]} | {
        key: objects[0][key] for key in ("centres", "radius")
    }
    write_text_atomic(path, json.dumps(doc | {"objects": objects}) + "\n")


def _object_entries(scene: Scene, t_us: int, k: int, folder: Path) -> list[dict]:
    """Test frame `k`'s per-object ground truth: name, world centre and the file of its mask
    (written into `folder`: the pixels that see that object first)."""
    from evsplat.data.images import write_png

    entries = []
    for j, (obj, mask) in enumerate(zip(scene.objects, scene.object_masks(t_us))):
        name = f"mask_{k:05d}_object{j}.png"
        write_png(folder / name, mask.astype(np.float32))
        centre = scene.object_centre(t_us, j).tolist()
        entries.append({"name": obj.name, "centre": centre, "mask": name})
    return entries


def simulate_dataset(
    scene_name: str,
    out_dir: str | os.PathLike,
    speed: int = 1,
    size: tuple[int, int] | None = None,
    color: bool = True,
    seed: int = 0,
    tiny: bool = False,
    progress: bool = True,
    samples: int | None = None,
) -> Path:
    """Render a built-in scene, simulate its events and write a dataset folder (docs/dataset.md).

    `speed` K renders K times fewer frames over the same motion (the paper's Table 2 protocol).
    Everything is written to a temporary sibling folder that is renamed to `out_dir` at the end,
    so an interrupted run leaves nothing half-written. Returns `out_dir`."""
    from evsplat.data.event_writer import write_events_h5
    from evsplat.data.images import write_exr, write_png
    from evsplat.data.poses import write_tum
    from evsplat.scenes import PIXEL_SAMPLES, get_scene

    if (
        isinstance(speed, bool)
        or not isinstance(speed, (int, np.integer))
        or not 1 <= speed <= MAX_SPEED
    ):
        raise EvsplatError(
            f"--speed {speed!r}: must be an integer from 1 to {MAX_SPEED} "
            "(1 = every rendered frame)"
        )
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise EvsplatError(
            f"{out}: already exists and is not empty; remove it or choose another --out"
        )
    samples = PIXEL_SAMPLES if samples is None else samples
    scene = get_scene(scene_name, size=size, tiny=tiny, samples=samples)
    if not out.parent.is_dir():
        raise EvsplatError(f"{out.parent}: parent folder does not exist; create it first")
    bayer = "RGGB" if color else "mono"
    cfg = SensorConfig(bayer=bayer, seed=int(seed))
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "test").mkdir(parents=True)
    try:
        frame_times = _times(scene.duration_us, speed * 1e6 / scene.fps)

        def frames() -> Iterator[tuple[int, np.ndarray]]:
            for t in tqdm(
                frame_times, desc=f"simulate {scene.name}", unit="frame", disable=not progress
            ):
                yield int(t), sensor_log_image(scene.render(int(t))[0], bayer)

        events = simulate_events(
            frames(),
            cfg.c_pos,
            cfg.c_neg,
            cfg.sigma_c,
            cfg.refractory_us,
            cfg.noise_rate_hz,
            cfg.hot_pixels,
            cfg.hot_rate_hz,
            bayer,
            cfg.seed,
            source=str(out / "events.h5"),
        )
        # The sensor recorded the whole sequence: a still start makes no events, no cut.
        write_events_h5(tmp / "events.h5", events, recorded_us=(0, scene.duration_us))
        pose_t = _times(scene.duration_us, 1e6 / MEASURED_POSE_HZ)
        write_tum(tmp / "poses.txt", pose_t, scene.c2w(pose_t))
        gt_t = _times(scene.duration_us, 1e6 / GT_POSE_HZ)
        write_tum(tmp / "poses_gt.txt", gt_t, scene.c2w(gt_t))
        intrinsics = {
            "K": scene.K.tolist(),
            "width": scene.width,
            "height": scene.height,
            "distortion": None,
        }
        write_text_atomic(tmp / "intrinsics.json", json.dumps(intrinsics, indent=1) + "\n")
        # Test views halfway between measured poses, spread over the sequence.
        n_test = TEST_FRAMES_TINY if tiny else TEST_FRAMES_FULL
        mids = (pose_t[:-1] + pose_t[1:]) // 2
        test_t = mids[np.round(np.linspace(0, len(mids) - 1, n_test)).astype(int)]
        test = []
        near, far = np.inf, 0.0
        for k, t in enumerate(test_t):
            rgb, depth, mask = scene.render(int(t))
            hit = depth[depth > 0]
            if hit.size:
                near, far = min(near, float(hit.min())), max(far, float(hit.max()))
            names = (f"rgb_{k:05d}.png", f"depth_{k:05d}.exr", f"mask_{k:05d}.png")
            write_png(tmp / "test" / names[0], rgb if color else rgb @ LUMA, bits=16)
            write_exr(tmp / "test" / names[1], depth)
            write_png(tmp / "test" / names[2], mask.astype(np.float32))
            c2w = scene.c2w(int(t)).tolist()
            frame = {
                "time_us": int(t),
                "c2w": c2w,
                "rgb": names[0],
                "depth": names[1],
                "mask": names[2],
            }
            if scene.objects:
                frame["object_centre"] = scene.object_centre(int(t)).tolist()
                frame["objects"] = _object_entries(scene, int(t), k, tmp / "test")
            test.append(frame)
        write_text_atomic(tmp / "test" / "frames.json", json.dumps(test, indent=1) + "\n")
        if scene.objects:
            _write_track(tmp / "test" / "track.json", scene, gt_t)
        meta = {
            "generator": "evsplat simulate",
            "generator_version": GENERATOR_VERSION,
            "pixel_samples": samples,
            "scene": scene.name,
            "description": scene.description,
            "width": scene.width,
            "height": scene.height,
            "c_pos": cfg.c_pos,
            "c_neg": cfg.c_neg,
            "sigma_c": cfg.sigma_c,
            "refractory_us": cfg.refractory_us,
            "noise_rate_hz": cfg.noise_rate_hz,
            "hot_pixels": cfg.hot_pixels,
            "bayer": bayer,
            "log_eps": LOG_EPS,
            "t_start_us": 0,
            "t_end_us": scene.duration_us,
            "speed": int(speed),
            "render_fps": scene.fps / speed,
            "rendered_frames": len(frame_times),
            "num_events": len(events),
            "seed": int(seed),
            "tiny": bool(tiny),
            # Where the scene lies in front of the camera: the trainer's initialisation range.
            "depth_range": [round(0.8 * near, 4), round(1.25 * far, 4)] if far > 0 else None,
            "pose_rate_hz": MEASURED_POSE_HZ,
            "gt_pose_rate_hz": GT_POSE_HZ,
            "rgb_encoding": "linear 16-bit PNG (not sRGB); grey for mono sensors",
        }
        write_text_atomic(tmp / "meta.json", json.dumps(meta, indent=1) + "\n")
        if out.exists():
            out.rmdir()  # empty (checked above)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
