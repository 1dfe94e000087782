"""The training loop: event windows -> renders -> the paper's losses -> an optimizer step.

One ``Trainer`` owns the Gaussians, the deformation MLP, their optimizers and the densifier.
Each iteration draws its random choices from ``default_rng([seed, iteration])`` so a resumed
run makes the same choices as an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from evsplat.checkpoint import latest_checkpoint, load_checkpoint, save_checkpoint
from evsplat.config import TrainConfig
from evsplat.data.atomic import write_text_atomic
from evsplat.data.dataset import Dataset
from evsplat.data.events import bayer_channel_map
from evsplat.data.poses import read_tum
from evsplat.errors import EvsplatError
from evsplat.losses.event import event_loss
from evsplat.losses.flow import gaussian_flow_features
from evsplat.model.deform import DeformationMLP
from evsplat.model.densify import Densifier
from evsplat.model.gaussians import GaussianModel
from evsplat.projection import viewmat
from evsplat.render import Renderer
from evsplat.train.coarse import coarse_due, half_renderer
from evsplat.train.depth_prior import DepthPrior
from evsplat.train.init import initial_gaussians, scene_extent
from evsplat.train.mover import MoverTrack
from evsplat.train.objective import motion_losses, refine_losses, track_loss
from evsplat.train.seeding import seed_mover
from evsplat.train.skips import (
    Plateau,
    Window,
    follow_rows,
    holdout_loss,
    holdout_windows,
    scene_unexplained,
    static_due,
    update_static,
)
from evsplat.train.stages import Stage, stage_at
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


class Trainer:
    """Trains a dynamic Gaussian scene from one dataset; see ``run``."""

    def __init__(
        self,
        data: Dataset,
        cfg: TrainConfig,
        run_dir: Path,
        depth_prior: DepthPrior | None = None,
    ):
        self.data = data
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.depth_prior = depth_prior
        torch.manual_seed(cfg.seed)
        if cfg.loss.views < 2:
            raise EvsplatError(f"loss.views = {cfg.loss.views}: L_e needs at least 2 renders")
        self.channels = 1 if data.bayer == "mono" else 3
        self.depth_range = tuple(data.meta.get("depth_range") or cfg.model.init_depth_range)
        self.extent = scene_extent(data, self.depth_range)

        self.model = initial_gaussians(data, cfg, self.channels, self.depth_range)
        self.mlp = DeformationMLP(cfg.model)
        self.optimizer = torch.optim.Adam(
            self.model.param_groups(cfg.model, self.extent), eps=1e-15
        )
        self.mlp_optimizer = self._mlp_adam()
        self.densifier = Densifier(cfg.densify, self.extent, cfg.schedule.iterations)
        self.renderer = Renderer(
            model=self.model,
            mlp=None,
            K=torch.from_numpy(data.K.astype(np.float32)),
            width=data.width,
            height=data.height,
            t_start_us=data.t_start_us,
            t_end_us=data.t_end_us,
            background=cfg.background,
        )
        channel_map = None
        if self.channels == 3:
            cmap = bayer_channel_map(data.bayer, data.width, data.height)
            channel_map = torch.from_numpy(cmap.astype(np.int64))
        self.views = Views(data, self.renderer, channel_map)
        # The measured poses travel with every checkpoint so renders need no dataset.
        self.pose_samples = read_tum(data.root / "poses.txt")
        self.stats = TrainStats()
        self.start_iteration = 0
        self.bad_in_a_row = 0
        sk = cfg.skips
        # A fixed, noise-free yardstick for early stopping; these windows still train too.
        self.holdout: list[Window] = []
        if sk.early_stop:
            self.holdout = holdout_windows(
                self.views.esi,
                data.t_start_us,
                data.t_end_us,
                cfg.loss,
                sk.early_stop_windows,
                cfg.seed,
            )
        self.plateau = Plateau()
        self.static_scene = False  # set when the static classification finds no motion
        self.mover_track: MoverTrack | None = None  # set by the mover's seeding

    # ---- one iteration -------------------------------------------------------------------

    def step(self, iteration: int) -> StepResult:
        cfg, lc = self.cfg, self.cfg.loss
        stage = stage_at(iteration, cfg.schedule)
        rng = np.random.default_rng([cfg.seed, iteration])
        # torch's own randomness (densification splits) is re-seeded per iteration too, so a
        # resumed run makes exactly the choices an uninterrupted one makes.
        torch.manual_seed(int(rng.integers(2**62)))
        duration = self.data.t_end_us - self.data.t_start_us
        motion_stage = cfg.deform and stage is not Stage.WARMUP
        if motion_stage and not self.static_scene:
            if static_due(cfg.skips, iteration, cfg.schedule.iterations):
                self._classify_static()  # may find the whole scene static
        seeded = {}
        # Right after the warm-up (none: no static model to find a mover against).
        if motion_stage and cfg.mover.enabled and iteration == cfg.schedule.warmup_end > 0:
            seeded = self.seed_mover()
        moving = motion_stage and not self.static_scene
        self.renderer.mlp = self.mlp if moving else None
        coarse = coarse_due(cfg, iteration, stage)
        view = half_renderer(self.renderer) if coarse else self.renderer

        # `views` render times t_0 < ... < t_last, consecutive gaps of random length; L_e compares
        # every pair (with 3 views: three windows from three renders instead of one from two).
        # The short flow window of L_ef starts at the last time, where the motion losses attach.
        draw = [rng.uniform(lc.window_min, lc.window_max) for _ in range(lc.views - 1)]
        gaps = [int(g * duration) for g in draw]
        dtau = max(int(lc.flow_window * duration), 1) if moving else 0
        span = sum(gaps)
        if span > duration - dtau:
            return StepResult({}, stage, skipped="windows longer than the sequence")
        t1 = int(rng.integers(self.data.t_start_us + span, self.data.t_end_us - dtau + 1))
        times = [t1 - sum(gaps[k:]) for k in range(lc.views - 1)] + [t1]
        pairs = [(i, j) for j in range(lc.views) for i in range(j)]
        windows = [self.views.esi(times[i], times[j], coarse) for i, j in pairs]
        if all(count == 0 for _, _, count in windows):
            return StepResult({}, stage, skipped="no events in window")

        pose1 = self.views.pose(t1)
        g1 = view.gaussians_at(t1)
        extra = None
        if moving and lc.w_flow > 0:
            # Gaussian flow: 2-D motion of each Gaussian over [t1, t1 + dtau] at the pose of t1.
            means_later = view.gaussians_at(t1 + dtau)[0]
            extra = gaussian_flow_features(g1[0], means_later, viewmat(pose1), view.K)
            if not lc.flow_moves_gaussians:
                extra = extra.detach()
        out1 = view.render(t1, pose1, extra=extra, gaussians=g1)
        logs = [self.views.log_image_at(t, view) for t in times[:-1]]
        log1 = self.views.log_image(out1, coarse)
        logs.append(log1)
        terms = [
            event_loss(logs[j] - logs[i], esi, mask, lc.lambda_ssim)
            for (i, j), (esi, mask, count) in zip(pairs, windows)
            if count > 0
        ]
        losses: dict[str, torch.Tensor] = {"e": torch.stack(terms).mean()}
        if moving:
            losses.update(
                motion_losses(
                    self.views, view, self.model, self.mlp, lc, t1, dtau, pose1, out1, rng
                )
            )
            track = track_loss(self.mover_track, self.renderer, self.model, g1[0], t1)
            if track is not None:
                losses["tr"] = track
        if stage is Stage.REFINE:
            # The refinement losses see the last window (pairs end with (views-2, views-1)).
            delta, mask = logs[-1] - logs[-2], windows[-1][1]
            losses.update(refine_losses(self.data, lc, self.depth_prior, t1, out1, delta, mask))

        weights = {
            "e": 1.0,
            "ef": lc.w_flow,
            "m": lc.w_motion,
            "d": lc.w_depth,
            "ne": lc.w_non_event,
            "sp": lc.w_spatial,
            "tr": cfg.mover.track_weight,
        }
        total = sum(weights[k] * v for k, v in losses.items())
        values = {k: float(v.detach()) for k, v in losses.items()} | seeded
        values["total"] = float(total.detach())
        bad = next((k for k, v in values.items() if not math.isfinite(v)), None)
        if bad is None and moving and self._grad_norms_due(iteration):
            values.update(self._mlp_grad_norms({k: weights[k] * v for k, v in losses.items()}))
        if bad is None:
            total.backward()
            bad = self._first_nonfinite_grad()
        if bad is not None:
            self._zero_grads()
            return StepResult(values, stage, skipped=f"non-finite {bad}")

        self.densifier.accumulate(
            out1.meta["means2d_grad"], out1.meta["radii"], view.width, view.height
        )
        self.optimizer.step()
        if moving:
            self.mlp_optimizer.step()
        self._zero_grads()
        self._schedule_learning_rates(iteration)
        counts = self.densifier.step(self.model, self.optimizer, iteration)
        if counts:
            values.update({f"n_{k}": float(v) for k, v in counts.items()})
        static = self.renderer.static_mask
        if static is not None:
            if counts:  # clones, splits and prunes change the rows the mask must follow
                self.renderer.static_mask = follow_rows(static, self.densifier.origin)
            values["static_frac"] = self._static_fraction()
        values["gaussians"] = float(self.model.means.shape[0])
        return StepResult(values, stage)

    def seed_mover(self) -> dict[str, float]:
        """After the warm-up: the mover's seeding (``seeding.seed_mover``); numbers for the log."""
        seeding = seed_mover(
            self.views, self.model, self.optimizer, self.mlp, self.cfg, self.depth_range
        )
        if seeding.seeded:
            self.mlp_optimizer = self._mlp_adam()  # the fit's moments are not training's
            self.mover_track = seeding.track
        return seeding.stats

    def _mlp_adam(self) -> torch.optim.Adam:
        return torch.optim.Adam(self.mlp.parameters(), lr=self.cfg.model.mlp_lr)

    def _classify_static(self) -> None:
        """Mark the dynamic Gaussians that stopped moving static (``skips.update_static``);
        the first classification may find the whole scene static."""
        centre = torch.from_numpy(self.pose_samples[1][:, :3, 3].mean(0).astype(np.float32))
        focal = float(self.data.K[0, 0])
        whole = update_static(
            self.model,
            self.mlp,
            self.renderer,
            centre,
            focal,
            self.cfg.skips,
            self.unexplained_events,
        )
        self.static_scene = self.static_scene or whole

    def unexplained_events(self) -> float:
        """The static-scene evidence for the model as it is now (``skips.scene_unexplained``)."""
        return scene_unexplained(self.views, self.mlp, self.cfg.loss, self.cfg.skips, self.cfg.seed)

    def _grad_norms_due(self, iteration: int) -> bool:
        every = self.cfg.schedule.grad_norms_every
        return every > 0 and iteration % every == 0

    def _mlp_grad_norms(self, weighted: dict[str, torch.Tensor]) -> dict[str, float]:
        """L2 norm of each weighted loss's gradient on the MLP's parameters (``g_<loss>``):
        which loss teaches the deformation, measured without changing the step (each loss gets
        its own backward pass through the retained graph)."""
        params = [p for p in self.mlp.parameters() if p.requires_grad]
        norms = {}
        for name, value in weighted.items():
            if not value.requires_grad:
                continue
            grads = torch.autograd.grad(value, params, retain_graph=True, allow_unused=True)
            sq = sum(float((g.detach() ** 2).sum()) for g in grads if g is not None)
            norms[f"g_{name}"] = math.sqrt(sq)
        return norms

    def _first_nonfinite_grad(self) -> str | None:
        for name, p in [*self.model.named_parameters(), *self.mlp.named_parameters()]:
            if p.grad is not None and not bool(torch.isfinite(p.grad).all()):
                return f"gradient of {name}"
        return None

    def _zero_grads(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        self.mlp_optimizer.zero_grad(set_to_none=True)

    def _schedule_learning_rates(self, iteration: int) -> None:
        """Exponential decay of the position and MLP learning rates (3DGS / Deformable-3DGS).

        The MLP's rate decays from iteration 0 over ``mlp_lr_horizon`` iterations, a fixed
        horizon as in the authors' code (40k), not the run's length: shrunk to a short run the
        decay left the MLP too small a rate to learn any motion (docs/results.md, session 11).
        """
        mc, sc = self.cfg.model, self.cfg.schedule
        frac = min(iteration / max(sc.iterations, 1), 1.0)
        for group in self.optimizer.param_groups:
            if group.get("name") == "means":
                start = mc.means_lr * self.extent
                group["lr"] = start * (mc.means_lr_final / mc.means_lr) ** frac
        frac_mlp = min(iteration / max(mc.mlp_lr_horizon, 1), 1.0)
        for group in self.mlp_optimizer.param_groups:
            group["lr"] = mc.mlp_lr * (mc.mlp_lr_final / mc.mlp_lr) ** frac_mlp

    # ---- checkpoints ---------------------------------------------------------------------

    def state(self, iteration: int) -> dict:
        """Everything needed to resume at ``iteration`` or to render the result."""
        data = self.data
        return {
            "config": self.cfg.to_dict(),
            "gaussians": self.model.state_for_checkpoint(),
            "mlp": self.mlp.state_dict() if self._mlp_active(iteration) else None,
            "mlp_full": self.mlp.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "mlp_optimizer": self.mlp_optimizer.state_dict(),
            "densifier": self.densifier.state_dict(),
            "static_mask": self.renderer.static_mask,
            "static_scene": self.static_scene,
            "mover_track": None if self.mover_track is None else self.mover_track.state_dict(),
            "early_stop": self.plateau.state_dict(),
            "camera": {
                "K": data.K.tolist(),
                "width": data.width,
                "height": data.height,
                "t_start_us": data.t_start_us,
                "t_end_us": data.t_end_us,
                "channels": self.channels,
                "bayer": data.bayer,
            },
            "trajectory": {"times_us": self.pose_samples[0], "c2w": self.pose_samples[1]},
            "dataset": str(data.root),
            "stats": {
                "skipped_nonfinite": self.stats.skipped_nonfinite,
                "skipped_empty": self.stats.skipped_empty,
                "seconds": self.stats.seconds,
            },
            "history": self.stats.history,
        }

    def restore(self, state: dict, path: Path) -> None:
        """Load a checkpoint of the same dataset and configuration shape."""
        cam = state["camera"]
        if (cam["width"], cam["height"]) != (self.data.width, self.data.height):
            raise EvsplatError(
                f"{path}: checkpoint is for a {state['camera']['width']}x"
                f"{state['camera']['height']} sensor but the data is {self.data.width}x"
                f"{self.data.height}; resume with the dataset it was trained on"
            )
        self.model = GaussianModel.from_checkpoint(state["gaussians"])
        self.renderer.model = self.model
        self.mlp.load_state_dict(state["mlp_full"])
        self.optimizer = torch.optim.Adam(
            self.model.param_groups(self.cfg.model, self.extent), eps=1e-15
        )
        self.optimizer.load_state_dict(state["optimizer"])
        self.mlp_optimizer.load_state_dict(state["mlp_optimizer"])
        self.densifier.load_state_dict(state["densifier"])
        self.renderer.static_mask = state.get("static_mask")  # absent before skips existed
        self.static_scene = bool(state.get("static_scene", False))
        track = state.get("mover_track")  # absent before the track prior existed
        self.mover_track = None if track is None else MoverTrack.from_state(track)
        if "early_stop" in state:
            self.plateau.load_state_dict(state["early_stop"])
        s = state["stats"]
        self.stats.skipped_nonfinite = s["skipped_nonfinite"]
        self.stats.skipped_empty = s["skipped_empty"]
        self.stats.seconds = s["seconds"]
        self.stats.history = list(state["history"])
        self.start_iteration = int(state["iteration"])

    def _mlp_active(self, iteration: int) -> bool:
        """Whether renders after ``iteration`` completed iterations use the MLP."""
        return (
            self.cfg.deform and iteration > self.cfg.schedule.warmup_end and not self.static_scene
        )

    def save(self, iteration: int) -> Path:
        path = save_checkpoint(
            self.run_dir, iteration, self.state(iteration), keep=self.cfg.schedule.keep_checkpoints
        )
        lines = "".join(json.dumps(h) + "\n" for h in self.stats.history)
        write_text_atomic(self.run_dir / "log.jsonl", lines)
        return path

    def resume(self) -> bool:
        """Continue from the newest complete checkpoint of the run folder, if there is one."""
        latest = latest_checkpoint(self.run_dir)
        if latest is None:
            return False
        self.restore(load_checkpoint(latest), latest)
        return True

    # ---- the loop ------------------------------------------------------------------------

    def run(self, progress: bool = True) -> TrainStats:
        """Train from ``start_iteration`` to the end of the schedule, checkpointing on the way;
        a run whose held-out loss plateaued stops there, and stays stopped when resumed."""
        from tqdm import tqdm

        sc = self.cfg.schedule
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.run_dir / "config.json", json.dumps(self.cfg.to_dict(), indent=2))
        end = sc.iterations if self.plateau.stopped_at is None else self.start_iteration
        bar = tqdm(
            range(self.start_iteration, end),
            initial=self.start_iteration,
            total=sc.iterations,
            disable=not progress,
            unit="it",
            dynamic_ncols=True,
        )
        last = self.start_iteration
        for it in bar:
            t = time.perf_counter()
            result = self.step(it)
            self.stats.seconds += time.perf_counter() - t
            last = it + 1
            self._account(it, result)
            stop = self._holdout_due(last) and self._plateaued(last, result.stage)
            if it % sc.log_every == 0 or last == sc.iterations or stop:
                entry = {"iteration": it, "stage": result.stage.value, **result.losses}
                self.stats.history.append(entry)
                shown = {k: f"{v:.3g}" for k, v in result.losses.items() if not k.startswith("n_")}
                bar.set_postfix({"stage": result.stage.value, **shown}, refresh=False)
            if stop:
                break
            # No checkpoint during a streak of skipped steps: the last one stays the last good one.
            if last % sc.checkpoint_every == 0 and last < sc.iterations and not self.bad_in_a_row:
                self.save(last)
        self.save(last)
        self.stats.iterations = last
        self.stats.stopped_early_at = self.plateau.stopped_at
        write_text_atomic(self.run_dir / "stats.json", json.dumps(self.summary(), indent=2))
        return self.stats

    def summary(self) -> dict:
        """Run-level numbers for benchmarks: time, rate, skips, size, peak memory."""
        import resource

        s = self.stats
        return {
            "iterations": s.iterations,
            "train_seconds": s.seconds,
            "iterations_per_second": s.iterations / max(s.seconds, 1e-9),
            "skipped_nonfinite": s.skipped_nonfinite,
            "skipped_empty": s.skipped_empty,
            "gaussians": int(self.model.num_gaussians),
            "stopped_early": s.stopped_early_at is not None,
            "stopped_early_at": s.stopped_early_at,
            "static_fraction": self._static_fraction(),
            "static_scene": self.static_scene,
            # ru_maxrss is in KiB on Linux
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        }

    def _static_fraction(self) -> float:
        static = self.renderer.static_mask
        return 0.0 if static is None else float(static.float().mean())

    def _holdout_due(self, done: int) -> bool:
        """Whether the held-out loss is evaluated after ``done`` iterations: never in warm-up,
        where the loss falls fast and the MLP is still off, nor at the end, which stops anyway."""
        sc, sk = self.cfg.schedule, self.cfg.skips
        inside = sc.warmup_end < done < sc.iterations
        return bool(self.holdout) and inside and done % sk.early_stop_every == 0

    def _plateaued(self, done: int, stage: Stage) -> bool:
        """Evaluate and log the held-out L_e after ``done`` iterations; True when it has not
        improved for ``early_stop_patience`` evaluations."""
        self.renderer.mlp = self.mlp if self._mlp_active(done) else None
        value = holdout_loss(self.holdout, self.views.log_image_at, self.cfg.loss.lambda_ssim)
        stop = self.plateau.update(value, done, self.cfg.skips)
        entry = {"iteration": done, "stage": stage.value, "holdout_e": value}
        self.stats.history.append({**entry, "holdout_best": self.plateau.best})
        return stop

    def _account(self, iteration: int, result: StepResult) -> None:
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
                    f"{self.run_dir / 'checkpoints'}; lower the learning rates or check the data"
                )
        else:
            self.stats.skipped_empty += 1
