"""`evsplat bench raster`: the wgpu rasterizer's forward and forward+backward per call, with a
per-pass breakdown (host timing around separately submitted passes), against the dense torch
reference (tests/reference/raster_ref.py, chunked over pixel rows) timed in the same run."""

from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import statistics
import time
from pathlib import Path

import torch

from evsplat.gpu import adapter_info
from evsplat.raster import rasterize

HELP = "rasterizer forward / forward+backward per call vs the torch reference"
CASES = [(128, 2_000), (256, 20_000), (512, 100_000)]
# Reference chunks hold at most this many pixel x Gaussian pairs (memory of the dense oracle).
REF_PAIRS = 20_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per row (median)")
    parser.add_argument(
        "--reference-max-pairs",
        type=float,
        default=3e9,
        help="skip the reference above this many pixel x Gaussian pairs (run time)",
    )


def _reference():
    """The torch oracle from the source tree's tests/reference (absent from installed wheels)."""
    path = Path(__file__).resolve().parents[3] / "tests" / "reference" / "raster_ref.py"
    if not path.exists():
        return None
    spec = importlib.util.spec_from_file_location("raster_ref", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _scene(size: int, n: int):
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(n, 2, generator=g) * 2 - 1, 3 + torch.rand(n, 1, generator=g)], 1)
    scales = torch.rand(n, 3, generator=g) * 0.03 + 0.005
    quats = torch.randn(n, 4, generator=g)
    opac = torch.rand(n, generator=g) * 0.8 + 0.1
    feats = torch.rand(n, 3, generator=g)
    f = size * 1.2
    K = torch.tensor([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
    return [means, quats, scales, opac, feats], torch.eye(4), K


def _time(fn, repeats: int) -> float:
    fn()  # warm-up: pipelines and buffers
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)


def _gpu_call(params, view, K, size, backward: bool, profile=None):
    leaves = [p.clone().requires_grad_(backward) for p in params]
    image, depth, alpha, _ = rasterize(*leaves, view, K, size, size, profile=profile)
    if backward:
        (image.sum() + depth.sum() + alpha.sum()).backward()


def _ref_call(ref, params, view, K, size, backward: bool):
    rows = max(1, REF_PAIRS // (size * params[0].shape[0]))
    leaves = [p.clone().requires_grad_(backward) for p in params]
    for r0 in range(0, size, rows):
        rr = (r0, min(size, r0 + rows))
        with torch.set_grad_enabled(backward):
            image, depth, alpha, _ = ref.render(*leaves, view, K, size, size, rows=rr)
            if backward:
                (image.sum() + depth.sum() + alpha.sum()).backward()


def run(args: argparse.Namespace) -> int:
    info = adapter_info()
    print(f"adapter: {info['name']} ({info['device_type']}), atomics: {info['atomic_mode']}, "
          f"torch threads: {torch.get_num_threads()}")  # fmt: skip
    ref = _reference()
    rows = []
    for size, n in CASES:
        params, view, K = _scene(size, n)
        fwd = _time(functools.partial(_gpu_call, params, view, K, size, False), args.repeats)
        both = _time(functools.partial(_gpu_call, params, view, K, size, True), args.repeats)
        prof: dict = {}
        _gpu_call(params, view, K, size, True, profile=prof)
        r_fwd = r_both = math.nan
        if ref is not None and size * size * n <= args.reference_max_pairs:
            r_fwd = _time(functools.partial(_ref_call, ref, params, view, K, size, False), 1)
            r_both = _time(functools.partial(_ref_call, ref, params, view, K, size, True), 1)
        rows.append((size, n, fwd, both, r_fwd, r_both, prof))
    print()
    print(
        "| image | Gaussians | fwd ms | fwd+bwd ms | ref fwd ms | ref fwd+bwd ms "
        "| speed-up fwd+bwd |"
    )
    print("|---|---|---|---|---|---|---|")
    skipped = "skipped (over --reference-max-pairs)"
    for size, n, fwd, both, r_fwd, r_both, _ in rows:
        if math.isnan(r_both):
            ref_cols = f"{skipped} | {skipped} | - |"
        else:
            ref_cols = f"{r_fwd * 1e3:.0f} | {r_both * 1e3:.0f} | {r_both / both:.0f}x |"
        print(f"| {size}x{size} | {n} | {fwd * 1e3:.1f} | {both * 1e3:.1f} | {ref_cols}")
    print()
    print("Per-pass host times (ms, passes submitted one by one, so the sum exceeds the total):")
    for size, n, *_, prof in rows:
        parts = [f"{k} {v * 1e3:.1f}" for phase in ("forward", "backward")
                 for k, v in prof.get(phase, {}).items()]  # fmt: skip
        print(f"- {size}x{size}/{n}: " + ", ".join(parts))
    return 0
