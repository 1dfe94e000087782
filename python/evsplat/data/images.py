"""Image files as float32 numpy arrays: PNG (values in [0, 1]) and single-channel EXR depth.
Encoding/decoding is done by the Rust `image` and `exr` crates; every write is atomic."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evsplat import _core
from evsplat.errors import EvsplatError, core_call


def _image_array(img: np.ndarray, path: Path, what: str) -> np.ndarray:
    a = np.ascontiguousarray(img, dtype=np.float32)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (1, 3)):
        raise EvsplatError(f"{path}: {what} must be [H,W] or [H,W,3], got shape {a.shape}")
    return a[..., 0] if a.ndim == 3 and a.shape[2] == 1 else a


def write_png(path: str | os.PathLike, img: np.ndarray, bits: int = 8) -> None:
    """Write [H,W] grey or [H,W,3] RGB values in [0, 1] (clamped) as an 8- or 16-bit PNG."""
    path = Path(path)
    if bits not in (8, 16):
        raise EvsplatError(f"{path}: PNG bit depth must be 8 or 16, got {bits}")
    core_call(None, _core.write_png, path, _image_array(img, path, "image"), bits == 16)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG as float32 in [0, 1]: [H,W] for grey, [H,W,3] for colour (alpha dropped)."""
    path = Path(path)
    if not path.is_file():
        raise EvsplatError(f"{path}: file not found")
    return core_call(None, _core.read_png, path)


def write_exr(path: str | os.PathLike, depth: np.ndarray) -> None:
    """Write an [H,W] float32 depth map as a one-channel ("Z") lossless EXR."""
    path = Path(path)
    d = np.ascontiguousarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise EvsplatError(f"{path}: depth must be [H,W], got shape {d.shape}")
    core_call(None, _core.write_exr, path, d)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read the depth ("Z") channel of an EXR as [H,W] float32."""
    path = Path(path)
    if not path.is_file():
        raise EvsplatError(f"{path}: file not found")
    return core_call(None, _core.read_exr, path)
