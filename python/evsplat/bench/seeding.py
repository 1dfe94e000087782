"""`evsplat bench seeding`: the motion module's objects against the simulator's true paths, in
minutes rather than a training run's hour.

Per scene (its tiny variant, simulated once under ``--out``): one warm-up, then the first look
(``motion.seed.seed_objects``) with the defaults and with each ``--against`` setting, from the
same warm-up, so the table compares settings on the same evidence. Each true object is matched to
the seeded object whose centre (its Gaussians' mean, carried along its rigid path) projects
nearest to the true centre over the times the true centre is in the image; the table gives that
distance's median, its median less the median offset (a region's centre is where its events
were, not the object's centre: the Gaussians take a steady offset up) and its 90th percentile.
No colour, no Gaussians' shape: what training starts the paths from.
"""

from __future__ import annotations

import argparse
import copy
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsplat.bench.train import Case, fmt, machine_info, simulate_cases

HELP = "the seeding's objects against the simulator's true paths, per scene and setting"
TIMES = 49  # scoring times spread over the sequence (about one per segmentation window)
DEFAULT_SCENES = ("ball", "crossing", "tumble", "spinner", "watch", "enter_leave", "pair")


@dataclass
class Score:
    """One true object's match among the seeded objects, in px (None: none seeded or never in
    view)."""

    scene: str
    setting: str
    objects: int  # seeded objects in the scene
    name: str
    matched: int | None
    median: float | None
    steady: float | None  # median less the median offset
    p90: float | None
    seconds: float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenes",
        default=",".join(DEFAULT_SCENES),
        help=f"comma-separated built-in scenes (default {','.join(DEFAULT_SCENES)})",
    )
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    parser.add_argument(
        "--iters", type=int, default=2000, help="the schedule whose warm-up runs (default 2000)"
    )
    parser.add_argument(
        "--against",
        action="append",
        default=[],
        metavar="'KEY=VALUE ...'",
        help="a setting to compare with the defaults (repeatable; e.g. 'mover.join=0.25')",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bench-seeding"), help="datasets and warm-up runs"
    )


def projected_errors(found: np.ndarray, truth: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """[K] median px distance of each seeded object's centres ``found`` [K,T,2] from the true
    ones ``truth`` [T,2] over the times ``seen`` [T] (inf where none is seen)."""
    if not seen.any():
        return np.full(len(found), np.inf)
    return np.median(np.linalg.norm(found[:, seen] - truth[None, seen], axis=-1), axis=1)


def match_score(found: np.ndarray, truth: np.ndarray, seen: np.ndarray) -> tuple:
    """(the nearest seeded object, its median, median less its median offset, 90th percentile
    px) for one true object; Nones where nothing was seeded or it is never seen."""
    errors = projected_errors(found, truth, seen)
    if not len(found) or not np.isfinite(errors).any():
        return None, None, None, None
    k = int(np.argmin(errors))
    off = found[k, seen] - truth[seen]
    dist = np.linalg.norm(off, axis=1)
    steady = np.linalg.norm(off - np.median(off, axis=0), axis=1)
    return k, float(np.median(dist)), float(np.median(steady)), float(np.quantile(dist, 0.9))


def _scores(scene: str, data_dir: Path, args: argparse.Namespace) -> list[Score]:
    import torch

    from evsplat.config import preset
    from evsplat.config_fields import apply
    from evsplat.data.dataset import load_dataset
    from evsplat.projection import project
    from evsplat.train.loop import Trainer

    data = load_dataset(data_dir)
    cfg = preset("tiny")
    cfg.seed, cfg.schedule.iterations, cfg.schedule.grad_norms_every = args.seed, args.iters, 0
    trainer = Trainer(data, cfg, args.out / "warm" / scene)
    for it in range(cfg.schedule.warmup_end):
        trainer.step(it)
    trainer.renderer.mlp = None  # the warm-up's static model, as the seeding sees it
    names = ("means", "log_scales", "quats", "opacity_logits", "sh", "t_mean", "t_log_scale")
    warm = {k: getattr(trainer.model, k).detach().clone() for k in names}
    times = np.linspace(data.t_start_us, data.t_end_us, TIMES + 2)[1:-1]
    poses = data.trajectory.pose(times)
    out = []
    for setting in ["defaults", *args.against]:
        for k, v in warm.items():  # every setting starts from the same warm-up
            getattr(trainer.model, k).data = v.clone()
        trainer.optimizer = trainer.gaussians_adam()
        trainer.cfg = apply(copy.deepcopy(cfg), [] if setting == "defaults" else setting.split())
        start = time.perf_counter()
        trainer.seed_objects()
        seconds = time.perf_counter() - start
        motion = trainer.renderer.motion
        found = np.zeros((0, len(times), 2))
        if motion is not None:
            with torch.no_grad():
                at = [
                    (motion.centres + motion.at(trainer.renderer.time(t))[1]).cpu().numpy()
                    for t in times
                ]
            found = np.stack(
                [project(c.astype(np.float64), p, data.K)[0] for c, p in zip(at, poses)], 1
            )
        trainer.renderer.motion = trainer.renderer.object_id = trainer.renderer.static_mask = None
        trainer.renderer.mlp = None
        for track in data.tracks:
            centres = np.stack(
                [np.interp(times, track.times_us, track.centres[:, j]) for j in range(3)], 1
            )
            truth = np.stack([project(c[None], p, data.K)[0][0] for c, p in zip(centres, poses)])
            seen = (truth >= 0).all(1) & (truth[:, 0] < data.width) & (truth[:, 1] < data.height)
            k, median, steady, p90 = match_score(found, truth, seen)
            out.append(
                Score(scene, setting, len(found), track.name, k, median, steady, p90, seconds)
            )
    return out


def table(scores: list[Score]) -> list[str]:
    """The markdown table of ``scores``."""
    lines = [
        "| scene | setting | objects | true object | matched | median px | less offset | 90% px "
        "| seeding s |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for s in scores:
        others = [o for o in scores if o is not s and (o.scene, o.setting) == (s.scene, s.setting)]
        shared = s.matched is not None and any(o.matched == s.matched for o in others)
        matched = "-" if s.matched is None else f"{s.matched}{' (shared)' if shared else ''}"
        cells = [s.scene, s.setting, str(s.objects), s.name, matched]
        cells += [fmt(s.median, 1), fmt(s.steady, 1), fmt(s.p90, 1), fmt(s.seconds, 1)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def run(args: argparse.Namespace) -> int:
    from evsplat.config import preset
    from evsplat.config_fields import apply
    from evsplat.errors import EvsplatError
    from evsplat.scenes import scene_names

    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in scenes if s not in scene_names()]
    if unknown:
        raise EvsplatError(f"--scenes: unknown {', '.join(unknown)}; see `evsplat simulate --help`")
    for setting in args.against:  # a misspelt setting fails now, not after the warm-ups
        apply(preset("tiny"), setting.split())
    print(" | ".join(f"{k}: {v}" for k, v in machine_info().items()), flush=True)
    paths = simulate_cases([Case(s, tiny=True) for s in scenes], args.out)
    scores = []
    for scene in scenes:
        scores += _scores(scene, paths[Case(scene, tiny=True).name], args)
        print("\n".join(table([s for s in scores if s.scene == scene])[2:]), flush=True)
    print("\n".join(table(scores)))
    return 0
