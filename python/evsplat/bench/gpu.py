"""`evsplat bench gpu`: training speed with torch on CUDA against torch on the CPU, measured in
one run on one machine (issue 47's measurements), and where one step's time goes.

Two workloads: the 400x400 ball at the default preset, and the demo (the tiny ball, preset
tiny). Each is trained for a few steps in the motion stage (the MLP on every Gaussian, every
loss of the stage) with ``--device cpu`` and ``--device cuda``; the table gives the steady
it/s (after warm-up steps), the paper's 30k schedule's time at that rate, and per phase the
milliseconds of a step (MLP, events, raster calls, host<->device copies, optimizer, the rest:
losses and autograd), each with its ratio to the CPU's. Without a CUDA GPU the cuda arms are
skipped with a message, so the suite also runs (``--tiny``) on a CPU machine.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from evsplat.bench.train import Case, machine_info, simulate_cases
from evsplat.data.atomic import write_text_atomic

if TYPE_CHECKING:
    from evsplat.train.loop import Trainer

HELP = "training it/s and a per-phase step profile with torch on CUDA against the CPU"
PAPER_ITERATIONS = 30_000
DEVICES = ("cpu", "cuda")


@dataclass(frozen=True)
class Workload:
    label: str
    case: Case
    preset: str


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("bench_results/gpu"))
    parser.add_argument("--iters", type=int, default=30, help="timed steps per arm (30)")
    parser.add_argument("--warm", type=int, default=5, help="untimed steps before them (5)")
    parser.add_argument(
        "--profile-steps", type=int, default=5, help="steps of the per-phase profile (5)"
    )
    parser.add_argument(
        "--tiny",
        action="store_true",
        help="the default-preset workload on the tiny ball too (a quick check on a CPU)",
    )


def workloads(tiny: bool) -> list[Workload]:
    big = "ball 96x96, preset default" if tiny else "ball 400x400, preset default"
    return [
        Workload(big, Case("ball", tiny=tiny), "default"),
        Workload("demo: ball 96x96, preset tiny", Case("ball", tiny=True), "tiny"),
    ]


# ---- timing ------------------------------------------------------------------------------


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


class PhaseTimer:
    """Exclusive wall time per phase: a phase called inside another is taken out of it. On
    CUDA each phase synchronises at its ends, so its kernels count where they were queued."""

    def __init__(self, device: torch.device):
        self.device = device
        self.seconds: dict[str, float] = {}
        self._inner: list[float] = []

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args, **kwargs):
            _sync(self.device)
            start = time.perf_counter()
            self._inner.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                _sync(self.device)
                took = time.perf_counter() - start
                inner = self._inner.pop()
                self.seconds[name] = self.seconds.get(name, 0.0) + took - inner
                if self._inner:
                    self._inner[-1] += took

        return timed


#: The phases of a step: (name, module, attribute) of the function each one times.
PHASES = (
    ("mlp", "evsplat.model.deform", "DeformationMLP.forward"),
    ("events", "evsplat.train.views", "Views.accumulate"),
    ("raster calls", "evsplat.raster", "_core_call"),
    ("copies", "evsplat.raster", "_to_host"),
    ("copies", "evsplat.raster", "_to_device"),
    ("optimizer", "torch.optim", "Adam.step"),
)


@contextmanager
def phases_timed(timer: PhaseTimer) -> Iterator[None]:
    """The functions of ``PHASES`` replaced by timed ones while inside."""
    import importlib

    undo = []
    for name, module, attr in PHASES:
        owner = importlib.import_module(module)
        *path, leaf = attr.split(".")
        for part in path:
            owner = getattr(owner, part)
        original = owner.__dict__[leaf]
        setattr(owner, leaf, timer.wrap(name, original))
        undo.append((owner, leaf, original))
    try:
        yield
    finally:
        for owner, leaf, original in reversed(undo):
            setattr(owner, leaf, original)


def measure(data: Path, preset_name: str, device: str, args: argparse.Namespace) -> dict:
    """Steady it/s and a per-phase profile (ms per step) of ``device``'s arm."""
    from evsplat.config import preset
    from evsplat.data.dataset import load_dataset
    from evsplat.train.loop import Trainer

    cfg = preset(preset_name)
    cfg.device = device
    callers_threads = torch.get_num_threads()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    try:
        trainer = Trainer(load_dataset(data), cfg, args.out / "runs" / f"{preset_name}-{device}")
        dev = trainer.device
        # The motion stage, past the one-off seeding: what most of a schedule's steps do.
        it = cfg.schedule.warmup_end + 1
        it, _ = _steps(trainer, it, args.warm)
        it, seconds = _steps(trainer, it, args.iters)
        timer = PhaseTimer(dev)
        with phases_timed(timer):
            it, total = _steps(trainer, it, args.profile_steps)
    finally:
        torch.set_num_threads(callers_threads)
    steps = max(args.profile_steps, 1)
    ms = {k: 1e3 * v / steps for k, v in timer.seconds.items()}
    ms["rest (losses, autograd)"] = 1e3 * total / steps - sum(ms.values())
    return {"it_per_s": args.iters / seconds, "ms_per_step": 1e3 * total / steps, "phases": ms}


