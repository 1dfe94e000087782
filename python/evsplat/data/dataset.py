"""The dataset folder: events, poses, intrinsics, sensor metadata and ground-truth test frames.

Layout (docs/dataset.md describes every field):
    events.h5            events (x, y, t µs, p) with their millisecond index, written by
                         evsplat.data.event_writer and read by time window (event_store)
    poses.txt            measured camera-to-world poses, TUM format (sparse, e.g. 100 Hz);
                         none for a static camera (meta.json "camera": "static")
    poses_gt.txt         optional dense ground-truth poses, TUM format
    intrinsics.json      {"K": 3x3, "width", "height", "distortion": null or a lens model
                         (evsplat.data.distortion: radtan / equidistant, OpenCV order)}
    meta.json            sensor and scene metadata (c_pos, c_neg, bayer, t_start_us, t_end_us, ...)
    test/frames.json     optional [{"time_us", "c2w", "rgb", "depth", "mask", "object_centre",
                         "objects": [{"name", "centre", "mask"}]}], files in test/
                         (evsplat.data.ground_truth reads them)
    test/track.json      optional dense paths of the moving objects (for path plots)
    depth_prior/         optional precomputed depth priors
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evsplat.data.distortion import LensDistortion, Rectifier
from evsplat.data.event_index import MS
from evsplat.data.event_store import EventStore, open_store, verify_store
from evsplat.data.ground_truth import ObjectTrack, TestFrame, read_test_frames, read_tracks
from evsplat.data.poses import CAMERA_KEY, STATIC_CAMERA, is_static_camera, read_tum, static_poses
from evsplat.data.simulator import BAYER_PATTERNS
from evsplat.data.trajectory import Trajectory
from evsplat.errors import EvsplatError

REQUIRED_FILES = ("events.h5", "poses.txt", "intrinsics.json", "meta.json")
POSES = "poses.txt"  # required unless meta.json says the camera is static


@dataclass
class Dataset:
    """Everything training and evaluation need from a dataset folder."""

    root: Path
    events: EventStore  # read by time window; on the ideal pinhole grid when distorted
    trajectory: Trajectory  # fitted to the sparse measured poses (poses.txt)
    gt_trajectory: Trajectory | None  # dense ground truth (poses_gt.txt), if present
    K: np.ndarray
    width: int
    height: int
    c_pos: float
    c_neg: float
    bayer: str
    t_start_us: int
    t_end_us: int
    test_frames: list[TestFrame]
    meta: dict
    depth_prior_dir: Path | None = None
    distortion: LensDistortion | None = None  # of the raw events; ``events`` are undistorted
    track: ObjectTrack | None = None  # dense ground-truth path of the (first) moving object
    tracks: list[ObjectTrack] = field(default_factory=list)  # every moving object's

    def between(self, t0_us: int, t1_us: int) -> Dataset:
        """The same data restricted to [t0, t1] µs, a part of [t_start_us, t_end_us]: training
        samples its windows there; test frames outside it are left out."""
        start, length = self.t_start_us, (self.t_end_us - self.t_start_us) / 1e6
        if not start <= t0_us < t1_us <= self.t_end_us:
            raise EvsplatError(
                f"{self.root}: time range {(t0_us - start) / 1e6:g}:{(t1_us - start) / 1e6:g} s "
                f"is not inside the recording, 0:{length:g} s from its start (meta.json "
                f"t_start_us); pass --time-range START:END with 0 <= START < END <= {length:g}"
            )
        frames = [f for f in self.test_frames if t0_us <= f.time_us <= t1_us]
        return replace(self, t_start_us=t0_us, t_end_us=t1_us, test_frames=frames)


@dataclass
class _Checker:
    """Collects problems, one line each; values parsed so far are kept for the dataset."""

    root: Path
    problems: list[str] = field(default_factory=list)

    def fail(self, msg: str) -> None:
        self.problems.append(msg)

    def json(self, name: str) -> dict | None:
        path = self.root / name
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except OSError as e:
            self.fail(f"{path}: cannot read ({e.strerror})")
            return None
        except json.JSONDecodeError as e:
            self.fail(f"{path}: not valid JSON ({e.msg} at line {e.lineno}); fix or regenerate it")
            return None
        if not isinstance(doc, (dict, list)):
            self.fail(f"{path}: expected a JSON object")
            return None
        return doc

    def attempt(self, fn, *args):
        try:
            return fn(*args)
        except EvsplatError as e:
            self.fail(str(e))
            return None


def _positive_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v > 0


def _intrinsics(c: _Checker) -> tuple[np.ndarray, int, int, LensDistortion | None] | None:
    doc = c.json("intrinsics.json")
    path = c.root / "intrinsics.json"
    if not isinstance(doc, dict):
        return None
    try:
        K = np.array(doc["K"], dtype=np.float64)
        w, h = doc["width"], doc["height"]
    except (KeyError, TypeError, ValueError):
        c.fail(f"{path}: needs 'K' (3x3 numbers), 'width' and 'height'")
        return None
    ok = True
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        c.fail(f"{path}: K must be a finite 3x3 matrix with positive focal lengths")
        ok = False
    if not (_positive_int(w) and _positive_int(h)):
        c.fail(f"{path}: width and height must be positive integers, got {w!r} and {h!r}")
        ok = False
    dist = None
    if doc.get("distortion") is not None:
        dist = c.attempt(LensDistortion.from_json, doc["distortion"], str(path))
        ok = ok and dist is not None
    return (K, w, h, dist) if ok else None


def _meta(c: _Checker) -> dict | None:
    doc = c.json("meta.json")
    path = c.root / "meta.json"
    if not isinstance(doc, dict):
        return None
    ok = True
    for key in ("c_pos", "c_neg"):
        v = doc.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not (np.isfinite(v) and v > 0):
            c.fail(f"{path}: '{key}' must be a positive number (contrast threshold), got {v!r}")
            ok = False
    if doc.get("bayer") not in BAYER_PATTERNS:
        c.fail(f"{path}: 'bayer' must be one of {BAYER_PATTERNS}, got {doc.get('bayer')!r}")
        ok = False
    t0, t1 = doc.get("t_start_us"), doc.get("t_end_us")
    if not (isinstance(t0, int) and isinstance(t1, int) and t0 < t1):
        c.fail(
            f"{path}: 't_start_us' and 't_end_us' must be integers with start < end, "
            f"got {t0!r}, {t1!r}"
        )
        ok = False
    if doc.get(CAMERA_KEY, STATIC_CAMERA) != STATIC_CAMERA:
        c.fail(
            f"{path}: '{CAMERA_KEY}' is {doc[CAMERA_KEY]!r}; the only value is "
            f"{STATIC_CAMERA!r} (a camera that never moves: no poses.txt); remove it otherwise"
        )
        ok = False
    for key in ("width", "height"):
        if not _positive_int(doc.get(key)):
            c.fail(
                f"{path}: '{key}' (sensor size) must be a positive integer, got {doc.get(key)!r}"
            )
            ok = False
    return doc if ok else None


def _camera(c: _Checker, meta: dict | None, t0: int | None, t1: int | None) -> Trajectory | None:
    """The training trajectory: fitted to poses.txt, or a static camera's constant identity."""
    path = c.root / POSES
    if meta is not None and is_static_camera(meta):
        if path.exists():
            c.fail(
                f"{path}: meta.json says the camera is static ('{CAMERA_KEY}': "
                f"'{STATIC_CAMERA}') but poses are given; remove one of them"
            )
            return None
        return c.attempt(Trajectory.fit, *static_poses(t0, t1), None, "static camera (meta.json)")
    if not path.is_file():
        what = "is a folder, not a file" if path.exists() else "missing"
        c.fail(
            f"{path}: {what} (a dataset folder needs {', '.join(REQUIRED_FILES)}; a static "
            f'camera needs no poses: "{CAMERA_KEY}": "{STATIC_CAMERA}" in meta.json)'
        )
        return None
    return _trajectory(c, POSES, t0, t1)


