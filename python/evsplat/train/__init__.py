"""Training: stages, schedule, checkpoints, depth priors and the loop.

``train`` is the Python API behind ``evsplat train``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from evsplat.errors import EvsplatError

if TYPE_CHECKING:
    from evsplat.config import TrainConfig
    from evsplat.train.progress import TrainStats

__all__ = ["train"]


def train(
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    config: TrainConfig | None = None,
    preset_name: str = "default",
    iterations: int | None = None,
    resume: bool = False,
    depth_prior: str = "auto",
    progress: bool = True,
    device: str | None = None,
) -> TrainStats:
    """Train a dynamic Gaussian scene on a dataset folder, writing checkpoints to ``out_dir``.

    With ``resume`` the newest complete checkpoint in ``out_dir`` is continued (its saved
    configuration wins); without it, an ``out_dir`` that already holds checkpoints is an error so
    a finished run is never overwritten by accident. ``device`` (auto | cpu | cuda) overrides
    the configuration's; a resumed run takes it, else ``auto``, not the device it was saved on
    (checkpoints hold CPU tensors, so a CUDA run resumes on a CPU).
    """
    # Imported here so `evsplat.train`'s light modules load without the data/model stack.
    import torch

    from evsplat.checkpoint import latest_checkpoint
    from evsplat.config import preset
    from evsplat.data.dataset import load_dataset
    from evsplat.run_state import RunState
    from evsplat.train.depth_prior import make_depth_prior
    from evsplat.train.loop import Trainer

    out = Path(out_dir)
    data = load_dataset(data_dir)
    latest = latest_checkpoint(out)
    if latest is not None and not resume:
        raise EvsplatError(
            f"{out}: already holds a trained run; pass --resume to continue it "
            "or choose a new --out"
        )
    if latest is not None:
        cfg = RunState.load(latest).config
        cfg.device = "auto"
    else:
        cfg = config or preset(preset_name)
    if device is not None:
        cfg.device = device
    if cfg.time_range is not None:
        data = data.between(*_range_us(data.t_start_us, data.t_end_us, cfg.time_range))
    if iterations is not None:
        if iterations < 1:
            raise EvsplatError(f"--iters {iterations}: must be at least 1")
        cfg.schedule.iterations = iterations
    callers_threads = torch.get_num_threads()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    try:
        trainer = Trainer(data, cfg, out, make_depth_prior(depth_prior, data))
        if latest is not None:
            trainer.resume()
        return trainer.run(progress=progress)
    finally:
        torch.set_num_threads(callers_threads)  # a preset's setting ends with its run


def _range_us(
    start_us: int, end_us: int, seconds: tuple[float | None, float | None]
) -> tuple[int, int]:
    """A (START, END) time range in seconds from ``start_us`` (None: that end of the data) as
    absolute µs; whole µs, so the integer clock is never in floating point."""
    a, b = seconds
    return (
        start_us if a is None else start_us + round(a * 1e6),
        end_us if b is None else start_us + round(b * 1e6),
    )
