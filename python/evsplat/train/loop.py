"""The training loop: event windows -> renders -> the paper's losses -> an optimizer step.

One ``Trainer`` owns the Gaussians, the deformation MLP, their optimizers and the densifier.
Each iteration draws its random choices from ``default_rng([seed, iteration])`` so a resumed
run makes the same choices as an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from evsplat.checkpoint import checkpoint_dir, latest_checkpoint
from evsplat.config import TrainConfig
from evsplat.data.atomic import write_text_atomic
from evsplat.data.dataset import Dataset
from evsplat.data.poses import measured_poses
from evsplat.errors import EvsplatError
from evsplat.losses.event import event_loss
from evsplat.losses.flow import gaussian_flow_features
from evsplat.model.deform import DeformationMLP
from evsplat.model.densify import Densifier
from evsplat.model.motion import ObjectMotion, knot_times_us
from evsplat.motion.seed import seed_objects
from evsplat.projection import viewmat
from evsplat.render import Renderer
from evsplat.run_state import RunState
from evsplat.train.coarse import coarse_due, half_renderer
from evsplat.train.depth_prior import DepthPrior
from evsplat.train.device import training_device
from evsplat.train.gradients import first_nonfinite_grad, grad_norms_due, mlp_grad_norms
from evsplat.train.heldout import heldout_intervals
from evsplat.train.init import initial_gaussians, scene_extent
from evsplat.train.motion_oracle import apply_oracle, true_scene
from evsplat.train.objective import (
    loss_weights,
    motion_events,
    motion_losses,
    refine_losses,
)
from evsplat.train.progress import Progress, StepResult, TrainStats
from evsplat.train.schedule import MOTION_GROUPS, decay_learning_rates
from evsplat.train.skips import (
    follow_rows,
    holdout_loss,
    scene_unexplained,
    static_due,
    update_static,
)
from evsplat.train.snapshot import restore, snapshot
from evsplat.train.stages import Stage, look_again_at, stage_at
from evsplat.train.views import Views


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
        true_scene(cfg.mover.oracle, data)  # a bad mover.oracle stops here, before training
        self.channels = 1 if data.bayer == "mono" else 3
        self.depth_range = tuple(data.meta.get("depth_range") or cfg.model.init_depth_range)
        self.extent = scene_extent(data, self.depth_range)

        self.device = training_device(cfg.device)
        self.model = initial_gaussians(data, cfg, self.channels, self.depth_range).to(self.device)
        self.mlp = DeformationMLP(cfg.model).to(self.device)
        self.optimizer = self.gaussians_adam()
        self.mlp_optimizer = self.mlp_adam()
        self.densifier = Densifier(cfg.densify, self.extent, cfg.schedule.iterations)
        self.renderer = Renderer(
            model=self.model,
            mlp=None,
            K=torch.from_numpy(data.K.astype(np.float32)).to(self.device),
            width=data.width,
            height=data.height,
            t_start_us=data.t_start_us,
            t_end_us=data.t_end_us,
            background=cfg.background,
        )
        # Never read in training; saved with the run for `evsplat eval` (``train.heldout``).
        self.heldout = heldout_intervals(data.t_start_us, data.t_end_us, cfg.holdout, cfg.seed)
        self.views = Views.of(data, self.renderer, self.heldout)
        # The measured poses travel with every checkpoint so renders need no dataset.
        self.pose_samples = measured_poses(data.root, data.meta)
        self.progress = Progress(cfg, self.views)
        self.start_iteration = 0
        self.static_scene = False  # set when the static classification finds no motion

    # ---- one iteration -------------------------------------------------------------------

    def step(self, iteration: int) -> StepResult:
        cfg, lc = self.cfg, self.cfg.loss
        stage = stage_at(iteration, cfg.schedule)
        rng = np.random.default_rng([cfg.seed, iteration])
        # torch's own randomness (densification splits) is re-seeded per iteration too, so a
        # resumed run makes exactly the choices an uninterrupted one makes.
        torch.manual_seed(int(rng.integers(2**62)))
        motion_stage = cfg.deform and stage is not Stage.WARMUP
        if motion_stage and not self.static_scene:
            if static_due(cfg.skips, iteration, cfg.schedule.iterations):
                self._classify_static()  # may find the whole scene static
        seeded = {}
        # Right after the warm-up (none: no static model to find the objects against), and
        # once more against all found by then.
        if motion_stage and cfg.mover.enabled and iteration == cfg.schedule.warmup_end > 0:
            self.renderer.mlp = None  # the warm-up's static model
            seeded = self.seed_objects()
        again = iteration == look_again_at(cfg) and not self.static_scene
        if motion_stage and cfg.mover.enabled and again:
            seeded = {f"again_{k}": v for k, v in self.seed_objects(again=True).items()}
        moving = motion_stage and not self.static_scene
        self.renderer.mlp = self.mlp if moving else None
        coarse = coarse_due(cfg, iteration, stage)
        view = half_renderer(self.renderer) if coarse else self.renderer

        # L_e compares every pair of the render times (with 3 views: three windows from three
        # renders instead of one from two); the motion losses attach to the last time, t1.
        drawn = self.views.draw_times(rng, lc, moving)
        if drawn is None:
            return StepResult({}, stage, skipped="windows longer than the sequence")
        times, dtau = drawn
        t1 = times[-1]
        pairs = [(i, j) for j in range(lc.views) for i in range(j)]
        if not any(self.views.has_events(times[i], times[j]) for i, j in pairs):
            return StepResult({}, stage, skipped="no events in window")

        # Each render is started on the device and the step goes on (the next render's MLP, the
        # event windows) while it is drawn: on a CPU adapter lavapipe's threads use the core
        # this thread leaves idle. Same values, and the same autograd graph, as rendering in
        # place.
        pose1 = self.views.pose(t1)
        g1 = view.gaussians_at(t1)
        extra = None
        if moving and lc.w_flow > 0:
            # Gaussian flow: 2-D motion of each Gaussian over [t1, t1 + dtau] at the pose of t1,
            # computed without a graph when the flow may not move them (the MLP runs once more).
            with torch.set_grad_enabled(lc.flow_moves_gaussians):
                means_later = view.gaussians_at(t1 + dtau)[0]
                extra = gaussian_flow_features(
                    g1[0], means_later, viewmat(pose1, view.K.device), view.K
                )
        pending1 = view.render_async(t1, pose1, extra=extra, gaussians=g1)
        earlier = [view.render_async(t, self.views.pose(t)) for t in times[:-1]]
        windows = [self.views.esi(times[i], times[j], coarse) for i, j in pairs]
        if all(count == 0 for _, _, count in windows):  # a transform dropped every event
            return StepResult({}, stage, skipped="no events in window")
        events1 = motion_events(self.views, lc, t1, dtau, coarse) if moving else None
        out1 = pending1.result()
        logs = [self.views.log_image(p.result(), coarse) for p in earlier]
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
                    self.views,
                    view,
                    self.model,
                    self.mlp,
                    lc,
                    t1,
                    dtau,
                    pose1,
                    out1,
                    events1,
                    rng,
                )
            )
            if self.renderer.motion is not None and cfg.mover.track_weight > 0:
                losses["tr"] = self.renderer.motion.prior_loss()
        if stage is Stage.REFINE:
            # The refinement losses see the last window (pairs end with (views-2, views-1)).
            delta, mask = logs[-1] - logs[-2], windows[-1][1]
            losses.update(refine_losses(self.data, lc, self.depth_prior, t1, out1, delta, mask))

        weights = loss_weights(cfg)
        weighted = {k: weights[k] * v for k, v in losses.items()}
        total = sum(weighted.values())
        values = {k: float(v.detach()) for k, v in losses.items()} | seeded
        values["total"] = float(total.detach())
        bad = next((k for k, v in values.items() if not math.isfinite(v)), None)
        if bad is None and moving and grad_norms_due(cfg.schedule.grad_norms_every, iteration):
            values.update(mlp_grad_norms(self.mlp, weighted))
        if bad is None:
            total.backward()
            bad = first_nonfinite_grad(self.model, self.mlp)
        if bad is not None:
            self._zero_grads()
            return StepResult(values, stage, skipped=f"non-finite {bad}")

        # The update: Adam, the learning-rate schedule, densification (the static mask follows).
        self.densifier.accumulate(
            out1.meta["means2d_grad"], out1.meta["radii"], view.width, view.height
        )
        self.optimizer.step()
        if moving:
            self.mlp_optimizer.step()
        self._zero_grads()
        decay_learning_rates(self.optimizer, self.mlp_optimizer, cfg, self.extent, iteration)
        counts = self.densifier.step(self.model, self.optimizer, iteration, self._swept(iteration))
        values.update({f"n_{k}": float(v) for k, v in counts.items()})
        static, objects = self.renderer.static_mask, self.renderer.object_id
        if counts and objects is not None:  # clones, splits and prunes change the rows
            self.renderer.object_id = follow_rows(objects, self.densifier.origin)
        if static is not None:
            if counts:
                self.renderer.static_mask = follow_rows(static, self.densifier.origin)
            values["static_gaussians"] = self.static_fraction()  # the background, after seeding
        if motion_stage:  # 1 once the scene-level check baked the MLP away
            values["static_scene"] = float(self.static_scene)
        values["gaussians"] = float(self.model.means.shape[0])
        return StepResult(values, stage)

    def _swept(self, iteration: int) -> torch.Tensor | None:
        """The scene's Gaussians in the space an object passes through or hides
        (``ObjectMotion.swept``), for the density control to prune where it runs at
        ``iteration``."""
        r, data = self.renderer, self.data
        if r.motion is None or r.object_id is None or not self.densifier.densifies(iteration):
            return None
        knots = knot_times_us(data.t_start_us, data.t_end_us, r.motion.translations.shape[1])
        eyes = torch.from_numpy(data.trajectory.pose(knots)[:, :3, 3]).to(self.model.means)
        return r.motion.swept(self.model.means.detach(), r.object_id, eyes)

    def seed_objects(self, again: bool = False) -> dict[str, float]:
        """Find the moving objects and start their motion (``motion.seed.seed_objects``); the
        scene's Gaussians skip the MLP from then on, and so do the objects' without
        ``mover.residual``. ``again``: look once more against all
        that the model draws, objects found before included, and start the new ones from the
        scene's Gaussians (their static decision reversed). Numbers for the log."""
        start = time.perf_counter()
        r = self.renderer
        known = (r.motion, r.object_id) if again and r.motion is not None else None
        found = seed_objects(
            self.views,
            self.model,
            self.optimizer,
            self.cfg.mover,
            self.cfg.seed,
            self.depth_range,
            known,
        )
        if found.stats["objects"] > 0 and found.motion is not None:
            motion, object_id = found.motion.to(self.device), found.object_id.to(self.device)
            mode = self.cfg.mover.oracle  # read here: `bench seeding --against` may set it
            if mode != "none":
                scene = true_scene(mode, self.data)
                found.stats |= apply_oracle(motion, found.references_us, mode, scene, self.data)
            static = r.static_mask
            r.motion, r.object_id = motion, object_id
            scene = (object_id < 0) | (not self.cfg.mover.residual)  # rigid objects skip it too
            r.static_mask = scene if static is None else static & scene
            self.mlp_optimizer = self.mlp_adam(motion)  # the paths train beside the MLP
        return found.stats | {"seed_seconds": time.perf_counter() - start}

    # Both optimizers take torch's multi-tensor ("foreach") Adam, which torch picks by default
    # only for GPU tensors: on the CPU it gives the same values bit for bit and halves the MLP
    # update's time (docs/experiments/training-speed.md, "The training step at the demo size").
    def gaussians_adam(self) -> torch.optim.Adam:
        groups = self.model.param_groups(self.cfg.model, self.extent)
        return torch.optim.Adam(groups, eps=1e-15, foreach=True)

    def mlp_adam(self, motion: ObjectMotion | None = None) -> torch.optim.Adam:
        """Adam on the MLP, and on the objects' rigid ``motion`` once they are found."""
        groups = [{"params": list(self.mlp.parameters()), "lr": self.cfg.model.mlp_lr}]
        mc = self.cfg.mover
        if motion is not None:
            lrs = (mc.path_lr, mc.turn_lr)
            params = (motion.translations, motion.rotvecs)
            groups += [
                {"params": [p], "lr": lr, "name": name}
                for name, p, lr in zip(MOTION_GROUPS, params, lrs)
            ]
        return torch.optim.Adam(groups, foreach=True)

    def _zero_grads(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        self.mlp_optimizer.zero_grad(set_to_none=True)

    def _classify_static(self) -> None:
        """Mark the dynamic Gaussians that stopped moving static (``skips.update_static``);
        the first classification may find the whole scene static."""
        centre = torch.from_numpy(self.pose_samples[1][:, :3, 3].mean(0).astype(np.float32))
        centre = centre.to(self.device)
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

    def mlp_active(self, iteration: int) -> bool:
        """Whether renders after ``iteration`` completed iterations use the MLP."""
        return (
            self.cfg.deform and iteration > self.cfg.schedule.warmup_end and not self.static_scene
        )

    def static_fraction(self) -> float:
        static = self.renderer.static_mask
        return 0.0 if static is None else float(static.float().mean())

    # ---- checkpoints and the loop --------------------------------------------------------

    def save(self, iteration: int) -> Path:
        """The checkpoint after ``iteration`` completed iterations, and the loss log so far."""
        path = snapshot(self, iteration).save(self.run_dir, keep=self.cfg.schedule.keep_checkpoints)
        lines = "".join(json.dumps(h) + "\n" for h in self.progress.stats.history)
        write_text_atomic(self.run_dir / "log.jsonl", lines)
        return path

    def resume(self) -> bool:
        """Continue from the newest complete checkpoint of the run folder, if there is one."""
        latest = latest_checkpoint(self.run_dir)
        if latest is None:
            return False
        restore(self, RunState.load(latest), latest)
        return True

    def run(self, progress: bool = True) -> TrainStats:
        """Train from ``start_iteration`` to the end of the schedule, checkpointing on the way;
        a run whose held-out loss plateaued stops there, and stays stopped when resumed."""
        from tqdm import tqdm

        sc, p = self.cfg.schedule, self.progress
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.run_dir / "config.json", json.dumps(self.cfg.to_dict(), indent=2))
        end = sc.iterations if p.plateau.stopped_at is None else self.start_iteration
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
            p.stats.seconds += time.perf_counter() - t
            last = it + 1
            p.account(it, result, checkpoint_dir(self.run_dir))
            stop = p.holdout_due(last) and p.plateaued(self._holdout_loss(last), last, result.stage)
            shown = p.log(it, result, stop)
            if shown is not None:
                bar.set_postfix(shown, refresh=False)
            if stop:
                break
            # No checkpoint during a streak of skipped steps: the last one stays the last good one.
            if last % sc.checkpoint_every == 0 and last < sc.iterations and not p.bad_in_a_row:
                self.save(last)
        self.save(last)
        stats = p.finish(last)
        write_text_atomic(self.run_dir / "stats.json", json.dumps(self.summary(), indent=2))
        return stats

    def summary(self) -> dict:
        """Run-level numbers for benchmarks: time, rate, skips, size, peak memory."""
        gaussians = int(self.model.num_gaussians)
        return self.progress.summary(gaussians, self.static_fraction(), self.static_scene)

    def _holdout_loss(self, done: int) -> float:
        """L_e on the held-out windows with the model after ``done`` iterations."""
        self.renderer.mlp = self.mlp if self.mlp_active(done) else None
        lambda_ssim = self.cfg.loss.lambda_ssim
        return holdout_loss(self.progress.holdout, self.views.log_image_at, lambda_ssim)
