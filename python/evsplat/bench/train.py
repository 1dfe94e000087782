"""`evsplat bench train --preset quick|full|ablation|speed`: run time against error.

Each case (scene, size, speed factor) x variant (model/loss set) is simulated once and is a
cell of the sweep runner (`evsplat.sweep`: trained in its own process, evaluated on the
held-out frames, reused by a rerun; `--ray` runs the cells on a Ray cluster), recorded with
the machine, the adapter and the git commit. Writes results.csv, results.json and a
Pareto plot (time on x, PSNR on y, frontier drawn) into the output folder.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from evsplat.data.atomic import write_atomic
from evsplat.sweep import Cell, SweepOptions, add_sweep_arguments, run_sweep
from evsplat.sweep.store import write_table
from evsplat.train.device import add_device_argument

HELP = "train + evaluate scenes x variants; CSV, JSON and a time-vs-PSNR Pareto plot"


@dataclass(frozen=True)
class Case:
    scene: str
    tiny: bool = False
    speed: int = 1

    @property
    def name(self) -> str:
        return f"{self.scene}{'-tiny' if self.tiny else ''}-x{self.speed}"


def _static(cfg):
    cfg.deform = False


def _losses(*keep: str) -> Callable:
    """A variant that keeps only the named losses (L_e always stays)."""
    weights = {"ef": "w_flow", "m": "w_motion", "d": "w_depth", "ne": "w_non_event"}

    def apply(cfg):
        for key, field in weights.items():
            if key not in keep:
                setattr(cfg.loss, field, 0.0)
        if "ne" not in keep:
            cfg.loss.w_spatial = 0.0

    return apply


def _full(cfg):
    return None


VARIANTS: dict[str, Callable] = {
    "static": _static,  # event-only 3DGS without deformation (Event3GS-like baseline)
    "no-motion-losses": _losses("d", "ne"),  # the method without L_ef and L_m
    "e": _losses(),
    "e+ef": _losses("ef"),
    "e+ef+m": _losses("ef", "m"),
    "e+ef+m+d": _losses("ef", "m", "d"),
    "full": _full,
}

SCENES = ("butterfly", "duck", "clock", "ball")
PRESETS: dict[str, dict] = {
    "quick": {
        "cases": [Case("ball", tiny=True)],
        "variants": ["static", "e", "full"],
        "train_preset": "tiny",
        "iterations": 400,
    },
    "full": {
        "cases": [Case(s) for s in SCENES],
        "variants": ["static", "no-motion-losses", "full"],
        "train_preset": "default",
        "iterations": None,
    },
    "ablation": {
        "cases": [Case("ball", tiny=True)],
        "variants": ["e", "e+ef", "e+ef+m", "e+ef+m+d", "full"],
        "train_preset": "tiny",
        "iterations": None,
    },
    "speed": {
        "cases": [Case("ball", tiny=True, speed=k) for k in (1, 2, 3, 4)],
        "variants": ["full"],
        "train_preset": "tiny",
        "iterations": None,
    },
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", default="quick", choices=sorted(PRESETS))
    parser.add_argument("--out", type=Path, default=None, help="default bench_results/<preset>")
    parser.add_argument("--iters", type=int, default=None, help="override iterations per run")
    parser.add_argument("--variants", default=None, help="comma list to run a subset")
    add_device_argument(parser, "auto")
    add_sweep_arguments(parser)


def machine_info() -> dict:
    """Machine, adapter and commit, recorded with every benchmark's numbers."""
    from evsplat.gpu import adapter_label

    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.platform()}",
        "adapter": adapter_label(),
        "commit": commit,
        "python": platform.python_version(),
    }


def simulate_cases(cases: list[Case], out: Path) -> dict[str, Path]:
    """Each case's dataset under ``out``/data, simulated once and reused by later runs. The
    sweep's workers read it in place, so ``out`` must be on a path they all see."""
    from evsplat.data.simulator import simulate_dataset

    paths = {}
    for case in cases:
        data_dir = (out / "data" / case.name).resolve()
        if not (data_dir / "meta.json").is_file():
            data_dir.parent.mkdir(parents=True, exist_ok=True)
            simulate_dataset(case.scene, data_dir, speed=case.speed, tiny=case.tiny, progress=False)
        paths[case.name] = data_dir
    return paths


