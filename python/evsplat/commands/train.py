"""`evsplat train DATA --out RUN`: event-only 4D training with checkpoints and --resume."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "train a deformable Gaussian scene on a dataset folder (events + poses)"


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """--preset, --config, --iters, --device and --set (shared with `evsplat train-many` and
    `evsplat config show`)."""
    from evsplat.config import PRESETS
    from evsplat.train.device import add_device_argument

    parser.add_argument("--preset", default="default", help=f"one of {', '.join(PRESETS)}")
    parser.add_argument(
        "--config", type=Path, default=None, help="a TrainConfig JSON (as in a run's config.json)"
    )
    parser.add_argument("--iters", type=int, default=None, help="override the iteration count")
    add_device_argument(parser, None)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set one setting, e.g. --set loss.w_motion=0.2 --set mover.enabled=false "
        "(repeatable; `evsplat config show` lists them all)",
    )


def config_from_args(args: argparse.Namespace):
    """The TrainConfig that --config or --preset names, on --device when given, with each
    --set applied."""
    from evsplat.config import load_config, preset
    from evsplat.config_fields import apply

    cfg = load_config(args.config) if args.config is not None else preset(args.preset)
    if args.device is not None:
        cfg.device = args.device
    return apply(cfg, args.set)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", type=Path, help="dataset folder (see docs/dataset.md)")
    parser.add_argument("--out", type=Path, required=True, help="run folder to write")
    add_config_arguments(parser)
    parser.add_argument("--resume", action="store_true", help="continue the newest checkpoint")
    parser.add_argument(
        "--checkpoint-every", type=int, default=None, help="iterations between checkpoints"
    )
    parser.add_argument(
        "--depth-prior",
        default="auto",
        help="none | auto | oracle | vggt | FOLDER of <time_us>.npy/.exr depth maps",
    )
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    parser.add_argument(
        "--temporal-opacity",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="time-local opacity for fast objects (default off; not in the paper, see "
        "docs/experiments/paper-tables.md)",
    )
    parser.add_argument(
        "--time-range",
        default=None,
        metavar="START:END",
        help="train on part of the recording: seconds from its start, either side may be "
        "empty (e.g. 2:5, 10:)",
    )
    parser.add_argument(
        "--holdout",
        default=None,
        metavar="N:LENGTH",
        help="hold N evenly spread event windows of LENGTH (a fraction of the sequence) out of "
        "training, for `evsplat eval` to score event prediction on (e.g. 8:0.02)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def parse_time_range(text: str) -> tuple[float | None, float | None]:
    """``START:END`` in seconds, either side empty for that end of the recording."""
    import math

    from evsplat.errors import EvsplatError

    try:
        ends = tuple(float(v) if v.strip() else None for v in text.split(":"))
    except ValueError:
        ends = ()
    if len(ends) != 2 or not all(v is None or math.isfinite(v) for v in ends):
        raise EvsplatError(
            f"--time-range {text!r}: expected START:END in seconds from the recording's start, "
            "e.g. 2:5 or 10: (either side may be empty)"
        )
    return ends


def parse_holdout(text: str) -> tuple[int, float]:
    """``N:LENGTH``: a window count and each window's length as a fraction of the sequence."""
    import math

    from evsplat.errors import EvsplatError

    try:
        count, length = text.split(":")
        n, frac = int(count), float(length)
    except ValueError:
        n, frac = -1, math.nan
    if n < 0 or not 0 < frac < 1:
        raise EvsplatError(
            f"--holdout {text!r}: expected N:LENGTH, N windows (0 = none) of LENGTH, a "
            "fraction of the sequence in (0, 1), e.g. 8:0.02"
        )
    return n, frac


def run(args: argparse.Namespace) -> int:
    from evsplat.train import train

    cfg = config_from_args(args)
    if args.seed is not None:
        cfg.seed = args.seed
    if args.temporal_opacity is not None:
        cfg.model.temporal_opacity = args.temporal_opacity
    if args.time_range is not None:
        cfg.time_range = parse_time_range(args.time_range)
    if args.holdout is not None:
        cfg.holdout.windows, cfg.holdout.length = parse_holdout(args.holdout)
    if args.checkpoint_every is not None:
        cfg.schedule.checkpoint_every = max(1, args.checkpoint_every)
    stats = train(
        args.data,
        args.out,
        config=cfg,
        iterations=args.iters,
        resume=args.resume,
        depth_prior=args.depth_prior,
        progress=not args.no_progress,
        device=args.device,
    )
    rate = stats.iterations / max(stats.seconds, 1e-9)
    print(
        f"trained {stats.iterations} iterations in {stats.seconds:.1f} s ({rate:.2f} it/s); "
        f"skipped: {stats.skipped_empty} empty windows, {stats.skipped_nonfinite} non-finite "
        f"steps; run folder {args.out}"
    )
    if stats.hot_pixels:
        print(f"left out the events of {stats.hot_pixels} hot pixels (`evsplat check` lists them)")
    return 0
