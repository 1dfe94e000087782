"""Where a rasterize call spends its host time, per phase (issue 26 item 4).

Times `evsplat.raster.rasterize` forward and its backward (a weighted sum of image, depth and
alpha, as `bench raster` differentiates) on `bench raster`'s scenes, with the wrapper's steps
timed from outside: the input checks (`_check`), the numpy hand-over (`_args`), the native
calls, and the rest of the wrapper and of torch's autograd. The native calls' own phases (the
"host" dict a build since f98f3be returns: buffer preparation, uploads, encoding, submission,
the wait for the device, copies out of the mapped staging buffer, numpy results) are listed
under them, with what is left of the Rust side and PyO3's argument conversion; "call less the
wait" is a call's host work. "free outputs" is dropping a call's outputs and graph afterwards.

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
        # Freeing the call's outputs and graph (the numpy arrays the core's vectors became).
        t0 = time.perf_counter()
        del image, depth, alpha, loss, leaves
        acc["free outputs"] = time.perf_counter() - t0
        if r > 0:
            for k, v in _derived(dict(acc)).items():
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
        low = {k: min(v) * 1e3 for k, v in rows.items()}
        print(f"\n{size}x{size}, {n} Gaussians, D={args.channels}, {args.repeats} calls, ms (the "
              "min filters out preemption on a busy machine):")  # fmt: skip
        print("| phase | median | min |\n|---|---|---|")
        for k in sorted(med, key=_order):
            print(f"| {k} | {med[k]:.1f} | {low[k]:.1f} |")


def _order(k: str) -> tuple:
    return (k[:3] not in ("fwd", "bwd"), k[:3], "call" not in k, k)


def _derived(t: dict[str, float]) -> dict[str, float]:
    """One call's phases with the remainders added (per call: medians of parts need not add up)."""
    t["fwd wrapper rest"] = t["fwd call"] - sum(
        t.get(k, 0.0)
        for k in ("fwd input checks (_check)", "fwd numpy hand-over (_args)", "fwd native call")
    )
    for side in ("fwd", "bwd"):
        call = t[f"{side} native call"]
        rust = t.pop(f"{side} native: rust call", None)
        phases = sum(v for k, v in t.items() if k.startswith(f"{side} native: "))
        if f"{side} native: wait" in t:
            t[f"{side} call less the wait: host work"] = (
                t[f"{side} call"] - t[f"{side} native: wait"]
            )
        if rust is None:  # builds before this one time no "rust call"
            t[f"{side} native: other Rust work and PyO3 conversion"] = call - phases
            continue
        numpy = t.get(f"{side} native: numpy results", 0.0)
        t[f"{side} native: other Rust work"] = rust - (phases - numpy)
        t[f"{side} native: PyO3 argument conversion"] = call - rust - numpy
    t["bwd wrapper rest"] = t["bwd wrapper (Function.backward)"] - t["bwd native call"]
    t["bwd torch autograd rest"] = t["bwd call"] - t["bwd wrapper (Function.backward)"]
    return t


if __name__ == "__main__":
    main()
