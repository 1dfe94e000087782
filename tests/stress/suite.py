"""The stress components, the run over them, and the table `evsplat bench stress` prints."""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from evsplat.errors import EvsplatError
from tests.stress.cases_events import event_cases, spline_cases
from tests.stress.cases_losses import colour_fit_cases, loss_cases
from tests.stress.cases_model import model_cases, raster_cases
from tests.stress.harness import Case, Tally, check_case
from tests.stress.kill import kill_trials

# The share of the total case count each component gets (the rasterizer is the slowest per call).
COMPONENTS: dict[str, tuple[Callable[[np.random.Generator, int], Iterator[Case]], float]] = {
    "events": (event_cases, 0.30),
    "spline": (spline_cases, 0.15),
    "losses": (loss_cases, 0.25),
    "colour_fit": (colour_fit_cases, 0.10),
    "model": (model_cases, 0.12),
    "raster": (raster_cases, 0.08),
}


def run_stress(
    total: int, seed: int = 0, components: Sequence[str] | None = None
) -> dict[str, Tally]:
    """Run about ``total`` cases split over ``components`` by their shares; a Tally for each."""
    names = list(components or COMPONENTS)
    share = sum(COMPONENTS[c][1] for c in names)
    tallies = {}
    for k, name in enumerate(names):
        gen, weight = COMPONENTS[name]
        rng = np.random.default_rng([seed, k])
        tally = Tally()
        for case in gen(rng, max(1, round(total * weight / share))):
            check_case(case, tally)
        tallies[name] = tally
    return tallies


def format_tallies(tallies: dict[str, Tally], seconds: dict[str, float] | None = None) -> str:
    """The per-component table the bench prints."""
    rows = ["component | cases | finite | refused (clear error) | NaN/Inf | failures | seconds"]
    tot = Tally()
    for name, t in tallies.items():
        s = f"{seconds[name]:.1f}" if seconds else "-"
        rows.append(
            f"{name} | {t.cases} | {t.finite} | {t.refused} | {t.nonfinite} | {t.failed} | {s}"
        )
        tot.cases, tot.finite, tot.refused = (
            tot.cases + t.cases,
            tot.finite + t.finite,
            tot.refused + t.refused,
        )
        tot.nonfinite += t.nonfinite
        tot.failures += t.failures
    rows.append(
        f"total | {tot.cases} | {tot.finite} | {tot.refused} | {tot.nonfinite} | {tot.failed} | -"
    )
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    """The bench: a table of the cases of each component, then the SIGKILL trials; 1 on any
    failure or corrupt output."""
    names = args.components.split(",") if args.components else list(COMPONENTS)
    unknown = [c for c in names if c not in COMPONENTS]
    if unknown:
        raise EvsplatError(
            f"--components: unknown {', '.join(unknown)}; choose from {', '.join(COMPONENTS)}"
        )
    tallies, seconds = {}, {}
    for name in names if args.cases > 0 else []:
        t = time.perf_counter()
        share = COMPONENTS[name][1] / sum(COMPONENTS[c][1] for c in names)
        tallies.update(run_stress(max(1, round(args.cases * share)), args.seed, [name]))
        seconds[name] = time.perf_counter() - t
    print(format_tallies(tallies, seconds))
    failures = [f for t in tallies.values() for f in t.failures]
    for f in failures[:50]:
        print(f"FAIL {f}")
    nan = sum(t.nonfinite for t in tallies.values())
    print(f"NaN/Inf found: {nan}; failures: {len(failures)}")
    corrupt = 0
    if args.kill_trials > 0:
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            rep = kill_trials(args.kill_trials, Path(tmp), args.seed)
            wall = time.perf_counter() - t
        corrupt = len(rep.corrupt)
        per = ", ".join(f"{k} {v}" for k, v in rep.trials.items())
        print(
            f"SIGKILL trials: {sum(rep.trials.values())} ({per}); killed mid-run "
            f"{rep.killed_mid_run}; resumed {rep.resumed}; corrupt outputs found: {corrupt}; "
            f"{wall:.0f} s"
        )
        for c in rep.corrupt:
            print(f"CORRUPT {c}")
    return 1 if failures or corrupt else 0
