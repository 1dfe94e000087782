"""What a run reports and when it stops: the steps it skipped, its loss log, and the early stop
on held-out windows."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from evsplat.config import TrainConfig
from evsplat.errors import EvsplatError
from evsplat.train.skips import Plateau, Window, holdout_windows
from evsplat.train.stages import Stage
from evsplat.train.views import Views

MAX_BAD_STEPS = 20  # consecutive non-finite steps before training stops


@dataclass
class StepResult:
    losses: dict[str, float]
    stage: Stage
    skipped: str | None = None  # why the step made no update, if it did not


@dataclass
class TrainStats:
    iterations: int = 0
    skipped_nonfinite: int = 0
    skipped_empty: int = 0
    seconds: float = 0.0
    history: list[dict] = field(default_factory=list)
    stopped_early_at: int | None = None  # completed iterations when the held-out loss plateaued
    hot_pixels: int = 0  # the sensor's hot pixels, whose events training left out


class Progress:
    """A run's counters, loss log and held-out plateau, step by step."""

    def __init__(self, cfg: TrainConfig, views: Views):
        self.cfg = cfg
        self.stats = TrainStats(hot_pixels=0 if views.hot is None else int(views.hot.sum()))
        self.plateau = Plateau()
        self.bad_in_a_row = 0
        # A fixed, noise-free yardstick for early stopping; these windows still train too.
        self.holdout: list[Window] = []
        sk = cfg.skips
        if sk.early_stop:
            data = views.data
            self.holdout = holdout_windows(
                views.esi,
                data.t_start_us,
                data.t_end_us,
                cfg.loss,
                sk.early_stop_windows,
                cfg.seed,
                allowed=views.allowed,
            )

    def account(self, iteration: int, result: StepResult, checkpoints: Path) -> None:
        """Count a skipped step; too many non-finite ones in a row end training."""
        if result.skipped is None:
            self.bad_in_a_row = 0
            return
        if result.skipped.startswith("non-finite"):
            self.stats.skipped_nonfinite += 1
            self.bad_in_a_row += 1
            if self.bad_in_a_row >= MAX_BAD_STEPS:
                raise EvsplatError(
                    f"training stopped at iteration {iteration}: {result.skipped} in "
                    f"{self.bad_in_a_row} steps in a row; the last good checkpoint is kept in "
                    f"{checkpoints}; lower the learning rates or check the data"
                )
        else:
            self.stats.skipped_empty += 1

    def holdout_due(self, done: int) -> bool:
        """Whether the held-out loss is evaluated after ``done`` iterations: never in warm-up,
        where the loss falls fast and the MLP is still off, nor at the end, which stops anyway."""
        sc, sk = self.cfg.schedule, self.cfg.skips
        inside = sc.warmup_end < done < sc.iterations
        return bool(self.holdout) and inside and done % sk.early_stop_every == 0

    def plateaued(self, value: float, done: int, stage: Stage) -> bool:
        """Log the held-out L_e after ``done`` iterations; True when it has not improved for
        ``early_stop_patience`` evaluations."""
        stop = self.plateau.update(value, done, self.cfg.skips)
        entry = {"iteration": done, "stage": stage.value, "holdout_e": value}
        self.stats.history.append({**entry, "holdout_best": self.plateau.best})
        return stop

    def log(self, iteration: int, result: StepResult, stop: bool) -> dict[str, str] | None:
        """Log the step's losses every ``log_every`` iterations, at the end and at an early
        stop; the short form for the progress bar, None when not logged."""
        sc = self.cfg.schedule
        if not (iteration % sc.log_every == 0 or iteration + 1 == sc.iterations or stop):
            return None
        self.stats.history.append(
            {"iteration": iteration, "stage": result.stage.value, **result.losses}
        )
        shown = {k: f"{v:.3g}" for k, v in result.losses.items() if not k.startswith("n_")}
        return {"stage": result.stage.value, **shown}

    def finish(self, iterations: int) -> TrainStats:
        """The run's numbers once it ends after ``iterations``."""
        self.stats.iterations = iterations
        self.stats.stopped_early_at = self.plateau.stopped_at
        return self.stats

    def summary(self, gaussians: int, static_fraction: float, static_scene: bool) -> dict:
        """Run-level numbers for benchmarks: time, rate, skips, size, peak memory."""
        import resource

        s = self.stats
        return {
            "iterations": s.iterations,
            "train_seconds": s.seconds,
            "iterations_per_second": s.iterations / max(s.seconds, 1e-9),
            "skipped_nonfinite": s.skipped_nonfinite,
            "skipped_empty": s.skipped_empty,
            "gaussians": gaussians,
            "stopped_early": s.stopped_early_at is not None,
            "stopped_early_at": s.stopped_early_at,
            "static_fraction": static_fraction,
            "static_scene": static_scene,
            # ru_maxrss is in KiB on Linux
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        }
