"""Pose files: TUM text (`t tx ty tz qx qy qz qw`, camera-to-world, t in seconds) and a
`transforms.json` style file (`{"frames": [{"time_us": int, "transform_matrix": 4x4}, ...]}`)."""

from __future__ import annotations

import json
import os
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from evsplat.data.atomic import write_text_atomic
from evsplat.data.trajectory import validate_poses
from evsplat.errors import EvsplatError

# A stored quaternion may be off unit length by rounding; more than this is a broken file.
QUAT_NORM_TOL = 1e-3


def rotation_entries(w, x, y, z) -> list:
    """The nine entries, row by row, of the rotation matrix of the unit quaternion (w, x, y, z),
    given as numpy arrays or torch tensors alike (the one place the formula is written)."""
    return [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip


def quat_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) [..., 4] -> rotation matrices [..., 3, 3] (float64)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    return np.stack(rotation_entries(*np.moveaxis(q, -1, 0)), -1).reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] -> unit quaternions (w, x, y, z) [..., 4] with w >= 0.

    Shepperd's method: take the largest of the four squared components to divide by."""
    r = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    sq = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    k = np.argmax(sq, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(sq, k[..., None], -1)[..., 0], 1e-300)) * 2  # 4|q_k|
    d21, d02, d10 = (
        r[..., 2, 1] - r[..., 1, 2],
        r[..., 0, 2] - r[..., 2, 0],
        r[..., 1, 0] - r[..., 0, 1],
    )
    a01, a02, a12 = (
        r[..., 0, 1] + r[..., 1, 0],
        r[..., 0, 2] + r[..., 2, 0],
        r[..., 1, 2] + r[..., 2, 1],
    )
    cands = np.stack(
        [
            np.stack([s / 4, d21 / s, d02 / s, d10 / s], -1),
            np.stack([d21 / s, s / 4, a01 / s, a02 / s], -1),
            np.stack([d02 / s, a01 / s, s / 4, a12 / s], -1),
            np.stack([d10 / s, a02 / s, a12 / s, s / 4], -1),
        ],
        -2,
    )
    q = np.take_along_axis(cands, k[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _seconds_to_us(token: str) -> int:
    """Parse decimal seconds exactly (no float rounding) to integer µs."""
    return int((Decimal(token) * 1_000_000).to_integral_value())


def _us_to_seconds(t: int) -> str:
    sign = "-" if t < 0 else ""
    s, us = divmod(abs(int(t)), 1_000_000)
    return f"{sign}{s}.{us:06d}"


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory: (times_us int64[N], c2w float64[N,4,4]). Lines starting with '#'
    and blank lines are skipped; errors name the line."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise EvsplatError(f"{path}: cannot read pose file ({e.strerror})") from None
    times, poses = [], []
    for n, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) != 8:
            raise EvsplatError(
                f"{path}:{n}: expected 8 values 't tx ty tz qx qy qz qw', got {len(tok)}"
            )
        try:
            t = _seconds_to_us(tok[0])
            tx, ty, tz, qx, qy, qz, qw = (float(v) for v in tok[1:])
        except (ValueError, InvalidOperation):
            raise EvsplatError(f"{path}:{n}: not a number in '{line}'") from None
        q = np.array([qw, qx, qy, qz])
        norm = np.linalg.norm(q)
        if not np.all(np.isfinite(q)) or not np.isfinite([tx, ty, tz]).all():
            raise EvsplatError(f"{path}:{n}: NaN/inf in pose '{line}'; fix or remove that line")
        if abs(norm - 1) > QUAT_NORM_TOL:
            raise EvsplatError(
                f"{path}:{n}: quaternion norm {norm:.6f} is not 1; "
                "store unit quaternions qx qy qz qw"
            )
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(q / norm)
        m[:3, 3] = (tx, ty, tz)
        times.append(t)
        poses.append(m)
    if not times:
        raise EvsplatError(
            f"{path}: no poses found (TUM format: 't tx ty tz qx qy qz qw' per line)"
        )
    return validate_poses(np.array(times, dtype=np.int64), np.stack(poses), str(path))


def write_tum(path: str | os.PathLike, times_us: np.ndarray, c2w: np.ndarray) -> None:
    """Write camera-to-world poses as a TUM file (times as exact decimal seconds), atomically."""
    t, m = validate_poses(times_us, c2w, str(path))
    q = matrix_to_quat(m[:, :3, :3])
    rows = ["# timestamp[s] tx ty tz qx qy qz qw (camera-to-world)"]
    for ti, mi, qi in zip(t, m, q):
        w, x, y, z = qi
        tx, ty, tz = mi[:3, 3]
        rows.append(
            f"{_us_to_seconds(ti)} " + " ".join(f"{v:.17g}" for v in (tx, ty, tz, x, y, z, w))
        )
    write_text_atomic(path, "\n".join(rows) + "\n")


def read_transforms_json(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read (times_us int64[N], c2w float64[N,4,4]) from a transforms.json style file:
    `{"frames": [{"time_us": int, "transform_matrix": 4x4}, ...]}`."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise EvsplatError(f"{path}: cannot read ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise EvsplatError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list) or not frames:
        raise EvsplatError(f"{path}: expected a non-empty 'frames' list")
    times, poses = [], []
    for i, f in enumerate(frames):
        try:
            t = f["time_us"]
            m = np.array(f["transform_matrix"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise EvsplatError(
                f"{path}: frame {i} needs 'time_us' (int) and 'transform_matrix' (4x4 numbers)"
            ) from None
        if not isinstance(t, int) or m.shape != (4, 4):
            raise EvsplatError(
                f"{path}: frame {i}: time_us must be an integer and transform_matrix 4x4"
            )
        times.append(t)
        poses.append(m)
    return validate_poses(np.array(times, dtype=np.int64), np.stack(poses), str(path))


def write_transforms_json(
    path: str | os.PathLike,
    times_us: np.ndarray,
    c2w: np.ndarray,
    K: np.ndarray | None = None,
    width: int | None = None,
    height: int | None = None,
) -> None:
    """Write poses (and optionally intrinsics and image size) as transforms.json, atomically."""
    t, m = validate_poses(times_us, c2w, str(path))
    doc: dict = {}
    if K is not None:
        k = np.asarray(K, dtype=np.float64)
        doc.update(fl_x=k[0, 0], fl_y=k[1, 1], cx=k[0, 2], cy=k[1, 2], K=k.tolist())
    if width is not None:
        doc["w"] = int(width)
    if height is not None:
        doc["h"] = int(height)
    doc["frames"] = [{"time_us": int(ti), "transform_matrix": mi.tolist()} for ti, mi in zip(t, m)]
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


#: meta.json's key and value for a camera that never moves: the folder then needs no
#: poses.txt, and the camera-to-world pose is the identity over the data's whole time range.
CAMERA_KEY, STATIC_CAMERA = "camera", "static"


def is_static_camera(meta: dict) -> bool:
    """Whether a dataset's meta.json says its camera stands still."""
    return meta.get(CAMERA_KEY) == STATIC_CAMERA


def static_poses(t_start_us: int, t_end_us: int) -> tuple[np.ndarray, np.ndarray]:
    """A still camera's poses: the identity at both ends of [t_start_us, t_end_us] (two
    samples, the fewest a trajectory is fitted to), as (times_us int64[2], c2w float64[2,4,4])."""
    return np.array([t_start_us, t_end_us], dtype=np.int64), np.stack([np.eye(4), np.eye(4)])


def measured_poses(root: str | os.PathLike, meta: dict) -> tuple[np.ndarray, np.ndarray]:
    """A dataset folder's measured camera-to-world poses: its poses.txt, or a static camera's
    two identity samples over meta.json's time range."""
    if is_static_camera(meta):
        return static_poses(meta["t_start_us"], meta["t_end_us"])
    return read_tum(Path(root) / "poses.txt")
