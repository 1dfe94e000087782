"""Figures a user looks at: loss curves and side-by-side ground truth | render | depth."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evsplat.data.atomic import write_atomic

if TYPE_CHECKING:
    from evsplat.data.ground_truth import ObjectTrack


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_losses(history: list[dict], out: Path) -> None:
    """Each loss term against iteration (log scale), stage changes marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    keys = [k for k in ("total", "e", "ef", "m", "d", "ne", "sp") if any(k in h for h in history)]
    for k in keys:
        pts = [(h["iteration"], h[k]) for h in history if k in h and h[k] > 0]
        if pts:
            it, v = zip(*pts)
            ax.plot(it, v, label=f"L_{k}" if k != "total" else "total", lw=1.2)
    prev = None
    for h in history:
        if prev is not None and h["stage"] != prev:
            ax.axvline(h["iteration"], color="grey", ls=":", lw=1)
            ax.text(h["iteration"], ax.get_ylim()[1], f" {h['stage']}", va="top", fontsize=8)
        prev = h["stage"]
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.legend(fontsize=8)
    ax.set_title("training losses")
    fig.tight_layout()
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def plot_test_frames(frames: list[dict], out: Path, title: str = "") -> None:
    """Rows of ground truth | render (colour-fitted) | depth for a few test frames."""
    plt = _pyplot()
    rows = len(frames)
    fig, axes = plt.subplots(rows, 3, figsize=(7.5, 2.6 * rows), squeeze=False)
    for r, fr in enumerate(frames):
        for c, (img, name) in enumerate(
            ((fr["gt"], "ground truth"), (fr["fitted"], "render"), (fr["depth"], "depth"))
        ):
            ax = axes[r, c]
            if name == "depth":
                valid = img[img > 0]
                vmax = float(np.percentile(valid, 99)) if valid.size else 1.0
                ax.imshow(img, cmap="turbo", vmin=0, vmax=vmax)
            else:
                shown = np.clip(img, 0, 1)
                ax.imshow(shown[..., 0] if shown.shape[-1] == 1 else shown, cmap="gray")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(name, fontsize=9)
        axes[r, 0].set_ylabel(f"t = {fr['time_us'] / 1e6:.3f} s", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


TRACK_FIGURE_INCHES = 6.5  # a 96 px image is drawn about 8x larger, so the paths are readable
TRACK_MAX_OVERHANG = 0.5  # the view extends at most this fraction of the image beyond its edges


# One colour per object: its true path thick, its tracked paths thin (bright named colours,
# the greys left out: they vanish on a grey picture).
TRACK_COLOURS = ("lime", "magenta", "orange", "cyan", "red", "yellow", "deepskyblue", "white")


def track_colour_name(i: int) -> str:
    """Object ``i``'s colour name in every picture of objects (``TRACK_COLOURS``, cycled)."""
    return TRACK_COLOURS[i % len(TRACK_COLOURS)]


def track_colour(i: int) -> np.ndarray:
    """Object ``i``'s colour as RGB in [0, 1] [3] (``track_colour_name``)."""
    from matplotlib.colors import to_rgb

    return np.array(to_rgb(track_colour_name(i)))


def plot_track(
    image: np.ndarray,
    c2w: np.ndarray,
    K: np.ndarray,
    objects: list[tuple[str, dict, ObjectTrack | None]],
    out: Path,
    title: str = "",
) -> None:
    """Per moving object (name, its tracking from ``evsplat.motion_metrics``, its dense
    ``track`` or None), in one colour each: the true path (dense when ``track`` is given, else
    through the test times) and each reference frame's predicted path, projected with one
    camera ``c2w`` over ``image`` (linear, shown at display gamma). Paths may leave the image:
    the view extends past its edges up to ``TRACK_MAX_OVERHANG``."""
    from evsplat.metrics import to_display
    from evsplat.motion_metrics import project

    plt = _pyplot()
    h, w = image.shape[:2]
    fig, ax = plt.subplots(figsize=(TRACK_FIGURE_INCHES, TRACK_FIGURE_INCHES * h / w + 0.6))
    shown = to_display(image)
    ax.imshow(shown, cmap="gray", extent=(0, w, h, 0), interpolation="nearest", vmin=0, vmax=1)
    drawn, summaries = [], []
    for n, (name, tracking, track) in enumerate(objects):
        colour = track_colour_name(n)
        drawn += _draw_object(ax, project, c2w, K, tracking, track, colour, name)
        err, ratio = tracking["error_px_median"], tracking["path_ratio"]
        region = tracking["region"]["error_px_median"]
        summaries.append(
            f"{name}: no reference frame shows its Gaussians"
            if err is None
            else f"{name}: region off by {'-' if region is None else f'{region:.1f}'} px "
            f"(median); Gaussians followed: {err:.1f} px, path ratio "
            f"{'-' if ratio is None else f'{ratio:.2f}'}"
        )
    _frame_view(ax, np.concatenate(drawn), w, h)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.0), frameon=False)
    summary = "\n".join(summaries)
    ax.set_title(f"{title}\n{summary}" if title else summary, fontsize=9)
    fig.tight_layout()
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def _draw_object(ax, project, c2w, K, tracking, track, colour: str, name: str) -> list:
    """One object's true path (thick) and predicted paths (thin; ring = reference); returns
    the drawn pixel points."""
    times = [p["time_us"] for p in tracking["per_time"]]
    gt_px = project(_true_path(tracking, track, times), c2w, K)
    ax.plot(*gt_px.T, color=colour, lw=2.5, label=f"{name}: true path (dots: test times)")
    at_tests = np.asarray([p["centre"] for p in tracking["per_time"]])
    ax.plot(*project(at_tests, c2w, K).T, "o", color=colour, ms=5)
    drawn = [gt_px]
    refs = [p for p in tracking["paths"] if p["centres"] is not None]
    for i, ref in enumerate(refs):
        px = project(np.asarray(ref["centres"]), c2w, K)
        k = times.index(ref["reference_us"])
        label = f"{name}: tracked, one per reference frame (ring)" if i == 0 else None
        ax.plot(*px.T, "o--", color=colour, lw=1.0, ms=3, alpha=0.8, label=label)
        ax.plot(*px[k], "o", mfc="none", mec=colour, ms=9, mew=1.5)
        drawn.append(px)
    return drawn


