"""`evsplat render RUN --times a:b:step --out DIR`: images and depth over time, where the events
saw anything (observed.png; ``evsplat.observed``) and, with ``--objects``, the pixels each moving
object draws (``evsplat.object_output``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from evsplat.data.event_store import EventStore
    from evsplat.render import Renderer
    from evsplat.run_state import RunState

HELP = "render a trained run at many times (PNG, depth EXR + colour-mapped PNG, MP4)"


def parse_times(spec: str) -> np.ndarray:
    """``a:b:step`` (fractions of the sequence, b inclusive) or a comma list of fractions."""
    from evsplat.errors import EvsplatError

    try:
        if ":" in spec:
            a, b, step = (float(v) for v in spec.split(":"))
            if step <= 0:
                raise ValueError
            times = np.arange(a, b + step * 0.5, step)
        else:
            times = np.array([float(v) for v in spec.split(",")])
    except ValueError:
        raise EvsplatError(
            f"--times {spec!r}: expected a:b:step with step > 0 or a comma list, e.g. 0:1:0.05"
        ) from None
    if times.size == 0 or times.min() < 0 or times.max() > 1:
        raise EvsplatError(f"--times {spec!r}: times are fractions of the sequence in [0, 1]")
    return times


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run_dir", metavar="RUN", type=Path, help="run folder written by `evsplat train`"
    )
    parser.add_argument("--times", default="0:1:0.05", help="a:b:step fractions of the sequence")
    parser.add_argument(
        "--pose",
        type=Path,
        default=None,
        help="TUM file with one c2w pose to render from (default: the training trajectory)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--video",
        action="store_true",
        help="also write render.mp4 and, when the run's dataset is found, render_events.mp4 "
        "(render | events around each time | depth)",
    )
    parser.add_argument("--fps", type=float, default=20.0, help="frame rate of the videos")
    parser.add_argument(
        "--show-unobserved",
        action="store_true",
        help="draw the pixels that saw no event as rendered (default: background grey, see "
        "observed.png)",
    )
    parser.add_argument(
        "--objects",
        action="store_true",
        help="also write each frame's moving objects: labels_N.png (0 none, k+1 the run's "
        "object k; 8-bit grey) and objects_N.png (the frame, each object tinted as in track.png)"
        "; with --video, objects.mp4",
    )


def run(args: argparse.Namespace) -> int:
    import torch

    from evsplat.data.images import write_exr, write_png
    from evsplat.data.poses import read_tum
    from evsplat.errors import EvsplatError
    from evsplat.object_output import object_labels, tinted
    from evsplat.observed import masked, observed_map
    from evsplat.render import Renderer
    from evsplat.video import colour_depth

    if args.out.exists() and not args.out.is_dir():
        raise EvsplatError(f"--out {args.out}: exists and is not a folder; choose a folder path")
    if args.video and not (args.fps > 0 and np.isfinite(args.fps)):
        raise EvsplatError(f"--fps {args.fps:g}: must be a positive frame rate")
    renderer, state = Renderer.from_run(args.run_dir)
    fractions = parse_times(args.times)
    span = renderer.t_end_us - renderer.t_start_us
    trajectory = state.poses.trajectory()
    fixed = read_tum(args.pose)[1][0] if args.pose is not None else None
    args.out.mkdir(parents=True, exist_ok=True)
    events = _run_events(state)
    observed = None
    if events is not None:
        seen = observed_map(events, renderer.t_start_us, renderer.t_end_us, state.heldout)
        write_png(args.out / "observed.png", seen.astype(np.float32))
        print(
            f"observed.png: {seen.mean():.1%} of the pixels saw events in training's data"
            + ("" if args.show_unobserved else "; the others are drawn background grey")
        )
        observed = None if args.show_unobserved else seen
    objects = _objects(args, renderer)
    frames, tints = [], []
    for i, frac in enumerate(fractions):
        t_us = renderer.t_start_us + float(frac) * span
        c2w = fixed if fixed is not None else trajectory.pose(t_us)
        with torch.no_grad():
            out = renderer.render(t_us, c2w)
        img = out.image.clamp(0, 1).numpy()
        if observed is not None:
            img = masked(img, observed, renderer.background)
        write_png(args.out / f"frame_{i:05d}.png", img[..., 0] if img.shape[-1] == 1 else img)
        depth = out.depth.numpy()
        write_exr(args.out / f"depth_{i:05d}.exr", depth)
        write_png(args.out / f"depth_{i:05d}.png", colour_depth(depth))
        if args.video:
            frames.append((t_us, img, colour_depth(depth)))
        if objects is not None:
            labels = object_labels(renderer, t_us, c2w)
            write_png(args.out / f"labels_{i:05d}.png", labels / 255.0)
            tints.append(tinted(img, labels, objects))
            write_png(args.out / f"objects_{i:05d}.png", tints[-1])
    print(f"rendered {len(fractions)} frames to {args.out}")
    if args.video:
        _write_videos(args, events, frames, span * _step(fractions))
    if tints and args.video:
        from evsplat.video import write_mp4

        n = write_mp4(args.out / "objects.mp4", tints, args.fps)
        print(f"wrote {args.out / 'objects.mp4'} ({n} frames)")
    return 0


def _objects(args: argparse.Namespace, renderer: Renderer) -> np.ndarray | None:
    """The objects' colours [K,3] when ``--objects`` asks for their labels (said so), else None."""
    from evsplat.errors import EvsplatError
    from evsplat.object_output import object_count
    from evsplat.plots import track_colour, track_colour_name

    if not args.objects:
        return None
    k = object_count(renderer)
    if k > 255:  # labels are 8-bit
        raise EvsplatError(f"--objects: the run has {k} objects; labels_N.png hold at most 255")
    names = ", ".join(f"{i + 1} = object {i} ({track_colour_name(i)})" for i in range(k))
    print(f"labels_N.png: 0 = no object, {names}" if k else "the run has no moving objects")
    return np.stack([track_colour(i) for i in range(max(k, 1))])


