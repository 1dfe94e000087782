"""One cell on one worker: train in a child process, score on the held-out frames, and publish
the run folder and its result row atomically under the sweep's output folder.

The same function runs in the local runner's process and inside a Ray task. It takes the
dataset's path, never its events: a worker reads the data in place from a path every worker
sees, so no event file goes through Ray's object store.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from evsplat.data.atomic import write_text_atomic
from evsplat.sweep import store
from evsplat.sweep.cell import Cell, code_version


@dataclass(frozen=True)
class Outcome:
    """What a cell attempt returns: its result row, or a one-line error."""

    key: str
    row: dict | None
    error: str | None = None
    host: str = ""


class CellError(Exception):
    """A cell that cannot finish; its message is the summary's one line for it."""


def execute_cell(cell: Cell, out: Path, code: str) -> Outcome:
    """Run ``cell`` unless it is already finished; ``code`` is the driver's code version."""
    key, host = cell.key(code), socket.gethostname()
    log = store.log_path(out, key)
    log.parent.mkdir(parents=True, exist_ok=True)
    _note(log, f"== attempt on {host} pid {os.getpid()} at {time.strftime('%Y-%m-%d %H:%M:%S')}")
    done = store.finished(out, key)  # a retry of an attempt that had already published
    if done is not None:
        _note(log, "already finished")
        return Outcome(key, done, host=host)
    try:
        row = _train_and_score(cell, out, key, log, host, code)
    except CellError as e:
        _note(log, f"failed: {e}")
        return Outcome(key, None, str(e), host)
    except Exception as e:  # any failure is this cell's alone: the sweep goes on
        _note(log, traceback.format_exc())
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return Outcome(key, None, f"{type(e).__name__}: {first} (log: {log})", host)
    _note(log, "finished")
    return Outcome(key, row, host=host)


def _train_and_score(cell: Cell, out: Path, key: str, log: Path, host: str, code: str) -> dict:
    from evsplat.eval import evaluate_run
    from evsplat.gpu import adapter_label  # the worker's, which trained and scored the cell

    mine = code_version()
    if mine != code:
        raise CellError(
            f"worker {host} runs evsplat {mine}, the driver {code}: install the same evsplat "
            "build on every node"
        )
    if not (cell.data / "meta.json").is_file():
        raise CellError(
            f"dataset {cell.data} not found on worker {host}: datasets must be on a path every "
            "worker sees (a shared filesystem; docs/scale-out.md)"
        )
    tmp = store.attempt_dir(out, key)
    spec = cell.to_dict() | {"code_version": code}
    write_text_atomic(tmp / "cell.json", json.dumps(spec, indent=2))
    write_text_atomic(tmp / "config.json", json.dumps(spec["config"]))
    run = tmp / "run"
    cmd = [sys.executable, "-m", "evsplat.sweep.child", str(os.getpid()), "train", str(cell.data)]
    cmd += ["--out", str(run), "--config", str(tmp / "config.json"), "--no-progress"]
    cmd += list(cell.train_args)
    start = time.perf_counter()
    with open(log, "a") as f:
        env = {**os.environ, "EVSPLAT_QUIET": "1"}
        code_ = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env).returncode
    wall = time.perf_counter() - start
    if code_ != 0:
        raise CellError(f"training failed ({_failure(log, code_)}; log: {log})")
    stats = json.loads((run / "stats.json").read_text())
    metrics = _score(evaluate_run, run, cell.data)
    row = {
        "scene": cell.scene,
        "seed": cell.seed,
        "config_hash": cell.config_hash,
        "code_version": code,
        "key": key,
        "host": host,
        "adapter": adapter_label(),
        "run": f"cells/{key}/run",
        "iterations": stats["iterations"],
        "wall_seconds": round(wall, 2),
        "iterations_per_second": round(stats["iterations_per_second"], 3),
        "peak_rss_mib": round(stats["peak_rss_mib"], 1),
        "gaussians": stats["gaussians"],
        **metrics,
        "static_fraction": stats.get("static_fraction", 0.0),
        "static_scene": stats.get("static_scene", False),
        "stopped_early_at": stats.get("stopped_early_at"),
    }
    write_text_atomic(tmp / "result.json", json.dumps(row, indent=2))  # last: marks it finished
    store.publish(tmp, out, key)
    return row


METRICS = ("psnr", "psnr_flat", "ssim", "lpips", "psnr_moving", "psnr_moving_flat")


def _score(evaluate_run, run: Path, data: Path) -> dict:
    """Held-out metrics (eval.json etc. into the run folder) and the moving object's region
    tracking error (``track_px``); None for what the data cannot score (a real camera's
    recording has no ground-truth frames, a scene without an object centre no tracking)."""
    if not (data / "test" / "frames.json").is_file():
        return dict.fromkeys((*METRICS, "track_px"))
    result = evaluate_run(run, data)
    tracking = result["tracking"]
    track = None if tracking is None else tracking["region"]["error_px_median"]
    return {k: result["mean"][k] for k in METRICS} | {"track_px": track}


def _failure(log: Path, returncode: int) -> str:
    """The training process's own one-line error, else its exit status."""
    lines = log.read_text(errors="replace").splitlines()
    start = max((i for i, x in enumerate(lines) if x.startswith("== attempt")), default=0)
    errors = [x for x in lines[start:] if x.startswith("evsplat train: error:")]
    if errors:
        return errors[-1].removeprefix("evsplat train: error: ")
    if returncode < 0:
        return f"killed by signal {-returncode}"
    return f"exit status {returncode}"


def _note(log: Path, text: str) -> None:
    with open(log, "a") as f:
        f.write(text.rstrip("\n") + "\n")
