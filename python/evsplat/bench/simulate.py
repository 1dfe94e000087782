"""`evsplat bench simulate`: time `simulate` on every built-in scene (full size and tiny) and
optionally draw each scene's frame / event frame / depth picture for the docs."""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

HELP = "simulate every built-in scene at full and tiny size; events, events/s, wall time"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenes", default=None, help="comma-separated scenes (default: all)")
    parser.add_argument("--tiny-only", action="store_true", help="only the tiny variants")
    parser.add_argument(
        "--pictures",
        default=None,
        help="write NAME.png pictures to this folder (of the tiny variants with --tiny-only)",
    )


def picture(dataset: Path, out: Path, window_us: int = 10_000) -> None:
    """Top: the middle test frame (gamma-encoded for display), the events within ±window/2 of
    it, its depth, and its per-object masks (one colour each) with every object's true path
    through the test times; below: every test frame, so the movers' motion shows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from evsplat.data.dataset import load_dataset
    from evsplat.data.images import read_exr, read_png
    from evsplat.motion_metrics import project
    from evsplat.plots import track_colour

    ds = load_dataset(dataset)
    f = ds.test_frames[len(ds.test_frames) // 2]
    rgb, depth = read_png(f.rgb_path), read_exr(f.depth_path)
    events = ds.events.read(f.time_us - window_us // 2, f.time_us + window_us // 2)
    ev = np.zeros((ds.height, ds.width))
    np.add.at(ev, (events.y, events.x), events.p)
    lim = max(1.0, np.percentile(np.abs(ev[ev != 0]), 95)) if (ev != 0).any() else 1.0
    n = len(ds.test_frames)
    cols = max(4, n)
    fig = plt.figure(figsize=(3 * 4, (3 + 12 / cols) * ds.height / ds.width + 0.9))
    grid = fig.add_gridspec(2, 4 * cols, height_ratios=[3, 12 / cols])
    axes = [fig.add_subplot(grid[0, k * cols : (k + 1) * cols]) for k in range(4)]
    axes[0].imshow(np.clip(rgb, 0, 1) ** (1 / 2.2), cmap="gray")
    axes[0].set_title(f"{ds.meta['scene']}: frame at {f.time_us / 1e3:.1f} ms", fontsize=9)
    axes[1].imshow(ev, cmap="bwr_r", vmin=-lim, vmax=lim)
    axes[1].set_title(f"events ±{window_us // 2000} ms ({len(events)}; red +, blue −)", fontsize=9)
    im = axes[2].imshow(depth, cmap="viridis")
    axes[2].set_title("depth (m)", fontsize=9)
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    ids = np.zeros((ds.height, ds.width, 3))
    for k, o in enumerate(f.objects):
        colour = track_colour(k)
        ids[read_png(o.mask_path).reshape(ds.height, ds.width, -1)[..., 0] > 0.5] = colour
        path = project(np.stack([g.objects[k].centre for g in ds.test_frames]), f.c2w, ds.K)
        axes[3].plot(*path.T, "o-", color=colour, ms=3, lw=1, label=o.name)
    axes[3].imshow(ids, extent=(0, ds.width, ds.height, 0))
    axes[3].set_xlim(0, ds.width)
    axes[3].set_ylim(ds.height, 0)
    axes[3].set_title("object masks, centres at the test times", fontsize=9)
    if f.objects:
        axes[3].legend(fontsize=7, loc="lower right")
    for j, g in enumerate(ds.test_frames):
        ax = fig.add_subplot(grid[1, j * 4 * cols // n : (j + 1) * 4 * cols // n])
        ax.imshow(np.clip(read_png(g.rgb_path), 0, 1) ** (1 / 2.2), cmap="gray")
        ax.set_title(f"{g.time_us / 1e3:.0f} ms", fontsize=8)
        axes.append(ax)
    for a in axes:
        a.axis("off")
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from evsplat.data.simulator import simulate_dataset
    from evsplat.scenes import get_scene, scene_names

    names = args.scenes.split(",") if args.scenes else scene_names()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for tiny in (True,) if args.tiny_only else (False, True):
                scene = get_scene(name, tiny=tiny)
                # Baseline in the same run: rendering alone, on every 10th frame.
                step = 10 * 1e6 / scene.fps
                t = time.perf_counter()
                n_base = 0
                for ts in np.arange(0, scene.duration_us, step):
                    scene.render(int(ts))
                    n_base += 1
                render_s = (time.perf_counter() - t) / n_base
                out = Path(tmp) / f"{name}{'-tiny' if tiny else ''}"
                t = time.perf_counter()
                simulate_dataset(name, out, tiny=tiny, progress=False)
                wall = time.perf_counter() - t
                meta = json.loads((out / "meta.json").read_text())
                secs = (meta["t_end_us"] - meta["t_start_us"]) * 1e-6
                rows.append(
                    (name, f"{scene.width}x{scene.height}", secs, meta["rendered_frames"],
                     meta["num_events"], meta["num_events"] / secs, render_s * 1e3, wall)
                )  # fmt: skip
                if args.pictures and tiny == args.tiny_only:
                    Path(args.pictures).mkdir(parents=True, exist_ok=True)
                    picture(out, Path(args.pictures) / f"{name}.png")
    head = ("scene", "size", "scene s", "frames", "events", "events/s", "render ms", "wall s")
    print(" | ".join(head))
    for r in rows:
        print(
            f"{r[0]} | {r[1]} | {r[2]:.2f} | {r[3]} | {r[4]} | {r[5]:.3g} | {r[6]:.2f} | {r[7]:.1f}"
        )
    return 0
