"""Sweeps: many training runs (scenes x configurations x seeds, or every recording of a
dataset) as cells that run locally or as Ray tasks, resumable and idempotent
(docs/scale-out.md)."""

from evsplat.sweep.cell import Cell, code_version
from evsplat.sweep.runner import SweepOptions, SweepResult, add_sweep_arguments, run_sweep

__all__ = [
    "Cell",
    "SweepOptions",
    "SweepResult",
    "add_sweep_arguments",
    "code_version",
    "run_sweep",
]
