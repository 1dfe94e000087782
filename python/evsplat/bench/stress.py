"""`evsplat bench stress`: property-based stress of every numeric component, and SIGKILL trials.

The harness is test code and lives in the repository's tests/stress/ (see its docstring); this
command runs it from the source checkout that evsplat is installed from (scripts/setup.sh
installs in place), and says so when there is none.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from evsplat.errors import EvsplatError

HELP = "property-based stress of every numeric component (NaN/Inf, crashes) and SIGKILL trials"

# python/evsplat/bench/stress.py -> the repository root, when installed in place.
CHECKOUT = Path(__file__).resolve().parents[3]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cases", type=int, default=10_000, help="total cases (default 10000; 0: none)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--components",
        default=None,
        help="comma-separated subset of the components (default: all; an unknown name lists them)",
    )
    parser.add_argument(
        "--kill-trials", type=int, default=0, help="SIGKILL trials of train/simulate/export"
    )


def run(args: argparse.Namespace) -> int:
    if not (CHECKOUT / "pyproject.toml").is_file() or not (CHECKOUT / "tests/stress").is_dir():
        raise EvsplatError(
            f"{CHECKOUT}: no source checkout with tests/stress/ here; the stress harness is test "
            "code: run `evsplat bench stress` from a clone installed with scripts/setup.sh"
        )
    if str(CHECKOUT) not in sys.path:
        sys.path.insert(0, str(CHECKOUT))  # the harness imports itself as tests.stress.*
    return importlib.import_module("tests.stress.suite").run(args)