# ---- the suite ---------------------------------------------------------------------------


def _ratio(cpu: float | None, other: float | None) -> str:
    return "-" if not cpu or not other else f"{cpu / other:.2f}x"


def run(args: argparse.Namespace) -> int:
    info = machine_info()
    cuda = torch.cuda.is_available()
    gpu = torch.cuda.get_device_name(0) if cuda else "none (torch sees no CUDA GPU)"
    print(f"machine: {info['machine']}\nadapter: {info['adapter']}\ncommit: {info['commit']}")
    print(f"torch {torch.__version__}, CUDA GPU: {gpu}")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    loads = workloads(args.tiny)
    data = simulate_cases(list(dict.fromkeys(w.case for w in loads)), out)
    results: dict[str, dict[str, dict | None]] = {}
    for w in loads:
        results[w.label] = {}
        for device in DEVICES:
            if device == "cuda" and not cuda:
                print(f"{w.label}: cuda arm skipped: torch sees no CUDA GPU", flush=True)
                results[w.label][device] = None
                continue
            r = measure(data[w.case.name], w.preset, device, args)
            results[w.label][device] = r
            print(f"{w.label}, --device {device}: {r['it_per_s']:.2f} it/s", flush=True)
    print_table(results)
    doc = {**info, "torch": torch.__version__, "cuda_gpu": gpu, "args": vars(args)}
    doc["results"] = results
    path = out / "gpu_bench.json"
    write_text_atomic(path, json.dumps(doc, indent=2, default=str))
    print(f"written: {path}")
    return 0


def print_table(results: dict[str, dict[str, dict | None]]) -> None:
    """Per workload: it/s and the 30k schedule's time per device, then ms per phase."""
    for label, arms in results.items():
        cpu = arms.get("cpu")
        print(f"\n## {label}")
        print(f"{'device':<8} {'it/s':>8} {'vs cpu':>8} {'30k its':>10}")
        for device, r in arms.items():
            if r is None:
                print(f"{device:<8} {'skipped':>8}")
                continue
            minutes = PAPER_ITERATIONS / r["it_per_s"] / 60
            ratio = _ratio(cpu and 1 / cpu["it_per_s"], 1 / r["it_per_s"])
            print(f"{device:<8} {r['it_per_s']:>8.2f} {ratio:>8} {minutes:>8.1f} min")
        names = list(dict.fromkeys(k for r in arms.values() if r for k in r["phases"]))
        shown = [d for d, r in arms.items() if r]
        print(f"{'ms per step':<26}" + "".join(f"{d:>10}" for d in shown) + f"{'cpu/cuda':>10}")
        for name in [*names, "step"]:
            row = [
                r["ms_per_step"] if name == "step" else r["phases"].get(name, 0.0)
                for d, r in arms.items()
                if r
            ]
            cuda = arms.get("cuda")
            other = cuda and (cuda["ms_per_step"] if name == "step" else cuda["phases"].get(name))
            ratio = _ratio(cpu and row[0], other)
            print(f"{name:<26}" + "".join(f"{v:>10.1f}" for v in row) + f"{ratio:>10}")


def _steps(trainer: Trainer, it: int, count: int) -> tuple[int, float]:
    """Run ``count`` training steps from iteration ``it``: (the next iteration, seconds until
    the device finished them)."""
    start = time.perf_counter()
    for _ in range(count):
        trainer.step(it)
        it += 1
    _sync(trainer.device)
    return it, time.perf_counter() - start
