"""`evsplat export RUN --time T --ply OUT`: the Gaussians at one time as a 3DGS PLY;
`evsplat export RUN --times a:b:step --ply-dir DIR`: a sequence of them (ply_00000.ply, ...)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "export the Gaussians at a time as a standard 3DGS PLY"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run_dir", metavar="RUN", type=Path, help="run folder written by `evsplat train`"
    )
    parser.add_argument(
        "--time", type=float, default=0.5, help="time as a fraction of the sequence (0..1)"
    )
    parser.add_argument("--ply", type=Path, default=None, help="output .ply path")
    parser.add_argument(
        "--times", default=None, help="a:b:step fractions for a PLY sequence (with --ply-dir)"
    )
    parser.add_argument("--ply-dir", type=Path, default=None, help="folder for a PLY sequence")


def run(args: argparse.Namespace) -> int:
    from evsplat.errors import EvsplatError
    from evsplat.export import export_ply
    from evsplat.render import Renderer

    if (args.ply is None) == (args.ply_dir is None) or (args.times is None) != (
        args.ply_dir is None
    ):
        raise EvsplatError("export: give --ply OUT, or --times a:b:step with --ply-dir DIR")
    if args.ply_dir is not None:
        return _sequence(args)
    if not 0.0 <= args.time <= 1.0:
        raise EvsplatError(f"--time {args.time}: must be a fraction of the sequence in [0, 1]")
    renderer, _ = Renderer.from_run(args.run_dir)
    t_us = renderer.t_start_us + args.time * (renderer.t_end_us - renderer.t_start_us)
    n = export_ply(args.run_dir, t_us, args.ply)
    print(f"wrote {n} Gaussians at t = {t_us / 1e6:.6f} s to {args.ply}")
    return 0


def _sequence(args: argparse.Namespace) -> int:
    """One PLY per time of ``--times``, plus times.txt (index, time in µs)."""
    from evsplat.commands.render import parse_times
    from evsplat.data.atomic import write_text_atomic
    from evsplat.export import gaussian_arrays, write_ply
    from evsplat.render import Renderer

    fractions = parse_times(args.times)
    renderer, _ = Renderer.from_run(args.run_dir)
    span = renderer.t_end_us - renderer.t_start_us
    args.ply_dir.mkdir(parents=True, exist_ok=True)
    lines = []
    for i, frac in enumerate(fractions):
        t_us = renderer.t_start_us + float(frac) * span
        write_ply(args.ply_dir / f"ply_{i:05d}.ply", gaussian_arrays(renderer, t_us))
        lines.append(f"{i} {t_us:.1f}\n")
    write_text_atomic(args.ply_dir / "times.txt", "".join(lines))
    print(f"wrote {len(fractions)} PLYs to {args.ply_dir}")
    return 0
