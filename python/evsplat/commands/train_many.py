"""`evsplat train-many DATA_GLOB --out RUNS`: one training run per recording (and seed), on the
sweep runner: resumable, locally or on a Ray cluster with `--ray` (docs/scale-out.md)."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

HELP = "train every dataset folder a glob matches (one run each; resumable; --ray for a cluster)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from evsplat.commands.train import add_config_arguments
    from evsplat.sweep import add_sweep_arguments

    parser.add_argument(
        "data_glob",
        metavar="DATA_GLOB",
        help="dataset folders, as a quoted glob (e.g. 'recordings/*'); see docs/dataset.md",
    )
    parser.add_argument("--out", type=Path, required=True, help="sweep folder to write")
    add_config_arguments(parser)
    parser.add_argument("--seeds", default="0", help="comma list of seeds, one run each (0)")
    parser.add_argument("--depth-prior", default="auto", help="as for `evsplat train`")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_sweep_arguments(parser)


def dataset_folders(pattern: str) -> dict[str, Path]:
    """Folders the glob matches, by scene name: the folder's name, or its path below the
    glob's fixed part where two names repeat."""
    from evsplat.errors import EvsplatError

    found = sorted(Path(p).resolve() for p in glob.glob(pattern) if Path(p).is_dir())
    if not found:
        raise EvsplatError(
            f"{pattern!r} matches no folder; quote the glob and point it at dataset folders "
            "(e.g. 'recordings/*')"
        )
    names = [p.name for p in found]
    if len(set(names)) < len(names):
        fixed = Path(pattern.split("*")[0].split("?")[0].split("[")[0]).resolve()
        base = fixed if fixed.is_dir() else fixed.parent
        names = ["_".join(p.relative_to(base).parts) for p in found]
    return dict(zip(names, found))


def parse_seeds(text: str) -> list[int]:
    from evsplat.errors import EvsplatError

    try:
        seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        seeds = []
    if not seeds:
        raise EvsplatError(f"--seeds {text!r}: expected a comma list of integers, e.g. 0,1,2")
    return seeds


def run(args: argparse.Namespace) -> int:
    from evsplat.bench.train import fmt
    from evsplat.commands.train import config_from_args
    from evsplat.errors import EvsplatError
    from evsplat.sweep import Cell, SweepOptions, run_sweep
    from evsplat.sweep.store import write_table

    cfg = config_from_args(args)
    if args.iters is not None:
        if args.iters < 1:
            raise EvsplatError(f"--iters {args.iters}: must be at least 1")
        cfg.schedule.iterations = args.iters
    train_args = ("--depth-prior", args.depth_prior)
    cells = [
        Cell(scene=name, data=path, config=cfg.to_dict(), seed=seed, train_args=train_args)
        for name, path in dataset_folders(args.data_glob).items()
        for seed in parse_seeds(args.seeds)
    ]
    sweep = run_sweep(cells, args.out, SweepOptions.from_args(args))
    if sweep.rows:
        print(f"{'scene':<24} {'seed':>4} {'iters':>6} {'time s':>8} {'PSNR':>6} {'SSIM':>6}  run")
        for r in sweep.rows:
            print(
                f"{r['scene']:<24} {r['seed']:>4} {r['iterations']:>6} {r['wall_seconds']:>8.1f} "
                f"{fmt(r['psnr']):>6} {fmt(r['ssim'], 3):>6}  {args.out / r['run']}"
            )
        written = write_table(args.out, sweep.rows, {"glob": args.data_glob})
        print(f"written: {', '.join(map(str, written))}")
    return sweep.exit_code
