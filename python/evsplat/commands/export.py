"""`evsplat export RUN --time T --ply OUT`: the Gaussians at one time as a 3DGS PLY."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "export the Gaussians at a time as a standard 3DGS PLY"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run folder written by `evsplat train`")
    parser.add_argument(
        "--time", type=float, default=0.5, help="time as a fraction of the sequence (0..1)"
    )
    parser.add_argument("--ply", type=Path, required=True, help="output .ply path")


def run(args: argparse.Namespace) -> int:
    from evsplat.errors import EvsplatError
    from evsplat.export import export_ply
    from evsplat.render import Renderer

    if not 0.0 <= args.time <= 1.0:
        raise EvsplatError(f"--time {args.time}: must be a fraction of the sequence in [0, 1]")
    renderer, _ = Renderer.from_run(args.run)
    t_us = renderer.t_start_us + args.time * (renderer.t_end_us - renderer.t_start_us)
    n = export_ply(args.run, t_us, args.ply)
    print(f"wrote {n} Gaussians at t = {t_us / 1e6:.6f} s to {args.ply}")
    return 0