def bench_cell(
    case: Case,
    variant: str,
    spec: dict,
    data: Path,
    iters: int | None,
    apply: Callable | None = None,
    cli: tuple[str, ...] = (),
    seed: int | None = None,
) -> Cell:
    """One run of the grid: the preset's config on ``spec``'s device (default auto) changed by
    ``apply`` (default: the named entry of ``VARIANTS``), ``cli`` as extra `evsplat train`
    arguments, and ``seed`` (default the preset's). The sweep trains it in its own process (so
    peak memory is per run) and scores it on the held-out frames."""
    from evsplat.config import preset

    cfg = preset(spec["train_preset"])
    cfg.device = spec.get("device", "auto")
    (apply or VARIANTS[variant])(cfg)
    n = iters or spec["iterations"]
    if n:
        cfg.schedule.iterations = n
    return Cell(
        scene=case.name,
        data=data,
        config=cfg.to_dict(),
        seed=cfg.seed if seed is None else seed,
        train_args=tuple(cli),
        labels={"case": case.name, "variant": variant},
    )


def fmt(v, nd: int = 2) -> str:
    """A table cell: the number to ``nd`` decimals, '-' when it was not measured."""
    return "-" if v is None else f"{v:.{nd}f}"


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of points not dominated (less time and more PSNR), sorted by time."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], float("-inf")
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def plot_pareto(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    markers = "osD^v<>PX*"
    variants = sorted({r["variant"] for r in rows})
    for k, v in enumerate(variants):
        sel = [r for r in rows if r["variant"] == v]
        ax.scatter(
            [r["wall_seconds"] for r in sel],
            [r["psnr"] for r in sel],
            marker=markers[k % len(markers)],
            s=50,
            label=v,
        )
        for r in sel:
            ax.annotate(r["case"], (r["wall_seconds"], r["psnr"]), fontsize=7, alpha=0.7)
    pts = [(r["wall_seconds"], r["psnr"]) for r in rows]
    front = pareto_front(pts)
    ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k--", lw=1, label="frontier")
    ax.set_xlabel("training wall time (s)")
    ax.set_ylabel("PSNR on held-out frames (dB)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    spec = PRESETS[args.preset] | {"device": args.device}
    out = args.out or Path("bench_results") / args.preset
    out.mkdir(parents=True, exist_ok=True)
    variants = args.variants.split(",") if args.variants else spec["variants"]
    info = machine_info()
    print(f"machine: {info['machine']}\nadapter: {info['adapter']}\ncommit: {info['commit']}")
    data = simulate_cases(spec["cases"], out)
    cells = [
        bench_cell(case, variant, spec, data[case.name], args.iters)
        for case in spec["cases"]
        for variant in variants
    ]
    sweep = run_sweep(cells, out, SweepOptions.from_args(args))
    rows = sweep.rows
    header = f"{'case':<18} {'variant':<18} {'iters':>6} {'time s':>8} {'it/s':>6} "
    header += f"{'MiB':>7} {'PSNR':>6} {'SSIM':>6} {'PSNRmov':>8}"
    print(header)
    for r in rows:
        print(
            f"{r['case']:<18} {r['variant']:<18} {r['iterations']:>6} "
            f"{r['wall_seconds']:>8.1f} {r['iterations_per_second']:>6.2f} "
            f"{r['peak_rss_mib']:>7.0f} {fmt(r['psnr']):>6} {fmt(r['ssim'], 3):>6} "
            f"{fmt(r['psnr_moving']):>8}"
        )
    if not rows:
        return sweep.exit_code
    written = write_table(out, rows, {"preset": args.preset, **info})
    plot_pareto(
        rows, out / "pareto.png", f"evsplat bench --preset {args.preset} ({info['adapter']})"
    )
    print(f"written: {', '.join(map(str, written))}, {out / 'pareto.png'}")
    return sweep.exit_code
