"""`evsplat bench turn`: the seeding's contrast-maximisation searches against their whole forms.

A textured disc's events, turning and sliding over one window, on sensors of several sizes:
the in-plane turn's images of warped events (`turn.warped_variance`, drawn over the box its
votes fall in) against the same images drawn over the whole sensor, and the ring search's distance
histograms (`sphere.histograms`, in blocks of centres) against one [centres, events, 2] array.
Each row checks that both give the same numbers and prints their times, measured in this run.
"""

from __future__ import annotations

import argparse
import re

import numpy as np
import torch

from evsplat.bench.events import best_of
from evsplat.motion import sphere
from evsplat.motion.turn import GRID, WindowEvents, carried_back, warped_variance

SLIDE = np.array([300.0, 0.0])  # px/s, the disc's image velocity
RATES = np.linspace(-33.0, 33.0, GRID)  # rad/s, the turn rates tried

HELP = "the seeding's turn searches (warped-event images, ring histograms) vs their whole forms"


def sizes(text: str) -> list[tuple[int, int]]:
    """Comma-separated WIDTHxHEIGHT as [(width, height)]; an argparse type."""
    found = [re.fullmatch(r"(\d+)x(\d+)", part.strip()) for part in text.split(",")]
    if not all(found):
        raise argparse.ArgumentTypeError(f"'{text}' is not WIDTHxHEIGHT,... (e.g. 96x96,346x260)")
    return [(int(m.group(1)), int(m.group(2))) for m in found if m]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sizes",
        type=sizes,
        default="96x96,346x260,1280x720",
        help="sensor sizes, comma-separated WIDTHxHEIGHT",
    )
    parser.add_argument("--events", type=int, default=20_000, help="the disc's events")
    parser.add_argument("--radius", type=float, default=30.0, help="the disc's radius, px")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per cell (best kept)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")


def whole_sensor_variance(
    x: torch.Tensor, y: torch.Tensor, p: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """The baseline: each image of bilinear votes drawn over the whole sensor, then its variance."""
    h, w = shape
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    channel = torch.from_numpy((p > 0).astype(np.int64))
    images = torch.zeros(x.shape[0], 2, h + 2, w + 2, dtype=x.dtype)
    flat = images.view(x.shape[0], -1)
    for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                           (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
        xi = (x0 + dx + 1).clamp(0, w + 1).long()
        yi = (y0 + dy + 1).clamp(0, h + 1).long()
        flat.scatter_add_(1, channel[None] * (h + 2) * (w + 2) + yi * (w + 2) + xi, weight)
    return images[:, :, 1:-1, 1:-1].reshape(x.shape[0], -1).var(dim=1).numpy()


def whole_array_histograms(off: np.ndarray, centres: np.ndarray, edge: int) -> np.ndarray:
    """The baseline: every centre's distances at once, then one bincount."""
    dist = np.linalg.norm(off[None] - centres[:, None], axis=-1)
    bins = np.minimum((dist / sphere.BIN_PX).astype(np.int64), edge)
    rows = np.arange(len(centres))[:, None] * (edge + 1)
    counts = np.bincount((rows + bins).ravel(), minlength=len(centres) * (edge + 1))
    return counts.reshape(len(centres), edge + 1)


def disc_events(
    rng: np.random.Generator, n: int, radius: float, centre: np.ndarray
) -> WindowEvents:
    """``n`` events of a textured disc at ``centre`` turning at 8 rad/s and sliding at ``SLIDE``
    over 9 ms, in pixel-centre coordinates."""
    marks = (
        radius
        * np.sqrt(rng.random(n))[:, None]
        * np.stack([np.cos(a := rng.uniform(0, 2 * np.pi, n)), np.sin(a)], 1)
    )
    dt = rng.uniform(-0.0045, 0.0045, n)
    turn = 8.0 * dt
    turned = np.stack([np.cos(turn) * marks[:, 0] - np.sin(turn) * marks[:, 1],
                       np.sin(turn) * marks[:, 0] + np.cos(turn) * marks[:, 1]], 1)  # fmt: skip
    xy = np.floor(centre + turned + SLIDE * dt[:, None]) + 0.5
    return WindowEvents(xy, dt, np.where(rng.random(n) < 0.5, 1, -1))


def run(args: argparse.Namespace) -> int:
    rng = np.random.default_rng(args.seed)
    rows = []
    for w, h in args.sizes:
        centre = np.array([w / 2, h / 2])
        ev = disc_events(rng, args.events, args.radius, centre)
        x, y = carried_back(ev, centre, SLIDE, RATES)
        same = np.allclose(
            warped_variance(x, y, ev.p, (h, w)),
            whole_sensor_variance(x, y, ev.p, (h, w)),
            rtol=1e-9,
            atol=0.0,
        )
        whole = best_of(args.repeat, lambda: whole_sensor_variance(x, y, ev.p, (h, w)))[0]  # noqa: B023
        boxed = best_of(args.repeat, lambda: warped_variance(x, y, ev.p, (h, w)))[0]  # noqa: B023
        rows.append((f"turn images, {w}x{h}", whole, boxed, same))
    off = disc_events(rng, args.events, args.radius, np.zeros(2)).xy
    reach = int(np.ceil(0.5 * args.radius))
    shifts = np.arange(-reach, reach + 1, dtype=np.float64)
    centres = np.stack(np.meshgrid(shifts, shifts), -1).reshape(-1, 2)
    edge = int(round(sphere.RADII[1] * args.radius / sphere.BIN_PX)) + 7
    same = np.array_equal(
        sphere.histograms(off, centres, edge), whole_array_histograms(off, centres, edge)
    )
    whole = best_of(args.repeat, lambda: whole_array_histograms(off, centres, edge))[0]
    blocks = best_of(args.repeat, lambda: sphere.histograms(off, centres, edge))[0]
    rows.append((f"ring histograms, {len(centres)} centres", whole, blocks, same))
    print(f"{args.events:,} events of a disc of radius {args.radius:g} px; best of {args.repeat}")
    print("| search | whole (s) | as seeded (s) | whole / seeded | same numbers |")
    print("|---|---:|---:|---:|---|")
    for name, base, ours, same in rows:
        print(f"| {name} | {base:.3f} | {ours:.3f} | {base / max(ours, 1e-9):.1f}x | {same} |")
    return 0 if all(r[3] for r in rows) else 1
