"""Checkpoint files: written atomically, validated on load, and found again for ``--resume``.

Layout inside a run folder: ``checkpoints/ckpt_<iteration>.pt`` (complete files only, thanks to
the atomic rename) and ``checkpoints/latest`` naming the newest one. What a checkpoint holds,
and its version, is ``evsplat.run_state``'s: this module is the container.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

from evsplat.data.atomic import write_atomic, write_text_atomic
from evsplat.errors import EvsplatError

FORMAT = "evsplat-checkpoint"
_NAME = re.compile(r"^ckpt_(\d+)\.pt$")

#: Per layout version older than the current one, the function that turns a payload of that
#: version into the next version's.
Upgrades = Mapping[int, Callable[[dict[str, Any]], dict[str, Any]]]


def checkpoint_dir(run_dir: Path) -> Path:
    return Path(run_dir) / "checkpoints"


def on_host(value: Any) -> Any:
    """``value`` with every tensor in it (in dicts, lists and tuples) copied to the CPU."""
    if isinstance(value, torch.Tensor):
        return value.cpu()
    if isinstance(value, dict):
        return {k: on_host(v) for k, v in value.items()}
    if type(value) in (list, tuple):  # exactly: a named tuple is rebuilt differently
        return type(value)(on_host(v) for v in value)
    return value


def save_checkpoint(
    run_dir: Path, iteration: int, state: dict[str, Any], version: int, keep: int = 2
) -> Path:
    """Write ``state`` (layout ``version``) as the checkpoint of ``iteration`` and prune all but
    the newest ``keep``. Tensors are saved from CPU copies: a run trained on a GPU loads on a
    machine without one."""
    folder = checkpoint_dir(run_dir)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"ckpt_{iteration:07d}.pt"
    state = on_host(state)
    payload = {"format": FORMAT, "version": version, "iteration": iteration, **state}
    write_atomic(path, lambda tmp: torch.save(payload, tmp))
    write_text_atomic(folder / "latest", path.name + "\n")
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def list_checkpoints(run_dir: Path) -> list[Path]:
    """Complete checkpoints of a run, oldest first (temporary files are never listed)."""
    folder = checkpoint_dir(run_dir)
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name))]
    return [p for _, p in sorted(found)]


def load_checkpoint(path: Path, version: int, upgrades: Upgrades) -> dict[str, Any]:
    """Load and validate one checkpoint file, upgraded to layout ``version`` one version at a
    time; foreign, damaged and unknown-version files are one-line errors."""
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except FileNotFoundError:
        raise EvsplatError(
            f"{path}: checkpoint not found; train first or pass a run folder"
        ) from None
    except Exception as e:  # torch raises many types for damaged zip/pickle data
        raise EvsplatError(
            f"{path}: not a readable checkpoint ({type(e).__name__}); delete it and resume from an "
            "earlier one or retrain"
        ) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise EvsplatError(
            f"{path}: not an evsplat checkpoint; pass a run folder made by `evsplat train`"
        )
    while (found := state.get("version")) in upgrades:
        try:
            state = {**upgrades[found](state), "version": found + 1}
        except KeyError as e:
            raise EvsplatError(f"{path}: version {found} checkpoint lacks {e}; retrain") from None
    if found != version:
        readable = ", ".join(str(v) for v in sorted({*upgrades, version}))
        raise EvsplatError(
            f"{path}: checkpoint format version {found} but this evsplat reads version "
            f"{readable}; retrain with this version"
        )
    return state


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint of a run, or None when it has none."""
    found = list_checkpoints(run_dir)
    return found[-1] if found else None


def run_checkpoint(run_dir: Path) -> Path:
    """The newest checkpoint of a run folder (or a checkpoint file given directly)."""
    run_dir = Path(run_dir)
    if run_dir.is_file():
        return run_dir
    if not run_dir.is_dir():
        raise EvsplatError(
            f"{run_dir}: no such run folder; pass the --out folder of `evsplat train`"
        )
    latest = latest_checkpoint(run_dir)
    if latest is None:
        raise EvsplatError(f"{run_dir}: no checkpoint in this run folder; train it first")
    return latest
