"""Where a rasterize call spends its host time, per phase (issue 26 item 4).

Times `evsplat.raster.rasterize` forward and its backward (a weighted sum of image, depth and
alpha, as `bench raster` differentiates) on `bench raster`'s scenes, with the wrapper's steps
timed from outside: the input checks (`_check`), the numpy hand-over (`_args`), the native
calls, and the rest of the wrapper and of torch's autograd. The native calls' own phases (the
"host" dict a build since session 21 returns: buffer preparation, uploads, encoding, submission,
the wait for the device, copies out of the mapped staging buffer, numpy results) are listed
under them; their remainder is PyO3's argument and result conversion.

    PYTHONPATH=python python scripts/raster_host_phases.py --cases 256x20000,1024x1000000
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from typing import Any, Callable

from evsplat import raster
from evsplat.bench.raster import _scene, _weights


class _Timed:
    """`raster._core` with the two rasterize entry points timed (and their "host" dicts kept)."""

    def __init__(self, core: Any, acc: dict[str, float]) -> None:
        self._core = core
        self._acc = acc

    def __getattr__(self, name: str) -> Any:
        fn = getattr(self._core, name)
        if name not in ("rasterize_forward", "rasterize_backward"):
            return fn
        side = "fwd" if name.endswith("forward") else "bwd"

        def call(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            self._acc[f"{side} native call"] += time.perf_counter() - t0
            for phase, dt in out.get("host", {}).items():
                self._acc[f"{side} native: {phase}"] += dt
            return out

        return call


def _timed(fn: Callable, acc: dict[str, float], key: str) -> Callable:
    def call(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += time.perf_counter() - t0

    return call


def measure(size: int, n: int, d: int, repeats: int, acc: dict[str, float]) -> dict:
    """Per-phase seconds of `repeats` fwd+bwd calls after a warm-up call (pipelines, buffers)."""
    params, view, K = _scene(size, n, d)
    w_img, w_depth, w_alpha = _weights(size, d)
    samples: dict[str, list[float]] = defaultdict(list)
    for r in range(repeats + 1):
        acc.clear()
        leaves = [p.clone().requires_grad_(True) for p in params]
        t0 = time.perf_counter()
        image, depth, alpha, _ = raster.rasterize(*leaves, view, K, size, size)
        acc["fwd call"] = time.perf_counter() - t0
        loss = (image * w_img).sum() + (depth * w_depth).sum() + (alpha * w_alpha).sum()
        t0 = time.perf_counter()
        loss.backward()
        acc["bwd call"] = time.perf_counter() - t0
        if r > 0:
            for k, v in acc.items():
                samples[k].append(v)
    return samples


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="256x20000,1024x1000000")
    ap.add_argument("--channels", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cases = [tuple(int(v) for v in c.split("x")) for c in args.cases.split(",")]
    acc: dict[str, float] = defaultdict(float)
    # Patch the wrapper's steps to add into `acc`, which each call of `measure` reads and resets.
    raster._core = _Timed(raster._core, acc)
    raster._check = _timed(raster._check, acc, "fwd input checks (_check)")
    raster._args = _timed(raster._args, acc, "fwd numpy hand-over (_args)")
    wrapped = raster._Rasterize.backward
    raster._Rasterize.backward = staticmethod(
        _timed(wrapped, acc, "bwd wrapper (Function.backward)")
    )
    for size, n in cases:
        rows = measure(size, n, args.channels, args.repeats, acc)
        med = {k: statistics.median(v) * 1e3 for k, v in rows.items()}
        med["fwd wrapper rest"] = med["fwd call"] - sum(
            med.get(k, 0.0)
            for k in (
                "fwd input checks (_check)",
                "fwd numpy hand-over (_args)",
                "fwd native call",
            )  # fmt: skip
        )
        for side in ("fwd", "bwd"):
            rust = med.pop(f"{side} native: rust call", None)
            if rust is None:  # a build without phase times
                continue
            numpy = med.get(f"{side} native: numpy results", 0.0)
            phases = sum(v for k, v in med.items() if k.startswith(f"{side} native: ")) - numpy
            med[f"{side} native: other Rust work"] = rust - phases
            med[f"{side} native: PyO3 argument conversion"] = (
                med[f"{side} native call"] - rust - numpy
            )
        med["bwd wrapper rest"] = med["bwd wrapper (Function.backward)"] - med["bwd native call"]
        med["bwd torch autograd rest"] = med["bwd call"] - med["bwd wrapper (Function.backward)"]
        print(f"\n{size}x{size}, {n} Gaussians, D={args.channels}: medians of {args.repeats} "
              "calls, ms")  # fmt: skip
        print("| phase | ms |\n|---|---|")
        for k in sorted(med, key=lambda k: (k[:3], "call" not in k, k)):
            print(f"| {k} | {med[k]:.1f} |")


if __name__ == "__main__":
    main()
