"""The ``evsplat`` command line: one subcommand per module in ``evsplat.commands``."""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import tempfile

from evsplat import __version__, commands
from evsplat.errors import EvsplatError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="evsplat",
        description="4D reconstruction of fast dynamic scenes from a single event camera.",
    )
    parser.add_argument("--version", action="version", version=f"evsplat {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"evsplat.commands.{info.name}")
        name = info.name.replace("_", "-")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        # Not `run`: a subcommand's own positional argument may be called that (`export RUN`).
        p.set_defaults(command_run=module.run)
    return parser


def quiet_vulkan_loader() -> None:
    """Gives XDG_RUNTIME_DIR a harmless value where it is unset or not a folder, as
    scripts/setup.sh does: the Vulkan loader otherwise prints two `error:` lines before every
    command that renders, though nothing is wrong. Called before anything loads Vulkan."""
    if not os.path.isdir(os.environ.get("XDG_RUNTIME_DIR") or ""):
        os.environ["XDG_RUNTIME_DIR"] = tempfile.gettempdir()


def main(argv: list[str] | None = None) -> int:
    quiet_vulkan_loader()
    args = build_parser().parse_args(argv)
    try:
        return int(args.command_run(args) or 0)
    except EvsplatError as e:
        print(f"evsplat {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"evsplat {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
