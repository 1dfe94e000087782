"""`evsplat bench events`: the Rust event core against numpy on random events.

ESI + event mask of one window (the work of every event-loss step) against ``np.add.at`` and
``np.bincount``, and patch extraction against a vectorised numpy implementation, all timed in
the same run. The core is timed with rayon's default thread pool and again in a subprocess
with ``RAYON_NUM_THREADS=1`` for the per-core rate.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Callable

import numpy as np

from evsplat.data.events import EventStream

HELP = "event core (ESI+mask, patches) vs numpy np.add.at / np.bincount on random events"

C_POS, C_NEG = 0.2, 0.3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--events", type=int, default=10_000_000, help="number of events")
    parser.add_argument("--width", type=int, default=640, help="sensor width")
    parser.add_argument("--height", type=int, default=480, help="sensor height")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per row (best kept)")
    parser.add_argument("--centres", type=int, default=2000, help="patch centres")
    parser.add_argument("--sub-windows", type=int, default=4, help="patch sub-windows m")
    parser.add_argument("--side", type=int, default=9, help="patch side in pixels")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument(
        "--core-only", action="store_true", help="time only the Rust core (no numpy baselines)"
    )
    parser.add_argument(
        "--no-single-thread",
        action="store_true",
        help="skip the RAYON_NUM_THREADS=1 re-run that gives the per-core rate",
    )


def best_of(repeat: int, fn: Callable[[], object]) -> tuple[float, float]:
    """Best wall time and best CPU time (all threads of the process) in seconds over
    ``repeat`` runs after one warm-up run. CPU time is what a core actually spent, so it stays
    meaningful on a shared, oversubscribed machine where wall time does not."""
    fn()
    wall, cpu = [], []
    for _ in range(max(1, repeat)):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def esi_mask_add_at(x, y, p, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Baseline: unbuffered scatter-add with np.add.at, mask by fancy assignment."""
    esi = np.zeros((h, w), np.float32)
    np.add.at(esi, (y, x), np.where(p > 0, np.float32(C_POS), np.float32(-C_NEG)))
    mask = np.zeros((h, w), bool)
    mask[y, x] = True
    return esi, mask


