"""`evsplat view RUN [--port P]`: the interactive 4D viewer (viser) on 127.0.0.1."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

HELP = "serve an interactive 4D viewer of a trained run in the browser (127.0.0.1 only)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run_dir", metavar="RUN", type=Path, help="run folder written by `evsplat train`"
    )
    parser.add_argument("--port", type=int, default=8080, help="port on 127.0.0.1")


def run(args: argparse.Namespace) -> int:
    from evsplat.viewer import open_viewer

    viewer = open_viewer(args.run_dir, args.port)
    print(f"evsplat viewer of {args.run_dir} at {viewer.url} (Ctrl-C stops it)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    finally:
        viewer.stop()
