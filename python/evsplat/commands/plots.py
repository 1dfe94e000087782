"""`evsplat plots RUN`: loss curves (from log.jsonl) and metric-vs-time (from eval.json)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "draw a run's loss curves and, after `evsplat eval`, its metrics against time"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run_dir", metavar="RUN", type=Path, help="run folder written by `evsplat train`"
    )
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: RUN)")


def _json_lines(path: Path) -> list[dict]:
    from evsplat.errors import EvsplatError

    rows = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as e:
            raise EvsplatError(
                f"{path}: line {n} is not JSON ({e.msg}); the log is damaged"
            ) from None
        if not isinstance(row, dict) or "iteration" not in row or "stage" not in row:
            raise EvsplatError(f"{path}: line {n} lacks 'iteration'/'stage'; not a training log")
        rows.append(row)
    return rows


def plot_metrics_vs_time(result: dict, out: Path) -> None:
    """PSNR, SSIM and LPIPS of each evaluated frame against its time (s from the first)."""
    from evsplat.data.atomic import write_atomic
    from evsplat.plots import _pyplot

    plt = _pyplot()
    frames = sorted(result["frames"], key=lambda r: r["time_us"])
    t0 = frames[0]["time_us"]
    t = [(r["time_us"] - t0) / 1e6 for r in frames]
    keys = [
        k for k in ("psnr", "psnr_moving", "ssim", "lpips") if any(r[k] is not None for r in frames)
    ]
    fig, axes = plt.subplots(len(keys), 1, figsize=(7, 2.2 * len(keys)), sharex=True, squeeze=False)
    for ax, k in zip(axes[:, 0], keys):
        pts = [(ti, r[k]) for ti, r in zip(t, frames) if r[k] is not None]
        ax.plot(*zip(*pts), "o-", ms=3, lw=1.2)
        ax.set_ylabel(k.upper().replace("_MOVING", " moving"))
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time since first test frame (s)")
    axes[0, 0].set_title("metrics against time (held-out test frames)")
    fig.tight_layout()
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from evsplat.errors import EvsplatError
    from evsplat.plots import plot_losses

    log = args.run_dir / "log.jsonl"
    if not log.is_file():
        raise EvsplatError(f"{log}: missing; run `evsplat train` into {args.run_dir} first")
    history = _json_lines(log)
    if not history:
        raise EvsplatError(f"{log}: no iterations logged yet; train longer")
    out = args.out or args.run_dir
    out.mkdir(parents=True, exist_ok=True)
    plot_losses(history, out / "losses.png")
    print(f"wrote {out / 'losses.png'} ({len(history)} logged iterations)")
    ev = args.run_dir / "eval.json"
    if ev.is_file():
        try:
            result = json.loads(ev.read_text(encoding="utf-8"))
            frames = result["frames"]
        except (json.JSONDecodeError, KeyError, TypeError):
            raise EvsplatError(f"{ev}: not an eval result; rerun `evsplat eval`") from None
        if frames:
            plot_metrics_vs_time(result, out / "metrics_vs_time.png")
            print(f"wrote {out / 'metrics_vs_time.png'} ({len(frames)} test frames)")
    else:
        print(f"no {ev}: run `evsplat eval {args.run_dir} DATA` for the metric-vs-time plot")
    return 0
