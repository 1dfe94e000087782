"""Videos of a trained run: MP4 (H.264 through the ffmpeg binary that ``imageio-ffmpeg``
ships in its wheel) of renders over time, alone or beside an event-frame visualisation."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from evsplat.data.atomic import write_atomic
from evsplat.data.events import EventStream
from evsplat.errors import EvsplatError

#: H.264 in yuv420p (what every player opens) needs even frame sides.
_BLOCK = 2


def to_rgb8(img: np.ndarray) -> np.ndarray:
    """[H,W], [H,W,1] or [H,W,3] floats in [0,1] -> [H,W,3] uint8 (NaN -> 0)."""
    a = np.nan_to_num(np.asarray(img, np.float32), nan=0.0)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def colour_depth(depth: np.ndarray) -> np.ndarray:
    """Turbo colour map of depth (near = warm), background black."""
    import matplotlib

    valid = depth > 0
    vmax = float(np.percentile(depth[valid], 99)) if valid.any() else 1.0
    rgb = matplotlib.colormaps["turbo"](np.clip(depth / max(vmax, 1e-9), 0, 1))[..., :3]
    return np.where(valid[..., None], rgb, 0.0).astype(np.float32)


def event_frame(events: EventStream, i0: int, i1: int) -> np.ndarray:
    """Events [i0, i1) as an image: white background, positive events red, negative blue,
    saturating at 3 events per pixel. [H,W,3] float32."""
    w, h = events.width, events.height
    img = np.ones((h, w, 3), np.float32)
    idx = events.y[i0:i1].astype(np.int64) * w + events.x[i0:i1]
    pos = events.p[i0:i1] > 0
    npos = np.bincount(idx[pos], minlength=w * h).reshape(h, w)
    nneg = np.bincount(idx[~pos], minlength=w * h).reshape(h, w)
    level = np.clip((npos - nneg) / 3.0, -1.0, 1.0)
    # Positive pulls green and blue down (red); negative pulls red and green down (blue).
    img[..., 0] -= np.clip(-level, 0, 1)
    img[..., 1] -= np.abs(level)
    img[..., 2] -= np.clip(level, 0, 1)
    return img


def hstack_images(*images: np.ndarray) -> np.ndarray:
    """Images of equal height [H,W,3] placed left to right."""
    heights = {im.shape[0] for im in images}
    if len(heights) != 1:
        raise EvsplatError(f"hstack_images: images have different heights {sorted(heights)}")
    return np.concatenate([to_rgb8(im) for im in images], axis=1)


def write_mp4(
    path: str | os.PathLike,
    frames: Iterable[np.ndarray],
    fps: float = 20.0,
    min_side: int = 240,
) -> int:
    """Writes ``frames`` ([H,W,3] uint8 or floats in [0,1], all one size) as an H.264 MP4,
    atomically; returns the number of frames. Frames whose shorter side is below ``min_side``
    are enlarged by a whole factor, nearest neighbour (small sensors stay watchable and each
    pixel survives the codec's 2x2 colour subsampling); odd sides are padded with black."""
    import imageio_ffmpeg

    path = Path(path)
    if not (fps > 0 and np.isfinite(fps)):
        raise EvsplatError(f"{path}: fps {fps} must be a positive number")
    count = 0

    def write(tmp: Path) -> None:
        nonlocal count
        writer = None
        size = None
        try:
            for frame in frames:
                rgb = frame if frame.dtype == np.uint8 and frame.ndim == 3 else to_rgb8(frame)
                if size is None:
                    size = rgb.shape[:2]
                    scale = max(1, -(-min_side // max(min(size), 1)))
                    padded = [-(-s * scale // _BLOCK) * _BLOCK for s in size]
                    writer = imageio_ffmpeg.write_frames(
                        str(tmp),
                        (padded[1], padded[0]),
                        fps=fps,
                        codec="libx264",
                        pix_fmt_out="yuv420p",
                        macro_block_size=1,
                        output_params=["-f", "mp4"],
                        ffmpeg_log_level="error",
                    )
                    writer.send(None)  # starts ffmpeg
                if rgb.shape[:2] != size:
                    raise EvsplatError(
                        f"{path}: frame {count} is {rgb.shape[1]}x{rgb.shape[0]}, the first was "
                        f"{size[1]}x{size[0]}; frames of a video must share one size"
                    )
                out = np.zeros((padded[0], padded[1], 3), np.uint8)
                out[: size[0] * scale, : size[1] * scale] = (
                    rgb.repeat(scale, 0).repeat(scale, 1) if scale > 1 else rgb
                )
                writer.send(np.ascontiguousarray(out))
                count += 1
        finally:
            if writer is not None:
                writer.close()
        if count == 0:
            raise EvsplatError(f"{path}: no frames to write")

    write_atomic(path, write)
    return count


def read_mp4_frame(path: str | os.PathLike, index: int = 0) -> np.ndarray:
    """Frame ``index`` of a video as [H,W,3] uint8 (for checks and thumbnails)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
        w, h = meta["size"]
        for i, raw in enumerate(reader):
            if i == index:
                return np.frombuffer(raw, np.uint8).reshape(h, w, 3).copy()
    finally:
        reader.close()
    raise EvsplatError(f"{path}: has no frame {index}")
