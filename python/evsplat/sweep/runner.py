"""The sweep runner behind every `evsplat bench` grid and `evsplat train-many`: skip the cells
already finished under the output folder, run the rest locally or on Ray with one progress
bar, and gather the result rows (failures are one line each; the other cells still finish)."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

from evsplat.data.atomic import write_text_atomic
from evsplat.errors import EvsplatError
from evsplat.sweep import store
from evsplat.sweep.backends import LOCAL_CLUSTER, LocalBackend, PoolBackend, RayBackend
from evsplat.sweep.cell import Cell, code_version

POLL_S = 1.0  # how often the bar's running count and ETA are refreshed while Ray works


@dataclass(frozen=True)
class SweepOptions:
    ray: str | None = None  # None: local; LOCAL_CLUSTER: start one here; else an address
    max_retries: int = 3
    cpus_per_cell: float = 1.0
    jobs: int = 1  # without Ray: cells run at once on this machine
    fresh: bool = False
    progress: bool = True

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> SweepOptions:
        return cls(
            ray=args.ray,
            max_retries=args.max_retries,
            cpus_per_cell=args.cpus_per_cell,
            jobs=args.jobs,
            fresh=args.fresh,
            progress=not getattr(args, "no_progress", False),
        )


def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("where the runs go (docs/scale-out.md)")
    g.add_argument(
        "--ray",
        nargs="?",
        const=LOCAL_CLUSTER,
        default=None,
        metavar="ADDRESS",
        help="run the cells as Ray tasks: on a cluster started on this machine (no ADDRESS) or "
        "on a running one (HOST:PORT, ray://HOST:10001, auto); needs evsplat[ray]",
    )
    g.add_argument(
        "--max-retries",
        type=int,
        default=3,
        help="with --ray: times a cell whose worker died is run again (default 3)",
    )
    g.add_argument(
        "--cpus-per-cell", type=float, default=1.0, help="with --ray: CPUs each cell asks for"
    )
    g.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="N",
        help="without --ray: run N cells at once on this machine, each in its own process "
        "(default 1; a GPU machine's cores; each cell takes its preset's torch threads)",
    )
    g.add_argument(
        "--fresh", action="store_true", help="run finished cells again instead of reusing them"
    )


@dataclass
class SweepResult:
    rows: list[dict]  # one per input cell that finished, in input order, labels first
    failures: list[tuple[Cell, str]] = field(default_factory=list)
    executed: int = 0  # cells run by this sweep (finished or failed)
    reused: int = 0  # cells finished by an earlier sweep

    @property
    def exit_code(self) -> int:
        return 1 if self.failures else 0


def run_sweep(
    cells: list[Cell], out: str | Path, options: SweepOptions | None = None
) -> SweepResult:
    """Run every cell not yet finished under ``out``; cells with one key run once."""
    options = options or SweepOptions()
    if options.max_retries < 0:
        raise EvsplatError(f"--max-retries {options.max_retries}: must be 0 or more")
    if options.jobs < 1:
        raise EvsplatError(f"--jobs {options.jobs}: must be 1 or more")
    if options.jobs != 1 and options.ray is not None:
        raise EvsplatError(
            f"--jobs {options.jobs} with --ray: Ray places the cells; set --cpus-per-cell instead"
        )
    # A missing extra or an unreachable address fails here, before anything is written.
    if options.ray is not None:
        backend = RayBackend(options.ray, options.max_retries, options.cpus_per_cell)
    elif options.jobs > 1:
        backend = PoolBackend(options.jobs)
    else:
        backend = LocalBackend()
    out = Path(out).resolve()  # workers get absolute paths
    code = code_version()
    keys = [c.key(code) for c in cells]
    unique = _unique(cells, keys)
    out.mkdir(parents=True, exist_ok=True)
    store.remove_attempts(out)  # left by workers killed in an earlier sweep
    if options.fresh:
        for key in unique:
            shutil.rmtree(store.cells_dir(out) / key, ignore_errors=True)
    done = {k: row for k in unique if (row := store.finished(out, k)) is not None}
    reused = len(done)
    todo = [c for k, c in unique.items() if k not in done]
    failed: dict[str, str] = {}
    hosts: Counter = Counter()
    start = time.perf_counter()
    bar = _bar(len(unique), reused, options.progress)
    try:
        backend.submit(todo, out, code)
        waiting = {k for k in unique if k not in done}
        while waiting:
            running = backend.running(out, waiting)
            bar.set_postfix_str(f"done {len(done)} running {running} failed {len(failed)}")
            for o in backend.poll(POLL_S):
                waiting.discard(o.key)
                bar.update(1)
                if o.error is None and store.finished(out, o.key) is None:
                    o = replace(o, row=None, error=_not_shared(out, o.key, o.host))
                if o.error is None:
                    done[o.key] = o.row
                    hosts[o.host] += 1
                else:
                    failed[o.key] = o.error
        bar.set_postfix_str(f"done {len(done)} running 0 failed {len(failed)}")
    finally:
        bar.close()
        backend.close()
    # Attempts of failed cells and those that lost the race to a retry: nothing half-written.
    store.remove_attempts(out, set(unique))
    result = SweepResult(
        rows=[{**c.labels, **done[k]} for c, k in zip(cells, keys) if k in done],
        failures=[(c, failed[k]) for k, c in unique.items() if k in failed],
        executed=len(todo),
        reused=reused,
    )
    summary = {
        "out": str(out),
        "code_version": code,
        "backend": backend.description,
        "cells": len(unique),
        "executed": result.executed,
        "reused": reused,
        "failed": [{"key": c.key(code), "scene": c.scene, "error": e} for c, e in result.failures],
        "wall_seconds": round(time.perf_counter() - start, 2),
        "datasets": sorted({str(c.data) for c in unique.values()}),
        "written_by": dict(hosts),
        "object_store_bytes": backend.object_store_bytes(),
    }
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2))
    print("\n".join(summary_lines(summary)), flush=True)
    return result


def summary_lines(s: dict) -> list[str]:
    """The sweep's summary: counts, what went where, and one line per failed cell."""
    lines = [
        f"sweep {s['out']}: {s['cells']} cells, {s['executed'] - len(s['failed'])} run, "
        f"{s['reused']} reused (finished before), {len(s['failed'])} failed; "
        f"{s['wall_seconds']:.1f} s on {s['backend']}",
        f"  data: {len(s['datasets'])} dataset folder(s) read in place by the workers, not "
        "copied: " + ", ".join(s["datasets"]),
    ]
    if s["written_by"]:
        by = ", ".join(f"{h} ({n})" for h, n in sorted(s["written_by"].items()))
        lines.append(f"  runs: written to {s['out']}/cells/<key>/run by {by}")
    if s["object_store_bytes"]:
        lines.append(
            f"  through Ray's object store: {s['object_store_bytes'] / 1024:.1f} KiB "
            "(cell specs and result rows only)"
        )
    lines += [f"  failed: {f['key']}: {f['error']}" for f in s["failed"]]
    return lines


def _unique(cells: list[Cell], keys: list[str]) -> dict[str, Cell]:
    """The first cell of each key; one key for two datasets would mix their results."""
    unique: dict[str, Cell] = {}
    for cell, key in zip(cells, keys):
        first = unique.setdefault(key, cell)
        if first.data != cell.data:
            raise EvsplatError(
                f"datasets {first.data} and {cell.data} are both named {cell.scene!r} in one "
                "sweep; rename one folder"
            )
    return unique


def _not_shared(out: Path, key: str, host: str) -> str:
    return (
        f"finished on {host}, but {store.cells_dir(out) / key} is not visible here: the output "
        "folder must be on a path every worker and this machine share (docs/scale-out.md)"
    )


def _bar(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit="cell",
        desc="sweep",
        disable=not enabled,
        file=sys.stderr,
        dynamic_ncols=True,
    )
