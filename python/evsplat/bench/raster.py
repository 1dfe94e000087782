"""`evsplat bench raster`: the wgpu rasterizer's forward and forward+backward per call, with a
per-pass breakdown (host timing around separately submitted passes) and the compositing pass's
work counters, against the dense torch reference (tests/reference/raster_ref.py, chunked over
pixel rows) timed in the same run.

With ``--against PYTHON`` (another checkout's venv interpreter, e.g. an older commit's build) the
two builds are timed in alternating subprocesses (ABAB...), each running this file's worker on
the same scenes, and their images and gradients are compared."""

from __future__ import annotations

import argparse
import functools
import importlib.util
import inspect
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from evsplat.errors import EvsplatError
from evsplat.gpu import adapter_info
from evsplat.raster import rasterize

HELP = "rasterizer forward / forward+backward per call vs the torch reference or another build"
CASES = "128x2000,256x20000,512x100000"
# Reference chunks hold at most this many pixel x Gaussian pairs (memory of the dense oracle).
REF_PAIRS = 20_000_000
# The oracle tests' gradient tolerance (tests/test_raster.py): median and max relative error.
GRAD_MEDIAN, GRAD_MAX = 1e-3, 1e-2
IMAGE_TOL = 1e-4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per row (median)")
    parser.add_argument(
        "--cases", default=CASES, help="comma-separated SIZExGAUSSIANS (square images)"
    )
    parser.add_argument("--channels", default="3", help="comma-separated feature channel counts")
    parser.add_argument(
        "--atomics",
        default="default",
        help="comma-separated gradient atomics to time fwd+bwd with: default, float, cas",
    )
    parser.add_argument(
        "--reference-max-pairs",
        type=float,
        default=3e9,
        help="skip the reference above this many pixel x Gaussian pairs (run time)",
    )
    parser.add_argument(
        "--against",
        type=Path,
        help="Python of another evsplat build: time both, interleaved, and compare outputs",
    )
    parser.add_argument("--rounds", type=int, default=3, help="ABAB rounds with --against")