def _run_events(state: RunState) -> EventStore | None:
    """The events of the run's dataset (for observed.png and render_events.mp4), or None
    (said so) when its folder is no longer where training read it."""
    from evsplat.data.dataset import load_dataset
    from evsplat.errors import EvsplatError

    data_dir = Path(state.dataset)
    if not (data_dir / "events.h5").is_file():
        print(f"no dataset at {data_dir}: no observed.png, no render_events.mp4")
        return None
    try:
        return load_dataset(data_dir).events
    except EvsplatError as e:
        print(f"dataset {data_dir} does not load ({e}): no observed.png, no render_events.mp4")
        return None


def _step(fractions: np.ndarray) -> float:
    """The spacing of the rendered times (a sequence fraction); 1/20 for a single time."""
    return float(np.median(np.diff(fractions))) if len(fractions) > 1 else 0.05


def _write_videos(
    args: argparse.Namespace, events: EventStore | None, frames: list, window_us: float
) -> None:
    """render.mp4, and render_events.mp4 (render | events of each frame's interval | depth)
    when the run's ``events`` were found."""
    from evsplat.video import event_frame, hstack_images, write_mp4

    n = write_mp4(args.out / "render.mp4", (img for _, img, _ in frames), args.fps)
    print(f"wrote {args.out / 'render.mp4'} ({n} frames, {args.fps:g} fps)")
    if events is None:
        return

    def panels():
        for t_us, img, depth in frames:
            ev = events.read(int(t_us - window_us / 2), int(t_us + window_us / 2))
            yield hstack_images(img, event_frame(ev, 0, len(ev)), depth)

    n = write_mp4(args.out / "render_events.mp4", panels(), args.fps)
    print(f"wrote {args.out / 'render_events.mp4'} ({n} frames: render | events | depth)")