def _trajectory(c: _Checker, name: str, t0: int | None, t1: int | None) -> Trajectory | None:
    path = c.root / name
    poses = c.attempt(read_tum, path)
    if poses is None:
        return None
    traj = c.attempt(Trajectory.fit, poses[0], poses[1], None, str(path))
    if traj is not None and t0 is not None and (traj.t_min_us > t0 or traj.t_max_us < t1):
        c.fail(
            f"{path}: poses cover [{traj.t_min_us}, {traj.t_max_us}] µs but the data spans "
            f"[{t0}, {t1}] µs (meta.json); add poses or shrink t_start_us/t_end_us"
        )
    return traj


def _events(
    c: _Checker,
    path: Path,
    size: tuple[int, int] | None,
    intr: tuple[np.ndarray, int, int, LensDistortion | None] | None,
    verify: bool,
) -> EventStore | None:
    """The event store of ``path`` (sensor size from meta.json when the file has none). A
    file without an index gets one; loading caches it beside the file and validates windows
    as they are read, while ``verify`` checks every event and the index in one streaming
    pass and writes nothing."""
    if not path.is_file():
        return None
    w, h = size or (None, None)
    rectify = None
    if intr and intr[3] is not None and size and not c.problems:
        # Undistorted as read; everything downstream sees the ideal pinhole grid.
        rectify = c.attempt(Rectifier, intr[3], intr[0], w, h, str(path))
    if verify:
        problems, store = verify_store(path, w, h, rectify)
        for problem in problems:
            c.fail(problem)
    else:
        store = c.attempt(open_store, path, w, h, rectify)
    if store is not None and size is not None and (store.width, store.height) != size:
        c.fail(
            f"{path}: sensor size {store.width}x{store.height} differs from meta.json "
            f"{size[0]}x{size[1]}; the events belong to another sensor or the metadata is wrong"
        )
    return store