def _reference():
    """The torch oracle from the source tree's tests/reference (absent from installed wheels)."""
    path = Path(__file__).resolve().parents[3] / "tests" / "reference" / "raster_ref.py"
    if not path.exists():
        return None
    spec = importlib.util.spec_from_file_location("raster_ref", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _scene(size: int, n: int, d: int = 3):
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(n, 2, generator=g) * 2 - 1, 3 + torch.rand(n, 1, generator=g)], 1)
    scales = torch.rand(n, 3, generator=g) * 0.03 + 0.005
    quats = torch.randn(n, 4, generator=g)
    opac = torch.rand(n, generator=g) * 0.8 + 0.1
    feats = torch.rand(n, d, generator=g)
    f = size * 1.2
    K = torch.tensor([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
    return [means, quats, scales, opac, feats], torch.eye(4), K


def _weights(size: int, d: int):
    """Fixed random loss weights on image, depth and alpha (the gradients compared)."""
    g = torch.Generator().manual_seed(1)
    return (
        torch.rand(size, size, d, generator=g),
        torch.rand(size, size, generator=g),
        torch.rand(size, size, generator=g),
    )


def _time(fn, repeats: int) -> tuple[list[float], list[float]]:
    """Wall-clock and process CPU seconds (all threads, lavapipe's included) of each call."""
    fn()  # warm-up: pipelines and buffers
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return wall, cpu


def _gpu_call(params, view, K, size, backward: bool, weights, atomics=None, **kw):
    leaves = [p.clone().requires_grad_(backward) for p in params]
    image, depth, alpha, meta = rasterize(*leaves, view, K, size, size, atomics=atomics, **kw)
    if backward:
        w_img, w_depth, w_alpha = weights
        ((image * w_img).sum() + (depth * w_depth).sum() + (alpha * w_alpha).sum()).backward()
    return image, depth, alpha, meta, [p.grad for p in leaves]


def _ref_call(ref, params, view, K, size, backward: bool, weights):
    rows = max(1, REF_PAIRS // (size * params[0].shape[0]))
    leaves = [p.clone().requires_grad_(backward) for p in params]
    w_img, w_depth, w_alpha = weights
    for r0 in range(0, size, rows):
        rr = (r0, min(size, r0 + rows))
        with torch.set_grad_enabled(backward):
            image, depth, alpha, _ = ref.render(*leaves, view, K, size, size, rows=rr)
            if backward:
                loss = (image * w_img[rr[0] : rr[1]]).sum() + (depth * w_depth[rr[0] : rr[1]]).sum()
                (loss + (alpha * w_alpha[rr[0] : rr[1]]).sum()).backward()


def _atomics(name: str) -> str | None:
    return None if name == "default" else name


def _configs(args) -> list[tuple[int, int, int]]:
    try:
        cases = [tuple(int(v) for v in c.lower().split("x")) for c in args.cases.split(",")]
        channels = [int(c) for c in str(args.channels).split(",")]
    except ValueError:
        raise EvsplatError(
            f"bench raster: --cases {args.cases!r} / --channels {args.channels!r}: use e.g. "
            "--cases 256x20000,512x100000 --channels 1,3,8"
        ) from None
    if any(len(c) != 2 for c in cases):
        raise EvsplatError(f"bench raster: --cases {args.cases!r}: each case is SIZExGAUSSIANS")
    return [(size, n, d) for size, n in cases for d in channels]


def measure(size: int, n: int, d: int, atomics: list[str], repeats: int, keep: Path | None):
    """Timings (seconds, every sample) of one scene with this process's build, its work counts
    when the build can count them, and (``keep``) its outputs saved for comparison."""
    params, view, K = _scene(size, n, d)
    weights = _weights(size, d)
    call = functools.partial(_gpu_call, params, view, K, size, weights=weights)
    row: dict = {}
    row["fwd"], row["fwd cpu"] = _time(functools.partial(call, False), repeats)
    for name in atomics:
        both = functools.partial(call, True, atomics=_atomics(name))
        row[f"fwd+bwd {name}"], row[f"fwd+bwd {name} cpu"] = _time(both, repeats)
    if "count_work" in inspect.signature(rasterize).parameters:
        row["work"] = call(False, count_work=True)[3]["work"]
    if keep is not None:
        image, depth, alpha, _, grads = call(True, atomics=_atomics(atomics[0]))
        out = {"image": image, "depth": depth, "alpha": alpha}
        torch.save({**{k: v.detach() for k, v in out.items()}, "grads": grads}, keep)
    return row


def _work_line(size: int, n: int, d: int, work: dict) -> str:
    pixels = size * size
    tiles = math.ceil(size / work.get("tile_size", 16)) ** 2  # builds before 518a066: 16
    frac = work["contributed"] / max(work["evaluated"], 1)
    return (
        f"| {size}x{size} | {n} | {d} | {work['pairs']:,} | {work['pairs'] / tiles:.0f} "
        f"| {work['evaluated'] / pixels:.0f} | {work['contributed'] / pixels:.1f} "
        f"| {100 * frac:.1f}% | {work['saturated'] / pixels:.0f} |"
    )


WORK_HEADER = (
    "| image | Gaussians | D | tile pairs | pairs per tile | steps evaluated per pixel "
    "| contributed per pixel | contributed | steps after saturation per pixel |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def run(args: argparse.Namespace) -> int:
    if args.against is not None:
        return _compare(args)
    info = adapter_info()
    print(f"adapter: {info['name']} ({info['device_type']}), atomics: {info['atomic_mode']}, "
          f"torch threads: {torch.get_num_threads()}")  # fmt: skip
    ref = _reference()
    atomics = args.atomics.split(",")
    rows = []
    for size, n, d in _configs(args):
        row = measure(size, n, d, atomics, args.repeats, None)
        params, view, K = _scene(size, n, d)
        prof: dict = {}
        _gpu_call(params, view, K, size, True, _weights(size, d), profile=prof)
        r_fwd = r_both = math.nan
        if ref is not None and size * size * n <= args.reference_max_pairs:
            weights = _weights(size, d)
            call = functools.partial(_ref_call, ref, params, view, K, size, weights=weights)
            r_fwd = _time(functools.partial(call, False), 1)[0][0]
            r_both = _time(functools.partial(call, True), 1)[0][0]
        rows.append((size, n, d, row, r_fwd, r_both, prof))
    print()
    both_cols = " | ".join(f"fwd+bwd ms ({a})" for a in atomics)
    print(f"| image | Gaussians | D | fwd ms | {both_cols} | ref fwd ms | ref fwd+bwd ms "
          "| speed-up fwd+bwd |")  # fmt: skip
    print("|---|---|---|---|" + "---|" * len(atomics) + "---|---|---|")
    skipped = "skipped (over --reference-max-pairs)"
    for size, n, d, row, r_fwd, r_both, _ in rows:
        med = {k: statistics.median(v) for k, v in row.items() if k != "work"}
        both = med[f"fwd+bwd {atomics[0]}"]
        if math.isnan(r_both):
            ref_cols = f"{skipped} | {skipped} | - |"
        else:
            ref_cols = f"{r_fwd * 1e3:.0f} | {r_both * 1e3:.0f} | {r_both / both:.0f}x |"
        times = " | ".join(f"{med[f'fwd+bwd {a}'] * 1e3:.1f}" for a in atomics)
        print(f"| {size}x{size} | {n} | {d} | {med['fwd'] * 1e3:.1f} | {times} | {ref_cols}")
    print()
    print("Work of the forward compositing pass (pixel-Gaussian steps, per render):")
    print(WORK_HEADER)
    for size, n, d, row, *_ in rows:
        print(_work_line(size, n, d, row["work"]))
    print()
    print("Per-pass host times (ms, passes submitted one by one, so the sum exceeds the total):")
    for size, n, d, *_, prof in rows:
        parts = [f"{k} {v * 1e3:.1f}" for phase in ("forward", "backward")
                 for k, v in prof.get(phase, {}).items()]  # fmt: skip
        print(f"- {size}x{size}/{n}, D={d}: " + ", ".join(parts))
    return 0


def _worker(argv: list[str]) -> None:
    """Subprocess side of ``--against``: measure every config, write JSON rows to argv[1]."""
    spec = json.loads(argv[0])
    rows = []
    for size, n, d in spec["configs"]:
        keep = Path(spec["keep"]) / f"{size}_{n}_{d}.pt"
        row = measure(size, n, d, spec["atomics"], spec["repeats"], keep)
        rows.append({"config": [size, n, d], **row})
    info = adapter_info()
    Path(argv[1]).write_text(json.dumps({"adapter": info["name"], "rows": rows}))


def _run_worker(python: Path, spec: dict, out: Path) -> dict:
    # runpy from a neutral directory: `python FILE` would put bench/ first on sys.path.
    code = f"import runpy; runpy.run_path({str(__file__)!r}, run_name='__worker__')"
    subprocess.run(
        [str(python), "-c", code, json.dumps(spec), str(out)], check=True, cwd=out.parent
    )
    return json.loads(out.read_text())


def _compare_outputs(a: Path, b: Path) -> tuple[float, float, float]:
    """Max |image difference| (image, depth, alpha) and the median and max relative gradient
    error of build A against build B (relative to |B|, floored as in the oracle tests)."""
    ra, rb = torch.load(a), torch.load(b)
    diff = max(float((ra[k] - rb[k]).abs().max()) for k in ("image", "depth", "alpha"))
    meds, maxs = [], []
    for ga, gb in zip(ra["grads"], rb["grads"]):
        rel = (ga - gb).abs() / (gb.abs() + 1e-3 * gb.abs().max().clamp(min=1e-12))
        meds.append(float(rel.median()))
        maxs.append(float(rel.max()))
    return diff, max(meds), max(maxs)


def _compare(args: argparse.Namespace) -> int:
    python = args.against
    if not python.exists():
        print(f"--against {python}: no such interpreter; pass another checkout's .venv/bin/python")
        return 2
    configs = _configs(args)
    atomics = args.atomics.split(",")
    sides = {"A (this build)": Path(sys.executable), f"B ({python})": python}
    samples: dict = {name: {} for name in sides}
    work: dict = {name: {} for name in sides}
    with tempfile.TemporaryDirectory(prefix="evsplat-bench-") as tmp:
        for r in range(args.rounds):
            for k, (name, exe) in enumerate(sides.items()):
                keep = Path(tmp) / f"side{k}"
                keep.mkdir(exist_ok=True)
                spec = {"configs": configs, "atomics": atomics, "repeats": args.repeats,
                        "keep": str(keep)}  # fmt: skip
                t0 = time.perf_counter()
                res = _run_worker(exe, spec, Path(tmp) / f"out{k}.json")
                print(f"round {r + 1}/{args.rounds} {name}: {time.perf_counter() - t0:.0f} s "
                      f"on {res['adapter']}", flush=True)  # fmt: skip
                for row in res["rows"]:
                    key = tuple(row["config"])
                    for col, vals in row.items():
                        if col == "work":
                            work[name][key] = vals
                        elif col != "config":
                            samples[name].setdefault((key, col), []).extend(vals)
        checks = {
            key: _compare_outputs(
                Path(tmp) / "side0" / f"{key[0]}_{key[1]}_{key[2]}.pt",
                Path(tmp) / "side1" / f"{key[0]}_{key[1]}_{key[2]}.pt",
            )
            for key in configs
        }
    (a, b) = sides
    print()
    print(f"Medians over {args.rounds} rounds x {args.repeats} calls, builds interleaved "
          f"(A = this build, B = {python}); wall and process CPU (all threads) ms:")  # fmt: skip
    print("| image | Gaussians | D | timed | B wall | A wall | B / A wall | B cpu | A cpu "
          "| B / A cpu |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for key in configs:
        for col in ["fwd"] + [f"fwd+bwd {x}" for x in atomics]:
            med = {
                (side, kind): statistics.median(samples[side][(key, col + kind)])
                for side in (a, b)
                for kind in ("", " cpu")
            }
            size, n, d = key
            wall_b, wall_a, cpu_b, cpu_a = (med[b, ""], med[a, ""], med[b, " cpu"], med[a, " cpu"])
            print(f"| {size}x{size} | {n} | {d} | {col} | {wall_b * 1e3:.0f} | {wall_a * 1e3:.0f} "
                  f"| {wall_b / wall_a:.2f}x | {cpu_b * 1e3:.0f} | {cpu_a * 1e3:.0f} "
                  f"| {cpu_b / cpu_a:.2f}x |")  # fmt: skip
    print()
    print(f"A against B: max |image, depth, alpha difference| (limit {IMAGE_TOL:g}); gradient "
          f"relative error, worst parameter's median (limit {GRAD_MEDIAN:g}) and max "
          f"(limit {GRAD_MAX:g}), atomics {atomics[0]}:")  # fmt: skip
    ok = True
    for key, (diff, med, mx) in checks.items():
        good = diff <= IMAGE_TOL and med <= GRAD_MEDIAN and mx <= GRAD_MAX
        ok &= good
        verdict = "within" if good else "OUTSIDE"
        print(f"- {key[0]}x{key[0]}/{key[1]}, D={key[2]}: image {diff:.2e}, gradients median "
              f"{med:.2e}, max {mx:.2e}: {verdict} the tolerance")  # fmt: skip
    for name in sides:
        if work[name]:
            print()
            print(f"Work of the forward compositing pass, {name}:")
            print(WORK_HEADER)
            for key, w in work[name].items():
                print(_work_line(*key, w))
    return 0 if ok else 1


if __name__ == "__worker__":
    _worker(sys.argv[1:])