def esi_mask_bincount(x, y, p, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Baseline: weighted and plain np.bincount over flat pixel indices."""
    idx = y.astype(np.intp) * w + x
    esi = np.bincount(idx, weights=np.where(p > 0, C_POS, -C_NEG), minlength=w * h)
    mask = np.bincount(idx, minlength=w * h) > 0
    return esi.astype(np.float32).reshape(h, w), mask.reshape(h, w)


def patches_numpy(ev: EventStream, centres: np.ndarray, bounds: np.ndarray, side: int):
    """Vectorised numpy patch extraction (bincount ESI per sub-window, bilinear gather with
    edge clamping, zero outside the sensor): the baseline and a cross-check of the core."""
    w, h = ev.width, ev.height
    off = np.arange(side) - (side - 1) / 2
    c = centres.astype(np.float64)
    sx = np.broadcast_to(c[:, 0, None, None] + off[None, None, :], (len(c), side, side))
    sy = np.broadcast_to(c[:, 1, None, None] + off[None, :, None], (len(c), side, side))
    inside = (sx >= 0) & (sx < w) & (sy >= 0) & (sy < h)
    u, v = sx - 0.5, sy - 0.5
    j0, i0 = np.floor(u), np.floor(v)
    ax, ay = u - j0, v - i0
    j0c, j1c = np.clip(j0, 0, w - 1).astype(np.intp), np.clip(j0 + 1, 0, w - 1).astype(np.intp)
    i0c, i1c = np.clip(i0, 0, h - 1).astype(np.intp), np.clip(i0 + 1, 0, h - 1).astype(np.intp)
    out = np.zeros((len(c), len(bounds) - 1, side, side), np.float32)
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]
        idx = ev.y[a:b].astype(np.intp) * w + ev.x[a:b]
        wts = np.where(ev.p[a:b] > 0, np.float32(C_POS), np.float32(-C_NEG))
        img = np.bincount(idx, weights=wts, minlength=w * h).astype(np.float32).reshape(h, w)
        img = img.astype(np.float64)
        top = (1 - ax) * img[i0c, j0c] + ax * img[i0c, j1c]
        bottom = (1 - ax) * img[i1c, j0c] + ax * img[i1c, j1c]
        out[:, k] = np.where(inside, (1 - ay) * top + ay * bottom, 0.0)
    return out


def random_stream(n: int, w: int, h: int, seed: int) -> EventStream:
    rng = np.random.default_rng(seed)
    return EventStream.from_arrays(
        rng.integers(0, w, n, dtype=np.uint16),
        rng.integers(0, h, n, dtype=np.uint16),
        np.sort(rng.integers(0, 10 * n, n)),
        rng.choice(np.array([-1, 1], np.int8), n),
        w,
        h,
        source="<bench>",
    )


def pool_threads() -> int:
    """Threads in rayon's global pool (RAYON_NUM_THREADS, else the usable CPUs)."""
    env = os.environ.get("RAYON_NUM_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def measure(args: argparse.Namespace) -> list[dict]:
    ev = random_stream(args.events, args.width, args.height, args.seed)
    n, w, h, r = len(ev), ev.width, ev.height, args.repeat
    threads = pool_threads()
    rows = []

    def row(op: str, impl: str, seconds: tuple[float, float], nthreads: int) -> None:
        wall, cpu = seconds
        rows.append(
            {
                "op": op,
                "impl": impl,
                "threads": nthreads,
                "wall_ms": wall * 1e3,
                "cpu_ms": cpu * 1e3,
            }
        )

    row(
        "ESI+mask",
        "rust (one pass)",
        best_of(r, lambda: ev.esi_and_mask(0, n, C_POS, C_NEG)),
        threads,
    )
    row(
        "ESI+mask",
        "rust (esi + event_mask)",
        best_of(r, lambda: (ev.esi(0, n, C_POS, C_NEG), ev.event_mask(0, n))),
        threads,
    )
    rng = np.random.default_rng(args.seed + 1)
    centres = np.column_stack(
        [rng.uniform(-2, w + 2, args.centres), rng.uniform(-2, h + 2, args.centres)]
    ).astype(np.float32)
    bounds = ev.split_equal_count(0, n, args.sub_windows)
    row(
        "patches",
        "rust",
        best_of(r, lambda: ev.patches(centres, bounds, args.side, C_POS, C_NEG)),
        threads,
    )
    if args.core_only:
        return rows
    rust, _ = ev.esi_and_mask(0, n, C_POS, C_NEG)
    for name, fn in (
        ("numpy np.add.at", esi_mask_add_at),
        ("numpy np.bincount", esi_mask_bincount),
    ):
        esi, mask = fn(ev.x, ev.y, ev.p, w, h)
        np.testing.assert_allclose(esi, rust, rtol=1e-4, atol=1e-3, err_msg=name)
        # np.add.at is slow: time it fewer times.
        row("ESI+mask", name, best_of(max(1, r // 3), lambda f=fn: f(ev.x, ev.y, ev.p, w, h)), 1)
    want = patches_numpy(ev, centres, bounds, args.side)
    got, _ = ev.patches(centres, bounds, args.side, C_POS, C_NEG)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3, err_msg="patches")
    row(
        "patches",
        "numpy (vectorised)",
        best_of(r, lambda: patches_numpy(ev, centres, bounds, args.side)),
        1,
    )
    return rows


def single_thread_rows(args: argparse.Namespace) -> list[dict]:
    """The core's rows re-measured in a subprocess whose rayon pool has one thread."""
    cmd = [
        sys.executable,
        "-m",
        "evsplat.cli",
        "bench",
        "events",
        "--json",
        "--core-only",
        "--no-single-thread",
        f"--events={args.events}",
        f"--width={args.width}",
        f"--height={args.height}",
        f"--repeat={args.repeat}",
        f"--centres={args.centres}",
        f"--sub-windows={args.sub_windows}",
        f"--side={args.side}",
        f"--seed={args.seed}",
    ]
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def run(args: argparse.Namespace) -> int:
    rows = measure(args)
    if not args.no_single_thread and pool_threads() != 1:
        rows += single_thread_rows(args)
    if args.json:
        print(json.dumps(rows))
        return 0
    print(
        f"evsplat bench events: {args.events:,} random events on {args.width}x{args.height}; "
        f"patches: {args.centres} centres x {args.sub_windows} sub-windows x "
        f"{args.side}x{args.side}; best of {args.repeat}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print(table(rows, args.events))
    print(
        "wall: elapsed time; cpu: CPU time of all threads (per-core rate = events / cpu).\n"
        "Speed-ups compare CPU times with the numpy baselines measured in this run."
    )
    return 0


def table(rows: list[dict], events: int) -> str:
    """Rows sorted by op, slowest first, with rates and speed-ups over the numpy baselines."""

    def cpu_of(impl: str) -> float | None:
        return next((r["cpu_ms"] for r in rows if r["impl"] == impl), None)

    baselines = {
        "ESI+mask": [
            ("np.add.at", cpu_of("numpy np.add.at")),
            ("np.bincount", cpu_of("numpy np.bincount")),
        ],
        "patches": [("numpy", cpu_of("numpy (vectorised)"))],
    }
    head = (
        f"{'op':<9} {'implementation':<24} {'threads':>7} {'wall ms':>9} {'cpu ms':>9} "
        f"{'Mev/s wall':>10} {'Mev/s/core':>10}  speed-up (cpu)"
    )
    lines = [head, "-" * len(head)]
    for r in sorted(rows, key=lambda r: (r["op"], -r["cpu_ms"])):
        ups = ", ".join(
            f"{b / r['cpu_ms']:.1f}x {name}" for name, b in baselines[r["op"]] if b is not None
        )
        lines.append(
            f"{r['op']:<9} {r['impl']:<24} {r['threads']:>7} {r['wall_ms']:>9.2f} "
            f"{r['cpu_ms']:>9.2f} {events / (r['wall_ms'] * 1e3):>10.1f} "
            f"{events / (r['cpu_ms'] * 1e3):>10.1f}  {ups}"
        )
    return "\n".join(lines)
