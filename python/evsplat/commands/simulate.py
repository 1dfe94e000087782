"""`evsplat simulate`: render a built-in dynamic scene, simulate its events, write a dataset."""

from __future__ import annotations

import argparse
import json
import re
import textwrap
import time

HELP = "render a built-in synthetic scene and simulate an event camera; writes a dataset folder"


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text.strip())
    if not m:
        raise argparse.ArgumentTypeError(f"'{text}' is not WIDTHxHEIGHT (e.g. 400x400)")
    return int(m.group(1)), int(m.group(2))


def _scene_list(width: int = 78) -> str:
    """The built-in scenes with their descriptions, for the help's epilog."""
    from evsplat.scenes import scene_descriptions
    from evsplat.scenes.drawn import SUMMARY

    rows = [
        textwrap.fill(text, width, initial_indent=f"  {name:<10} ", subsequent_indent=" " * 13)
        for name, text in scene_descriptions().items()
    ]
    drawn = textwrap.fill(
        SUMMARY,
        width,
        initial_indent=f"  {'drawn-N':<10} ",
        subsequent_indent=" " * 13,
    )
    return "built-in scenes:\n" + "\n".join([*rows, drawn])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from evsplat.scenes import scene_names

    # Raw epilog: keep one scene per entry instead of argparse's single re-wrapped paragraph.
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = _scene_list()
    parser.add_argument(
        "--scene", required=True, help=f"scene name: {', '.join(scene_names())}, or drawn-N"
    )
    parser.add_argument(
        "--out", required=True, help="output dataset folder (must not exist or be empty)"
    )
    parser.add_argument(
        "--speed",
        type=int,
        default=1,
        help="render K times fewer frames over the same motion (paper Table 2); default 1",
    )
    parser.add_argument(
        "--size",
        type=_size,
        default=None,
        help="image size WIDTHxHEIGHT (default: the scene's, 400x400 or 600x400)",
    )
    parser.add_argument(
        "--tiny", action="store_true", help="tiny variant (96 px, 0.6 s) for tests and the demo"
    )
    colour = parser.add_mutually_exclusive_group()
    colour.add_argument(
        "--color",
        dest="color",
        action="store_true",
        default=True,
        help="colour events through an RGGB Bayer filter (default)",
    )
    colour.add_argument("--mono", dest="color", action="store_false", help="monochrome sensor")
    parser.add_argument(
        "--seed", type=int, default=0, help="random seed for thresholds and noise (default 0)"
    )
    parser.add_argument(
        "--samples",
        type=int,
        default=None,
        help="rays per pixel side, odd; a pixel's colour is their mean over its area "
        "(default 3; 1 = one ray through each pixel centre, aliased edges)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from evsplat.data.simulator import simulate_dataset

    start = time.perf_counter()
    out = simulate_dataset(
        args.scene,
        args.out,
        speed=args.speed,
        size=args.size,
        color=args.color,
        seed=args.seed,
        tiny=args.tiny,
        progress=not args.no_progress,
        samples=args.samples,
    )
    meta = json.loads((out / "meta.json").read_text())
    wall = time.perf_counter() - start
    seconds = (meta["t_end_us"] - meta["t_start_us"]) * 1e-6
    print(
        f"{out}: {meta['scene']} {meta['width']}x{meta['height']} {meta['bayer']}, "
        f"{meta['num_events']} events over {seconds:.2f} s "
        f"({meta['num_events'] / seconds:.3g} ev/s), "
        f"{meta['rendered_frames']} frames, {wall:.1f} s"
    )
    return 0
