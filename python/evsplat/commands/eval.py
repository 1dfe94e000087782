"""`evsplat eval RUN DATA`: PSNR/SSIM/LPIPS on the held-out intermediate frames, next to a
flat image's, under two colour-fit protocols, and the moving object's tracking error; without
frames (or with held-out event windows), how well the run predicts events."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = (
    "score a trained run on a dataset's held-out test frames (table, JSON and, with tracked "
    "objects, track.png and segmentation.png)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run folder written by `evsplat train`")
    parser.add_argument(
        "data", type=Path, help="dataset folder (test/frames.json scored where it has one)"
    )
    parser.add_argument("--out", type=Path, default=None, help="where eval.json/eval.md go")


def run(args: argparse.Namespace) -> int:
    from evsplat.eval import evaluate_run, format_table, headline

    result = evaluate_run(args.run, args.data, args.out)
    print(format_table(result), end="")
    print(headline(result))
    out = args.out or args.run
    pictures = ["track.png", "segmentation.png"] if result.get("objects") else []
    written = ["eval.json", "eval.md", *pictures]
    print("written: " + ", ".join(str(out / name) for name in written))
    return 0
