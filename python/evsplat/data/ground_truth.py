"""A dataset's ground-truth test frames (test/frames.json) and moving objects' paths
(test/track.json), read and checked for ``evsplat.data.dataset`` (docs/dataset.md).

Since generator version 4 every moving object has, per test frame, its own mask (the pixels that
see it first) and centre (``objects``), and in track.json its dense path and radius. Older
datasets describe one tracked object (``object_centre``, track.json's top level): they read as
one object whose mask is the moving-object mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evsplat.data.trajectory import validate_poses

if TYPE_CHECKING:
    from evsplat.data.dataset import _Checker

SINGLE_OBJECT = "object"  # the name of a dataset's one tracked object before version 4


@dataclass
class FrameObject:
    """One moving object in a test frame."""

    name: str
    centre: np.ndarray  # [3] world position (metres)
    mask_path: Path | None  # the pixels that see this object first (occlusion respected)


@dataclass
class TestFrame:
    """A ground-truth view at an intermediate time (mask marks moving-object pixels)."""

    time_us: int
    c2w: np.ndarray
    rgb_path: Path
    depth_path: Path
    mask_path: Path | None
    object_centre: np.ndarray | None = None  # [3] world position of the (first) tracked object
    objects: list[FrameObject] = field(default_factory=list)  # every moving object


@dataclass
class ObjectTrack:
    """A moving object's centre over the sequence (test/track.json)."""

    times_us: np.ndarray  # [T] int64, increasing
    centres: np.ndarray  # [T,3] float64 world positions (metres)
    radius: float | None  # bounds the object around its centre (metres), if known
    name: str = SINGLE_OBJECT


def read_test_frames(
    c: _Checker, size: tuple[int, int] | None, t0: int | None, t1: int | None
) -> list[TestFrame]:
    """test/frames.json's frames (none without the file); problems go to ``c``."""
    from evsplat.data.images import read_exr, read_png

    path = c.root / "test" / "frames.json"
    if not path.exists():
        return []
    doc = c.json("test/frames.json")
    if not isinstance(doc, list):
        if doc is not None:
            c.fail(f"{path}: expected a list of frames")
        return []
    frames = []
    for i, f in enumerate(doc):
        try:
            t = f["time_us"]
            m = np.array(f["c2w"], dtype=np.float64)
            rgb, depth, mask = f["rgb"], f["depth"], f.get("mask")
        except (KeyError, TypeError, ValueError):
            c.fail(f"{path}: frame {i} needs 'time_us', 'c2w' (4x4), 'rgb' and 'depth'")
            continue
        if not isinstance(t, int) or isinstance(t, bool):
            c.fail(f"{path}: frame {i} time_us must be an integer (µs), got {t!r}")
            continue
        # One pose: validated as a two-sample trajectory that stands still.
        still = (np.array([t, t + 1]), np.stack([m, m]), f"{path} frame {i}")
        if c.attempt(validate_poses, *still) is None:
            continue
        if t0 is not None and not (t0 <= t <= t1):
            c.fail(f"{path}: frame {i} time {t} µs is outside [{t0}, {t1}] µs")
        where = f"{path}: frame {i}"
        objects = _frame_objects(c, f.get("objects"), where)
        if objects is None:
            continue
        paths = [c.root / "test" / p for p in [rgb, depth] + ([mask] if mask else [])]
        paths += [o.mask_path for o in objects]
        missing = [p for p in paths if not p.is_file()]
        if missing:
            c.fail(f"{missing[0]}: missing (listed in {path} frame {i})")
            continue
        if size is not None:
            for p, read in zip(paths, (read_png, read_exr) + (read_png,) * (len(paths) - 2)):
                img = c.attempt(read, p)
                if img is not None and img.shape[:2] != (size[1], size[0]):
                    c.fail(
                        f"{p}: image is {img.shape[1]}x{img.shape[0]} "
                        f"but the sensor is {size[0]}x{size[1]}"
                    )
        mask_path = paths[2] if mask else None
        centre = _centre(c, f.get("object_centre"), f"{where} object_centre")
        if not objects and centre is not None:
            objects = [FrameObject(SINGLE_OBJECT, centre, mask_path)]
        frames.append(TestFrame(int(t), m, paths[0], paths[1], mask_path, centre, objects))
    _same_objects(c, path, [[o.name for o in f.objects] for f in frames])
    return frames


def _frame_objects(c: _Checker, value, where: str) -> list[FrameObject] | None:
    """A frame's ``objects`` ([] when absent), or None after reporting a malformed entry."""
    if value is None:
        return []
    out = []
    for j, o in enumerate(value if isinstance(value, list) else [None]):
        name, mask, centre = (
            (o.get("name"), o.get("mask"), o.get("centre")) if isinstance(o, dict) else (None,) * 3
        )
        if not (isinstance(name, str) and name and isinstance(mask, str) and mask and centre):
            c.fail(
                f"{where} objects[{j}] needs 'name', 'centre' ([x, y, z]) and 'mask' (a file in "
                "test/); regenerate the dataset with evsplat simulate"
            )
            return None
        point = _centre(c, centre, f"{where} objects[{j}] centre")
        if point is None:
            return None
        out.append(FrameObject(name, point, c.root / "test" / mask))
    return out


def _same_objects(c: _Checker, path: Path, names: list[list[str]]) -> None:
    """Every frame must list the same objects in the same order (evaluation follows each)."""
    for i, got in enumerate(names):
        if got != names[0]:
            c.fail(
                f"{path}: frame {i} lists objects {got} but frame 0 lists {names[0]}; every "
                "frame needs the same objects in the same order"
            )
            return


def _centre(c: _Checker, value, where: str) -> np.ndarray | None:
    """An optional world point: None when absent, else 3 finite numbers (a problem otherwise)."""
    if value is None:
        return None
    try:
        p = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        p = np.zeros(0)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        c.fail(f"{where} must be [x, y, z] (finite metres), got {value!r}")
        return None
    return p


def read_tracks(c: _Checker) -> list[ObjectTrack]:
    """test/track.json's paths, one per moving object (the top level alone before version 4;
    none without the file); problems go to ``c``."""
    path = c.root / "test" / "track.json"
    if not path.exists():
        return []
    doc = c.json("test/track.json")
    if doc is None:
        return []
    try:
        times = np.array(doc["times_us"], dtype=np.int64)
        entries = doc.get("objects") or [doc | {"name": SINGLE_OBJECT}]
        tracks = [
            _track(e["name"], times, np.array(e["centres"], dtype=np.float64), e.get("radius"))
            for e in entries
        ]
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError):
        c.fail(
            f"{path}: needs 'times_us' (integers), 'centres' ([x, y, z] each) and 'radius', "
            "and for each of its 'objects' a 'name', 'centres' and 'radius'"
        )
        return []
    if any(t is None for t in tracks):
        c.fail(
            f"{path}: needs increasing 'times_us', one finite [x, y, z] in 'centres' per time "
            "and a positive 'radius' or null (for each object)"
        )
        return []
    return tracks


def _track(name, times: np.ndarray, centres: np.ndarray, radius) -> ObjectTrack | None:
    """One object's path, or None when its values are malformed."""
    radius_ok = radius is None or (
        isinstance(radius, (int, float)) and not isinstance(radius, bool) and radius > 0
    )
    if (
        not isinstance(name, str)
        or times.ndim != 1
        or centres.shape != (len(times), 3)
        or not np.all(np.isfinite(centres))
        or np.any(np.diff(times) <= 0)
        or not radius_ok
    ):
        return None
    return ObjectTrack(times, centres, None if radius is None else float(radius), name)
