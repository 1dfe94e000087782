"""`evsplat bench [SUITE]`: benchmarks that print tables; one module per suite in evsplat.bench.

Without a suite, `evsplat bench --preset P` runs the training benchmark (run time against error).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from evsplat import bench

HELP = "run a benchmark suite and print its table (default suite: train)"
DEFAULT_SUITE = "train"


def _suites() -> dict[str, object]:
    return {
        m.name: importlib.import_module(f"evsplat.bench.{m.name}")
        for m in pkgutil.iter_modules(bench.__path__)
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    suites = _suites()
    # The default suite's options also work without naming it: `evsplat bench --preset quick`.
    suites[DEFAULT_SUITE].add_arguments(parser)
    sub = parser.add_subparsers(dest="suite", metavar="SUITE")
    for name, module in sorted(suites.items()):
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(suite_run=module.run)


def run(args: argparse.Namespace) -> int:
    if args.suite is None:
        return int(_suites()[DEFAULT_SUITE].run(args) or 0)
    return int(args.suite_run(args) or 0)
