"""`evsplat export RUN --time T --ply OUT`: the Gaussians at one time as a 3DGS PLY;
`evsplat export RUN --times a:b:step --ply-dir DIR`: a sequence of them (ply_00000.ply, ...);
`evsplat export RUN --tracks OUT.csv [--times a:b:step]`: each moving object's rigid pose over
time (``evsplat.object_output``)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "export the Gaussians at a time as a standard 3DGS PLY, or the moving objects' tracks"
TRACK_TIMES = "0:1:0.01"  # --tracks' times unless given: every hundredth of the sequence


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
    parser.add_argument(
        "--tracks",
        type=Path,
        default=None,
        help=f"CSV of each moving object's rigid pose at --times (default {TRACK_TIMES}): per "
        "time and object, its world position and rotation, the pixel it projects to and its "
        "depth, and how visible it is",
    )


def run(args: argparse.Namespace) -> int:
    from evsplat.errors import EvsplatError
    from evsplat.export import export_ply
    from evsplat.render import Renderer

    outputs = [args.ply, args.ply_dir, args.tracks]
    if (
        sum(o is not None for o in outputs) != 1
        or (args.ply_dir is not None and args.times is None)
        or (args.ply is not None and args.times is not None)
    ):
        raise EvsplatError(
            "export: give --ply OUT, or --times a:b:step with --ply-dir DIR, or --tracks OUT.csv"
        )
    if args.ply_dir is not None:
        return _sequence(args)
    if args.tracks is not None:
        return _tracks(args)
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


def _tracks(args: argparse.Namespace) -> int:
    """The objects' poses at ``--times`` as CSV (``object_output.TRACK_COLUMNS``), atomically."""
    from evsplat.commands.render import parse_times
    from evsplat.data.atomic import write_text_atomic
    from evsplat.object_output import TRACK_COLUMNS, object_count, object_poses
    from evsplat.render import Renderer

    fractions = parse_times(args.times or TRACK_TIMES)
    renderer, state = Renderer.from_run(args.run_dir)
    trajectory = state.poses.trajectory()
    span = renderer.t_end_us - renderer.t_start_us
    rows = [TRACK_COLUMNS]
    for frac in fractions:
        t_us = renderer.t_start_us + float(frac) * span
        rows += [pose.csv_row() for pose in object_poses(renderer, t_us, trajectory)]
    write_text_atomic(args.tracks, "\n".join(rows) + "\n")
    k = object_count(renderer)
    print(f"wrote {k} objects' poses at {len(fractions)} times to {args.tracks}")
    return 0
