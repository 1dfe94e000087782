"""`evsplat bench skips`: what each skip saves and what it costs, on a static and a dynamic scene.

Every skip is measured as a pair of runs that differ only in it, on the scene where it should
apply (`still`: only the camera moves) and on one where it should not matter (`ball`). Runs are
the training benchmark's cells on the sweep runner (own process, held-out evaluation; `--ray`
for a cluster), and the table is written into docs/results.md as its own section, replaced on
every regeneration.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from evsplat.bench.train import Case, bench_cell, fmt, machine_info, simulate_cases
from evsplat.data.atomic import write_text_atomic
from evsplat.sweep import SweepOptions, add_sweep_arguments, run_sweep

HELP = "time saved and PSNR change of every skip, on a static and a dynamic scene"
SECTION = "## Skipping what a scene does not need"
CASES = (Case("still", tiny=True), Case("ball", tiny=True))
# (image side, Gaussians) of the render-level measurements; the first also hosts the empty tiles.
RENDER_CASES = ((96, 2_400), (400, 20_000))


@dataclass(frozen=True)
class Variant:
    apply: Callable
    cli: tuple[str, ...] = ()  # extra `evsplat train` arguments
    long: bool = False  # run for --long-iters on the static scene only (early stop needs time)


def _defaults(cfg) -> None:
    return None


def _set(section: str | None, **values) -> Callable:
    def apply(cfg) -> None:
        target = cfg if section is None else getattr(cfg, section)
        for k, v in values.items():
            setattr(target, k, v)

    return apply


def _both(first: Callable, second: Callable) -> Callable:
    def apply(cfg) -> None:
        first(cfg)
        second(cfg)

    return apply


VARIANTS: dict[str, Variant] = {
    "defaults": Variant(_defaults),
    "no-mlp": Variant(_set(None, deform=False)),
    "static-off": Variant(_set("skips", static=False)),
    "static-off-paper-mlp": Variant(
        _both(_set("skips", static=False), _set("model", mlp_width=256, mlp_depth=8, mlp_skip=4))
    ),
    "coarse": Variant(_set("skips", coarse_fraction=0.3)),
    "early-stop-patience-2": Variant(_set("skips", early_stop_patience=2)),
    "budget-3000": Variant(_set("densify", max_gaussians=3000)),
    "no-depth-prior": Variant(_defaults, ("--depth-prior", "none")),
    "early-stop-patience-2-long": Variant(_set("skips", early_stop_patience=2), long=True),
    "no-early-stop-long": Variant(_set("skips", early_stop=False), long=True),
}

# (what is skipped, variant with the skip, variant without it). The default early stop
# (patience 10) cannot trigger in a short run, so the defaults are its "without".
PAIRS = [
    ("deformation MLP and motion losses, by flag (`deform=False`)", "no-mlp", "static-off"),
    ("the same against the paper's 8x256 MLP (tiny preset's is 4x64)", "no-mlp",
     "static-off-paper-mlp"),
    ("MLP for Gaussians found static; all of it once the scene is (`skips.static`)", "defaults",
     "static-off"),
    ("full resolution in the first 30% (`skips.coarse_fraction=0.3`)", "coarse", "defaults"),
    ("iterations after the held-out L_e plateaus (patience 2)", "early-stop-patience-2",
     "defaults"),
    ("the same, in long runs (early stop off without it)", "early-stop-patience-2-long",
     "no-early-stop-long"),
    ("Gaussians beyond a budget of 3000 (default 6000)", "budget-3000", "defaults"),
    ("depth stage without a depth prior (`--depth-prior none`)", "no-depth-prior", "defaults"),
]  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--iters", type=int, default=300, help="iterations per run (default 300)")
    parser.add_argument(
        "--long-iters",
        type=int,
        default=1500,
        help="iterations of the early-stop pair on the static scene (default 1500)",
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="timed calls per render measurement (median)"
    )
    parser.add_argument("--out", type=Path, default=Path("bench_results/skips"))
    parser.add_argument("--doc", type=Path, default=Path("docs/results.md"))
    add_sweep_arguments(parser)


def table(rows: dict[tuple[str, str], dict]) -> list[str]:
    """One line per (skip, scene): both runs, the time saved and the PSNR change."""
    lines = [
        "| skipped | scene | with: it / s / PSNR / SSIM | without: it / s / PSNR / SSIM | "
        "time saved | PSNR change | moving-mask PSNR with / without |",
        "|---|---|---|---|---|---|---|",
    ]
    for what, on, off in PAIRS:
        for case in CASES:
            a, b = rows.get((case.name, on)), rows.get((case.name, off))
            if a is None or b is None:
                continue
            saved = 1.0 - a["wall_seconds"] / b["wall_seconds"]
            lines.append(
                f"| {what} | {case.scene} | {_cell(a)} | {_cell(b)} | {100 * saved:+.0f}% | "
                f"{a['psnr'] - b['psnr']:+.2f} dB | "
                f"{fmt(a['psnr_moving'])} / {fmt(b['psnr_moving'])} |"
            )
    return lines


def _cell(r: dict) -> str:
    return f"{r['iterations']} / {r['wall_seconds']:.0f} / {fmt(r['psnr'])} / {fmt(r['ssim'], 3)}"


def render_table(repeats: int) -> list[str]:
    """Skips inside one render, timed per rasterizer call (forward + backward, median):
    one channel instead of three for a monochrome sensor, and tiles that no Gaussian touches
    (the same splats rendered into an image four times larger, 3/4 of its tiles empty)."""
    from evsplat.bench.raster import _gpu_call, _scene, _time, _weights

    def ms(params, view, K, size) -> float:
        weights = _weights(size, params[4].shape[1])
        wall, _ = _time(lambda: _gpu_call(params, view, K, size, True, weights), repeats)
        return 1e3 * statistics.median(wall)

    lines = [
        "| skipped | image, Gaussians | with (ms) | without (ms) | time saved |",
        "|---|---|---|---|---|",
    ]
    for size, n in RENDER_CASES:
        params, view, K = _scene(size, n)
        mono = ms([*params[:4], params[4][:, :1].contiguous()], view, K, size)
        colour = ms(params, view, K, size)
        lines.append(
            f"| two of three colour channels (monochrome sensor: 1 channel) | {size}x{size}, "
            f"{n:,} | {mono:.1f} | {colour:.1f} | {100 * (1 - mono / colour):+.0f}% |"
        )
    size, n = RENDER_CASES[0]
    params, view, K = _scene(size, n)
    padded = K.clone()
    padded[:2, 2] += size / 2  # the same view in the centre of an image twice as wide
    small, large = ms(params, view, K, size), ms(params, view, padded, 2 * size)
    tiles = math.ceil(2 * size / 16) ** 2
    empty = tiles - math.ceil(size / 16) ** 2
    lines.append(
        f"| {empty} empty of {tiles} tiles (the {size}x{size} view centred in "
        f"{2 * size}x{2 * size}; 'with' renders only the {size}x{size}) | {2 * size}x{2 * size}, "
        f"{n:,} | {small:.1f} | {large:.1f} | {100 * (1 - small / large):+.0f}% |"
    )
    return lines


def replace_section(old: str, section: list[str]) -> str:
    """``old`` with its SECTION (up to the next '## ' heading) replaced by ``section``, or
    ``section`` appended when there is none."""
    new = "\n".join(section).rstrip("\n") + "\n"
    if SECTION not in old:
        return old.rstrip("\n") + "\n\n" + new
    head, rest = old.split(SECTION, 1)
    nxt = rest.find("\n## ")
    tail = "" if nxt < 0 else rest[nxt + 1 :]
    return head + new + ("\n" + tail if tail else "")


def run(args: argparse.Namespace) -> int:
    info = machine_info()
    print(f"machine: {info['machine']}\nadapter: {info['adapter']}\ncommit: {info['commit']}")
    args.out.mkdir(parents=True, exist_ok=True)
    spec = {"train_preset": "tiny", "iterations": args.iters}
    render_lines = render_table(args.repeats)
    print("\n".join(render_lines), flush=True)
    data = simulate_cases(list(CASES), args.out)
    cells = [
        bench_cell(
            case,
            name,
            spec,
            data[case.name],
            args.long_iters if variant.long else args.iters,
            variant.apply,
            variant.cli,
        )
        for case in CASES
        for name, variant in VARIANTS.items()
        if not variant.long or case is CASES[0]
    ]
    sweep = run_sweep(cells, args.out, SweepOptions.from_args(args))
    rows = {(r["case"], r["variant"]): r for r in sweep.rows}
    for r in sweep.rows:
        print(
            f"{r['case']:<16} {r['variant']:<22} {r['iterations']:>5} it "
            f"{r['wall_seconds']:>7.1f} s PSNR {fmt(r['psnr'])} SSIM {fmt(r['ssim'], 3)} "
            f"moving {fmt(r['psnr_moving'])} static {r['static_fraction']:.2f} "
            f"static scene {r['static_scene']} stopped at {r['stopped_early_at']}",
            flush=True,
        )
    write_text_atomic(
        args.out / "results.json",
        json.dumps({**info, "rows": [r for r in rows.values()]}, indent=2),
    )
    section = [
        SECTION,
        "",
        f"Regenerate with `evsplat bench skips` (tiny preset, {args.iters} iterations per run, "
        f"{args.long_iters} for the long early-stop pair, 96x96, seed 0). Each line is a pair of "
        "runs that differ only in the skip, on `still` (the ball room with the ball at rest: only "
        "the camera moves) and on `ball`. Time is the training process's wall time; 'time "
        "saved' is relative to the run without the skip.",
        "",
        f"- Machine: {info['machine']}",
        f"- Adapter: {info['adapter']}",
        f"- Commit: {info['commit']}",
        "",
        *table(rows),
        "",
        "Skips inside a render, per rasterizer call (forward + backward, median of "
        f"{args.repeats}; the Gaussians of `evsplat bench raster`):",
        "",
        *render_lines,
        "",
    ]
    old = args.doc.read_text() if args.doc.is_file() else ""
    write_text_atomic(args.doc, replace_section(old, section))
    print(f"written: {args.doc}, {args.out / 'results.json'}")
    return sweep.exit_code
