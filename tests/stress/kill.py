"""Crash safety: SIGKILL `evsplat train` / `simulate --tiny` / `export` at random moments, then
check that every file a later command reads is absent or complete and that `--resume` continues
from the newest complete checkpoint."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evsplat.errors import EvsplatError

if TYPE_CHECKING:
    from evsplat.config import TrainConfig

KILL_ITERS = 12  # iterations of each killed tiny training run
KILL_CKPT_EVERY = 3
KILL_GAUSSIANS = 300  # the tiny preset with fewer Gaussians: crash safety, not quality


def kill_config() -> TrainConfig:
    """The tiny preset shrunk so that a killed run and its resume take seconds."""
    from evsplat.config import preset

    cfg = preset("tiny")
    cfg.num_gaussians = KILL_GAUSSIANS
    cfg.schedule.iterations = KILL_ITERS
    cfg.schedule.checkpoint_every = KILL_CKPT_EVERY
    return cfg


def _cli(*args: str | Path) -> list[str]:
    return [sys.executable, "-m", "evsplat.cli", *map(str, args)]


def _run_and_kill(cmd: list[str], after_s: float) -> bool:
    """Start ``cmd``, SIGKILL it ``after_s`` seconds later; True if it was still running."""
    env = {**os.environ, "EVSPLAT_QUIET": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    try:
        proc.wait(timeout=after_s)
        return False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return True


def _timed(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def check_dataset_output(out: Path) -> list[str]:
    """A killed `simulate`: its --out folder is absent or a complete, valid dataset."""
    from evsplat.data.dataset import check_dataset

    if not out.exists():
        return []
    return [f"{out}: {p}" for p in check_dataset(out)]


def check_ply_output(path: Path, before: bytes | None) -> list[str]:
    """A killed `export`: the PLY is absent, the old file byte for byte, or complete."""
    if not path.exists():
        return [] if before is None else [f"{path}: existing export deleted"]
    data = path.read_bytes()
    if data == before:
        return []
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        return [f"{path}: no complete PLY header"]
    header = data[: end + len(b"end_header\n")].decode("ascii").splitlines()
    n = next(int(h.split()[2]) for h in header if h.startswith("element vertex"))
    props = sum(1 for h in header if h.startswith("property float"))
    want = end + len(b"end_header\n") + 4 * n * props
    return [] if len(data) == want else [f"{path}: {len(data)} bytes, a complete PLY has {want}"]


def check_run_output(run: Path) -> list[str]:
    """A killed `train`: every JSON file parses and every listed checkpoint loads."""
    from evsplat.checkpoint import list_checkpoints
    from evsplat.run_state import RunState

    problems = []
    for name in ("config.json", "stats.json"):
        if (run / name).exists():
            try:
                json.loads((run / name).read_text())
            except ValueError:
                problems.append(f"{run / name}: not valid JSON")
    if (run / "log.jsonl").exists():
        try:
            for line in (run / "log.jsonl").read_text().splitlines():
                json.loads(line)
        except ValueError:
            problems.append(f"{run / 'log.jsonl'}: a line is not valid JSON")
    for ckpt in list_checkpoints(run):
        try:
            RunState.load(ckpt)
        except EvsplatError as e:
            problems.append(str(e))
    return problems


def resume_and_check(data: Path, run: Path, iters: int) -> list[str]:
    """``--resume`` a killed run: it must start at the newest complete checkpoint's iteration
    (0 when there is none) and finish with a checkpoint at ``iters``."""
    from evsplat.checkpoint import latest_checkpoint
    from evsplat.run_state import RunState
    from evsplat.train import loop, train

    latest = latest_checkpoint(run)
    expected = RunState.load(latest).iteration if latest is not None else 0
    started: list[int] = []
    original = loop.Trainer.run

    def spy(self: loop.Trainer, progress: bool = True) -> loop.TrainStats:
        started.append(self.start_iteration)
        return original(self, progress)

    loop.Trainer.run = spy  # observe where the resumed loop starts; restored below
    try:
        train(data, run, config=kill_config(), iterations=iters, resume=True, progress=False)
    finally:
        loop.Trainer.run = original
    problems = []
    if started != [expected]:
        problems.append(f"{run}: resumed at {started}, newest complete checkpoint is {expected}")
    final = latest_checkpoint(run)
    if final is None or RunState.load(final).iteration != iters:
        problems.append(f"{run}: resumed run did not finish at iteration {iters}")
    return problems


@dataclass
class KillReport:
    """Outcome of the SIGKILL trials."""

    trials: dict[str, int] = field(default_factory=lambda: {"train": 0, "simulate": 0, "export": 0})
    killed_mid_run: int = 0  # trials where the process was still running when killed
    resumed: int = 0
    corrupt: list[str] = field(default_factory=list)


KINDS = ("train", "simulate", "export")


def kill_trials(n: int, work: Path, seed: int = 0, kinds: Sequence[str] = KINDS) -> KillReport:
    """``n`` SIGKILL trials cycling through ``kinds`` (train / simulate --tiny / export), each
    killed at a uniform random moment within the command's measured uninterrupted wall time."""
    from evsplat.data.simulator import simulate_dataset
    from evsplat.train import train

    rng = np.random.default_rng(seed)
    data = work / "data"
    simulate_dataset("ball", data, tiny=True, seed=0, progress=False)
    source_run = work / "source_run"
    if "export" in kinds:
        train(data, source_run, config=kill_config(), iterations=2, progress=False)
    config = work / "kill_config.json"
    config.write_text(json.dumps(kill_config().to_dict()))
    train_args = ("--config", config, "--iters", KILL_ITERS, "--checkpoint-every", KILL_CKPT_EVERY)
    cmds = {
        "train": lambda out: _cli("train", data, "--out", out, *train_args, "--no-progress"),
        "simulate": lambda out: _cli(
            "simulate", "--scene", "ball", "--tiny", "--out", out, "--no-progress"
        ),  # fmt: skip
        "export": lambda out: _cli("export", source_run, "--ply", out),
    }
    # Uninterrupted wall times (interpreter start included) bound the random kill moments.
    duration = {k: _timed(cmds[k](work / f"timing_{k}")) for k in kinds}
    previous_ply = (work / "timing_export").read_bytes() if "export" in kinds else None
    report = KillReport()
    for i in range(n):
        kind = kinds[i % len(kinds)]
        out = work / f"{kind}_{i}"
        if kind == "export":  # an older export sits where the new one goes: it must survive
            out.write_bytes(previous_ply)
        report.killed_mid_run += _run_and_kill(cmds[kind](out), rng.uniform(0, duration[kind]))
        report.trials[kind] += 1
        if kind == "simulate":
            report.corrupt += check_dataset_output(out)
        elif kind == "export":
            report.corrupt += check_ply_output(out, previous_ply)
        else:
            found = check_run_output(out)
            report.corrupt += found
            if not found:
                report.corrupt += resume_and_check(data, out, KILL_ITERS)
                report.resumed += 1
    return report
