"""`evsplat config show [--preset P] [--set KEY=VALUE ...]`: the resolved training configuration,
every setting with its value and its one-line meaning."""

from __future__ import annotations

import argparse

HELP = "print the training configuration a preset (--config, --set) resolves to, with meanings"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from evsplat.commands.train import add_config_arguments

    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    show = sub.add_parser("show", help="every setting as KEY = VALUE  # meaning", description=HELP)
    add_config_arguments(show)


def run(args: argparse.Namespace) -> int:
    from evsplat.commands.train import config_from_args
    from evsplat.config_fields import describe

    cfg = config_from_args(args)
    if args.iters is not None:
        cfg.schedule.iterations = args.iters
    print(describe(cfg))
    return 0
