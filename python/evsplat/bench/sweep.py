"""`evsplat bench sweep`: one training grid run three ways, its wall time and Ray's per-cell cost.

The grid of `evsplat bench --preset P` (default quick) runs (1) on the local runner, one cell
after another, (2) on a Ray cluster started on this machine with ``--workers`` cells at once,
and (3) on the same cluster one cell at a time (each cell asks for all its CPUs). Every run
starts from nothing (``fresh``). Per-cell overhead is the sweep's wall time less the cells'
own training time, per cell; (3) against (1) is what Ray adds to a cell, and the cluster's
start is timed on its own.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from evsplat.bench.train import PRESETS, bench_cell, machine_info, simulate_cases
from evsplat.sweep import SweepOptions, run_sweep

HELP = "a training grid locally and on a local Ray cluster: wall time and Ray's per-cell cost"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", default="quick", choices=sorted(PRESETS))
    parser.add_argument("--iters", type=int, default=None, help="override iterations per run")
    parser.add_argument("--workers", type=int, default=2, help="CPUs of the Ray cluster (2)")
    parser.add_argument("--out", type=Path, default=Path("bench_results/sweep"))


def run(args: argparse.Namespace) -> int:
    from evsplat.sweep.backends import LOCAL_CLUSTER, import_ray, start_local_cluster

    info = machine_info()
    print(f"machine: {info['machine']}\nadapter: {info['adapter']}\ncommit: {info['commit']}")
    spec = PRESETS[args.preset]
    data = simulate_cases(spec["cases"], args.out)
    cells = [
        bench_cell(case, variant, spec, data[case.name], args.iters)
        for case in spec["cases"]
        for variant in spec["variants"]
    ]
    ray = import_ray(LOCAL_CLUSTER)
    modes = [
        ("local, one at a time", "local", SweepOptions(fresh=True)),
        (
            f"ray, {args.workers} at a time",
            "ray",
            SweepOptions(ray=LOCAL_CLUSTER, fresh=True),
        ),
        (
            "ray, one at a time",
            "ray-serial",
            SweepOptions(ray=LOCAL_CLUSTER, cpus_per_cell=args.workers, fresh=True),
        ),
    ]
    start = time.perf_counter()
    start_local_cluster(ray, args.workers)
    cluster_s = time.perf_counter() - start
    results = []
    try:
        for name, folder, options in modes:
            t = time.perf_counter()
            sweep = run_sweep(cells, args.out / folder, options)
            wall = time.perf_counter() - t
            if sweep.failures:
                return sweep.exit_code
            trained = sum(r["wall_seconds"] for r in sweep.rows)
            results.append((name, wall, trained))
    finally:
        ray.shutdown()
    n = len(cells)
    local_wall, local_trained = results[0][1], results[0][2]
    print(f"\n{n} cells of `bench --preset {args.preset}`; Ray cluster start: {cluster_s:.1f} s")
    print("| mode | wall s | speed-up | training s (sum) | overhead s per cell |")
    print("|---|---|---|---|---|")
    for name, wall, trained in results:
        print(
            f"| {name} | {wall:.1f} | {local_wall / wall:.2f}x | {trained:.1f} | "
            f"{(wall - trained) / n:.2f} |"
        )
    serial_wall, serial_trained = results[2][1], results[2][2]
    added = ((serial_wall - serial_trained) - (local_wall - local_trained)) / n
    print(f"Ray adds {added:.2f} s per cell (one at a time, against the local runner)")
    return 0
