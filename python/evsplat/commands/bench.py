"""`evsplat bench SUITE`: benchmarks that print tables; one module per suite in evsplat.bench."""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from evsplat import bench

HELP = "run a benchmark suite and print its table (suites: see `evsplat bench --help`)"


def _suites() -> dict[str, object]:
    return {
        m.name: importlib.import_module(f"evsplat.bench.{m.name}")
        for m in pkgutil.iter_modules(bench.__path__)
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="suite", metavar="SUITE", required=True)
    for name, module in sorted(_suites().items()):
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(suite_run=module.run)


def run(args: argparse.Namespace) -> int:
    return int(args.suite_run(args) or 0)
