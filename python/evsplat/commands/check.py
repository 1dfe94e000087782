"""`evsplat check DIR`: validate a dataset folder, one line per problem."""

from __future__ import annotations

import argparse
import sys

HELP = (
    "validate a dataset folder (events, poses, intrinsics, meta, test frames); exit 2 on problems"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="dataset folder (see docs/dataset.md)")


def run(args: argparse.Namespace) -> int:
    from evsplat.data.dataset import check_dataset

    problems = check_dataset(args.path)
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        print(f"{args.path}: {len(problems)} problem(s)", file=sys.stderr)
        return 2
    print(f"{args.path}: ok")
    return 0
