"""Objects cut by the image border (docs/motion.md, step 2): its whole region from a sighting
clear of the border, moved until its part in the image best matches the cut region, puts its
centre there, beyond the border if need be."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import signal

from evsplat.motion.segment import Blob


def borders(mask: np.ndarray) -> set[str]:  # the image borders a region touches
    edges = {"top": mask[0], "bottom": mask[-1], "left": mask[:, 0], "right": mask[:, -1]}
    return {side for side, edge in edges.items() if edge.any()}


def touches_border(mask: np.ndarray) -> bool:
    return bool(borders(mask))


def whole_centre(shape: Blob, cut: Blob) -> np.ndarray:
    """[2] (x, y) px: the centre of the object whose whole region is ``shape`` where its cut
    region ``cut`` shows it: whole-pixel shifts up to the shape's diameter, then quarter pixels
    about the best. The cut region's own centre where the shape there lies wholly in view (a
    blur's rim touched the border, not the object)."""
    ys, xs = np.nonzero(shape.mask)
    offsets = np.stack([xs + 0.5, ys + 0.5], 1) - shape.centre[None]  # [M,2] about its centre
    centre = _coarse(shape, cut, int(np.ceil(2.0 * shape.radius)))
    centre = _best(offsets, cut, centre, np.arange(-4, 5, dtype=np.float64) / 4)
    pixels = np.floor(centre[None] + offsets).astype(np.int64)
    if in_image(pixels, cut.mask.shape).all():
        return cut.centre  # all of it in view there: its region's own centre is unbiased
    return centre


def in_image(pixels: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """[...] bool: which (x, y) ``pixels`` [...,2] lie in an image of ``shape`` (H, W)."""
    h, w = shape
    x, y = pixels[..., 0], pixels[..., 1]
    return (x >= 0) & (x < w) & (y >= 0) & (y < h)


def _coarse(shape: Blob, cut: Blob, reach: int) -> np.ndarray:
    """``_best`` over the whole-pixel shifts up to ``reach`` from ``cut``'s centre, as
    correlations of the masks by FFT (pixel by pixel for every shift takes too much memory)."""
    h, w = cut.mask.shape
    image = np.stack([cut.mask, np.ones((h, w), dtype=bool)]).astype(np.float64)
    counts = signal.correlate(image, shape.mask[None].astype(np.float64), "full", "fft")
    steps = np.arange(-reach, reach + 1)
    shifts = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)  # [S,2]
    lag = np.floor(cut.centre - shape.centre + 0.5).astype(np.int64) + shifts  # of the pixels
    ok = (np.abs(lag[:, 0]) < w) & (np.abs(lag[:, 1]) < h)
    hit, inside = np.rint(counts[:, lag[ok, 1] + h - 1, lag[ok, 0] + w - 1])
    score = np.zeros(len(shifts))
    score[ok] = hit / np.maximum(inside + cut.area - hit, 1.0)
    return (cut.centre + shifts)[np.lexsort((np.abs(shifts).sum(1), -score))[0]]


def _best(offsets: np.ndarray, cut: Blob, around: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Of the centres ``around`` + every (dx, dy) in ``steps``², the one whose shape ``offsets``
    [M,2] in the image best matches ``cut``'s region (IoU); of equals, the nearest."""
    shifts = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)  # [S,2]
    centres = around[None] + shifts
    pixels = np.floor(centres[:, None] + offsets[None]).astype(np.int64)  # [S,M,2]
    inside = in_image(pixels, cut.mask.shape)
    hit = np.zeros_like(inside)
    hit[inside] = cut.mask[pixels[..., 1][inside], pixels[..., 0][inside]]
    overlap = hit.sum(1).astype(np.float64)
    score = overlap / np.maximum(inside.sum(1) + cut.area - overlap, 1.0)
    return centres[np.lexsort((np.abs(shifts).sum(1), -score))[0]]


def uncut(blobs: dict[int, Blob], own: set[int]) -> dict[int, Blob]:
    """The regions by window, those cut by the border given their whole shape's centre: that of
    the nearest window whose region is the object's alone (``own``) and clear of the border (its
    region changes as it turns). Unchanged where none is clear."""
    clear = [k for k in sorted(own) if not touches_border(blobs[k].mask)]
    if not clear:
        return blobs
    out = dict(blobs)
    for k in own:
        if touches_border(blobs[k].mask):
            near = min(clear, key=lambda c: abs(c - k))
            out[k] = replace(blobs[k], centre=whole_centre(blobs[near], blobs[k]))
    return out