#: How far into the data's time range (a share of it) its events may start, or before its end
#: stop, e.g. a quiet scene's first event (the simulated tiny scenes': 0.04-0.05%).
COVERAGE_SLACK = 0.01


def _coverage(c: _Checker, store: EventStore, t0: int, t1: int) -> None:
    """The recording must span meta.json's time range: training draws windows all over it, and
    one past the recording's end would teach the model that nothing moved there. Its span is
    the one the file says it recorded (``recorded_us``: a quiet start has no events yet was
    recorded), else its first and last events'."""
    if store.count == 0:
        return
    slack = max(MS, round(COVERAGE_SLACK * (t1 - t0)))
    first, last = store.recorded_us or (store.t_first_us, store.t_last_us)
    if first <= t0 + slack and last >= t1 - slack:
        return
    c.fail(
        f"{store.path}: the recording spans [{first}, {last}] µs, shorter than the data's time "
        f"range [{t0}, {t1}] µs (meta.json t_start_us/t_end_us, which the poses cover); set "
        f"them inside the recording in {c.root / 'meta.json'}, or re-convert the full recording"
    )


def _inspect(root: str | os.PathLike, verify: bool = False) -> tuple[list[str], Dataset | None]:
    root = Path(root)
    c = _Checker(root)
    if not root.is_dir():
        return [f"{root}: not a directory (expected a dataset folder, see docs/dataset.md)"], None
    for name in REQUIRED_FILES:
        if name != POSES and not (root / name).is_file():
            what = "is a folder, not a file" if (root / name).exists() else "missing"
            c.fail(f"{root / name}: {what} (a dataset folder needs {', '.join(REQUIRED_FILES)})")
    intr = _intrinsics(c) if (root / "intrinsics.json").is_file() else None
    meta = _meta(c) if (root / "meta.json").is_file() else None
    sizes_disagree = bool(intr and meta and (meta["width"], meta["height"]) != (intr[1], intr[2]))
    if sizes_disagree:
        c.fail(
            f"{root / 'meta.json'}: sensor size {meta['width']}x{meta['height']} differs from "
            f"intrinsics.json {intr[1]}x{intr[2]}; make them agree"
        )
    size = (meta["width"], meta["height"]) if meta else (intr[1], intr[2]) if intr else None
    t0, t1 = (meta["t_start_us"], meta["t_end_us"]) if meta else (None, None)
    events = _events(c, root / "events.h5", size, intr, verify)
    if events is not None and meta is not None:
        _coverage(c, events, t0, t1)
    traj = _camera(c, meta, t0, t1)
    gt = _trajectory(c, "poses_gt.txt", t0, t1) if (root / "poses_gt.txt").is_file() else None
    # With two different sensor sizes on record, image sizes cannot be judged (one line above).
    frames = read_test_frames(c, None if sizes_disagree else size, t0, t1)
    tracks = read_tracks(c)
    if c.problems:
        return c.problems, None
    prior = root / "depth_prior"
    return [], Dataset(
        root=root,
        events=events,
        trajectory=traj,
        gt_trajectory=gt,
        K=intr[0],
        width=size[0],
        height=size[1],
        c_pos=float(meta["c_pos"]),
        c_neg=float(meta["c_neg"]),
        bayer=meta["bayer"],
        t_start_us=t0,
        t_end_us=t1,
        test_frames=frames,
        meta=meta,
        depth_prior_dir=prior if prior.is_dir() else None,
        distortion=intr[3],
        track=tracks[0] if tracks else None,
        tracks=tracks,
    )


def verify_dataset(path: str | os.PathLike) -> tuple[list[str], Dataset | None]:
    """All problems with the dataset folder, one line each, from a check of every event and
    of the millisecond index against the timestamps; and the dataset when there are none."""
    return _inspect(path, verify=True)


def check_dataset(path: str | os.PathLike) -> list[str]:
    """All problems with the dataset folder, one line each (empty list = usable)."""
    return verify_dataset(path)[0]


def load_dataset(path: str | os.PathLike) -> Dataset:
    """Load and validate a dataset folder; raises EvsplatError with the first problem."""
    problems, ds = _inspect(path)
    if problems:
        more = (
            f" (and {len(problems) - 1} more; run `evsplat check {path}`)"
            if len(problems) > 1
            else ""
        )
        raise EvsplatError(problems[0] + more)
    return ds