def _true_path(tracking: dict, track: ObjectTrack | None, times: list[int]) -> np.ndarray:
    """World points of the true path over the test times' span: dense when ``track`` is known,
    else through the test frames' centres."""
    if track is None:
        return np.asarray([p["centre"] for p in tracking["per_time"]])
    keep = (track.times_us >= times[0]) & (track.times_us <= times[-1])
    return track.centres[keep]


def _frame_view(ax, px: np.ndarray, w: int, h: int) -> None:
    """Axis limits holding the image and the drawn points, at most ``TRACK_MAX_OVERHANG`` of
    the image beyond each edge (a wild prediction must not shrink the picture to a dot)."""
    finite = px[np.all(np.isfinite(px), axis=1)]
    lo = np.minimum(finite.min(axis=0, initial=0.0), 0.0) - 2.0
    hi = np.maximum(finite.max(axis=0, initial=0.0), (w, h)) + 2.0
    lo = np.maximum(lo, (-TRACK_MAX_OVERHANG * w, -TRACK_MAX_OVERHANG * h))
    hi = np.minimum(hi, ((1 + TRACK_MAX_OVERHANG) * w, (1 + TRACK_MAX_OVERHANG) * h))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])  # image rows grow downwards
    ax.set_facecolor("0.85")


def plot_segmentation(
    images: list[np.ndarray],
    times_us: list[int],
    truths: list[list[np.ndarray]],
    found_for: list[int | None],
    names: list[str],
    out: Path,
    title: str = "",
) -> None:
    """One panel per test time: ``images`` ([H,W,3] in [0, 1], the found objects' pixels
    already tinted, ``object_output.tinted``) with each true object's mask (``truths[j][f]``)
    outlined in its colour (``track_colour``); the legend names the found object matched to
    each (``found_for[j]``)."""
    from scipy import ndimage

    plt = _pyplot()
    fig, axes = plt.subplots(1, len(images), figsize=(2.2 * len(images), 2.6), squeeze=False)
    for f, (image, ax) in enumerate(zip(images, axes[0])):
        shown = image.copy()
        for j, masks in enumerate(truths):
            shown[masks[f] & ~ndimage.binary_erosion(masks[f])] = track_colour(j)
        ax.imshow(shown, interpolation="nearest")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"t = {times_us[f] / 1e6:.3f} s", fontsize=8)
    legend = ", ".join(
        f"{name} ({track_colour_name(j)}): "
        + ("no object found for it" if k is None else f"object {k}")
        for j, (name, k) in enumerate(zip(names, found_for))
    )
    fig.suptitle(
        (title + "\n" if title else "")
        + "true outlines; the pixels of the object found for each, filled (white: none's)\n"
        + legend,
        fontsize=8,
    )
    fig.tight_layout()
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
