"""Figures a user looks at: loss curves and side-by-side ground truth | render | depth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evsplat.data.atomic import write_atomic


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


def side_by_side(frames: list[dict], out: Path, title: str = "") -> None:
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
