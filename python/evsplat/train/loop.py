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
from evsplat.data.atomic import write_text_atomic
from evsplat.data.dataset import Dataset
from evsplat.data.events import bayer_channel_map
from evsplat.data.poses import read_tum
from evsplat.errors import EvsplatError
from evsplat.losses.depth import silog
from evsplat.losses.event import bayer_select, event_loss, log_render
from evsplat.losses.flow import (
    camera_flow,
    event_flow_loss,
    gaussian_flow_features,
    linearized_brightness_change,
)
from evsplat.losses.patch import patch_motion_loss, select_visible
from evsplat.losses.reg import non_event_loss, spatial_gradient_loss
from evsplat.model.deform import DeformationMLP, deformed_means
from evsplat.model.densify import Densifier
from evsplat.model.gaussians import GaussianModel
from evsplat.projection import project_points, viewmat
from evsplat.render import Renderer, RenderOut
from evsplat.train.coarse import bin_events, coarse_due, half_renderer
from evsplat.train.config import TrainConfig
from evsplat.train.depth_prior import DepthPrior
from evsplat.train.mover import (
    MoverPath,
    MoverTrack,
    disc_depth,
    disc_inside,
    find_path,
    fit_mlp_to_path,
    interp_rows,
    lift,
    near_path,
    place_on_mover,
    unexplained,
)
from evsplat.train.skips import (
    Plateau,
    Window,
    bake,
    classify_static,
    evidence_windows,
    follow_rows,
    holdout_loss,
    holdout_windows,
    pixels_per_unit,
    static_due,
    unexplained_events,
)
from evsplat.train.spin import SpinSettings, find_spin, integrate
from evsplat.train.stages import Stage, stage_at

MAX_BAD_STEPS = 20  # consecutive non-finite steps before training stops
FIT_GRID = 121  # times on which the MLP is fitted to the mover's path and turn


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


def _init_points(data: Dataset, n: int, rng: np.random.Generator, depth_range: tuple[float, float]):
    """Random points in the volume the trajectory sees: random time, pixel and inverse depth.

    Event data carries no RGB or SfM points, so the frusta are the only geometric prior.
    Returns (points [n,3], depths [n]) — depth sets each Gaussian's initial size.
    """
    times = rng.uniform(data.trajectory.t_min_us, data.trajectory.t_max_us, size=n)
    c2w = data.trajectory.pose(times)
    px = np.stack([rng.uniform(0, data.width, n), rng.uniform(0, data.height, n)], axis=1)
    near, far = depth_range
    depth = 1.0 / rng.uniform(1.0 / far, 1.0 / near, size=n)
    kinv = np.linalg.inv(data.K)
    rays = (np.concatenate([px, np.ones((n, 1))], axis=1) @ kinv.T) * depth[:, None]
    points = np.einsum("nij,nj->ni", c2w[:, :3, :3], rays) + c2w[:, :3, 3]
    return points, depth


def scene_extent(data: Dataset, depth_range: tuple[float, float]) -> float:
    """Radius used to scale learning rates and densification (3DGS: camera spread x 1.1),
    never below the far depth so a nearly static camera still gets a sensible scale."""
    times = np.linspace(data.trajectory.t_min_us, data.trajectory.t_max_us, 64)
    centres = data.trajectory.pose(times)[:, :3, 3]
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) * 1.1
    return max(spread, depth_range[1])


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

        rng = np.random.default_rng(cfg.seed)
        points, depth = _init_points(data, cfg.num_gaussians, rng, self.depth_range)
        lo, hi = points.min(0), points.max(0)
        self.model = GaussianModel.random_init(
            cfg.num_gaussians, self.channels, lo, hi, sh_degree=cfg.model.sh_degree, seed=cfg.seed
        )
        self.model.temporal = cfg.deform and cfg.model.temporal_opacity
        if self.model.temporal:
            self.model.start_time_local(*cfg.model.init_time_local, seed=cfg.seed)
        focal = float(data.K[0, 0])
        with torch.no_grad():
            self.model.means.copy_(torch.from_numpy(points.astype(np.float32)))
            # About two pixels wide where it was sampled: visible, but no initial blur.
            size = np.log(np.maximum(2.0 * depth / focal, 1e-6)).astype(np.float32)
            self.model.log_scales.copy_(torch.from_numpy(size)[:, None].expand(-1, 3))
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
        self.channel_map = None
        if self.channels == 3:
            cmap = bayer_channel_map(data.bayer, data.width, data.height)
            self.channel_map = torch.from_numpy(cmap.astype(np.int64))
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
                self._esi, data.t_start_us, data.t_end_us, cfg.loss, sk.early_stop_windows, cfg.seed
            )
        self.plateau = Plateau()
        self.static_scene = False  # set when the static classification finds no motion
        self.mover_track: MoverTrack | None = None  # set by the mover's seeding

    # ---- one iteration -------------------------------------------------------------------

    def _log_image(self, out: RenderOut, coarse: bool = False) -> torch.Tensor:
        """Log intensity each pixel's sensor sees: its own Bayer channel, or the one channel.
        A coarse colour render keeps all three channels ``[3,h,w]``, as its binned events do."""
        img = out.image
        if self.channel_map is None:
            return log_render(img[..., 0])
        if coarse:
            return log_render(img).permute(2, 0, 1)
        return log_render(bayer_select(img, self.channel_map))

    def _linearized_change(self, out: RenderOut, flow: torch.Tensor, coarse: bool) -> torch.Tensor:
        """-∇L·F (eq. 13) in the sensor's channels. A colour render is differentiated per
        channel before each pixel keeps its Bayer channel: differences across a mosaic mix
        colours, and drove the MLP's motion backwards in the oracle test (docs/results.md)."""
        if self.channel_map is None:
            return linearized_brightness_change(log_render(out.image[..., 0]), flow)
        change = linearized_brightness_change(log_render(out.image).permute(2, 0, 1), flow)
        if coarse:
            return change
        return bayer_select(change.permute(1, 2, 0), self.channel_map)

    def _esi(
        self, t0: int, t1: int, coarse: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, int]:
        """(ESI, event mask, event count) of [t0, t1), 2x2-binned for a coarse render."""
        ev = self.data.events.read(t0, t1)
        esi, mask = ev.esi_and_mask(0, len(ev), self.data.c_pos, self.data.c_neg)
        esi, mask = torch.from_numpy(esi), torch.from_numpy(mask)
        if coarse:
            esi, mask = bin_events(esi, mask, self.channel_map)
        return esi, mask, len(ev)

    def _pose(self, t_us: float) -> np.ndarray:
        return self.data.trajectory.pose(float(t_us))

    def _log_image_at(self, t_us: int, view: Renderer | None = None) -> torch.Tensor:
        """Render at ``t_us`` with ``view`` (default the full-resolution renderer) and log it."""
        view = view or self.renderer
        return self._log_image(view.render(t_us, self._pose(t_us)), view is not self.renderer)

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
            seeded = self._seed_mover()
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
        windows = [self._esi(times[i], times[j], coarse) for i, j in pairs]
        if all(count == 0 for _, _, count in windows):
            return StepResult({}, stage, skipped="no events in window")

        pose1 = self._pose(t1)
        g1 = view.gaussians_at(t1)
        extra = None
        if moving and lc.w_flow > 0:
            # Gaussian flow: 2-D motion of each Gaussian over [t1, t1 + dtau] at the pose of t1.
            means_later = view.gaussians_at(t1 + dtau)[0]
            extra = gaussian_flow_features(g1[0], means_later, viewmat(pose1), view.K)
            if not lc.flow_moves_gaussians:
                extra = extra.detach()
        out1 = view.render(t1, pose1, extra=extra, gaussians=g1)
        logs = [self._log_image_at(t, view) for t in times[:-1]]
        log1 = self._log_image(out1, coarse)
        logs.append(log1)
        terms = [
            event_loss(logs[j] - logs[i], esi, mask, lc.lambda_ssim)
            for (i, j), (esi, mask, count) in zip(pairs, windows)
            if count > 0
        ]
        losses: dict[str, torch.Tensor] = {"e": torch.stack(terms).mean()}
        if moving:
            losses.update(self._motion_losses(view, t1, dtau, pose1, out1, rng))
            track = self._track_loss(g1[0], t1)
            if track is not None:
                losses["tr"] = track
        if stage is Stage.REFINE:
            # The refinement losses see the last window (pairs end with (views-2, views-1)).
            losses.update(self._refine_losses(t1, out1, logs[-1] - logs[-2], windows[-1][1]))

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

    def _seed_mover(self) -> dict[str, float]:
        """After the warm-up: find a fast mover from the events the static model leaves
        unexplained, re-place on it (at the time it is seen best) the Gaussians that smear it
        along its path and then the faintest, fit the MLP to carry them along its path (turning
        them with its spin when it is round), and mark every other Gaussian static (the
        background's gradients drowned the mover's in a shared MLP: docs/results.md, session
        11). Returns numbers for the log; nothing changes when no mover is found."""
        mc, data, cfg = self.cfg.mover, self.data, self.cfg
        self.renderer.mlp = None  # the warm-up's static model

        def residual_of(t0: int, t1: int) -> torch.Tensor:
            esi = self._esi(t0, t1)[0]
            return unexplained(esi, self._log_image_at(t1) - self._log_image_at(t0), mc.pool)

        with torch.no_grad():
            path = find_path(residual_of, data.t_start_us, data.t_end_us, mc)
        # Whether there is a mover: the windows that saw one (contrast); its path: the found
        # windows, fewer (mover.prefer_ring and mover.connected drop the fits that disagree).
        found = float((path.contrast >= mc.min_contrast).mean())
        if found < mc.min_found or not path.found.any():
            return {"mover_found": found}
        # The reference: the clearest window well inside the image, with its own radius (the
        # median radius placed a mover twice as large that the model did not move: session 12).
        k = path.reference(data.width, data.height)
        radius_px = float(path.radius_px[k])
        times = path.times_us[path.found]
        depth = self._mover_depth(path)
        poses = self.data.trajectory.pose(times.astype(np.float64))
        points = lift(path.uv[path.found], np.full(len(times), depth), poses, data.K)
        ref = points[int(np.count_nonzero(path.found[:k]))]  # k is a found window
        radius = radius_px * depth / float(data.K[0, 0])
        n = self.model.num_gaussians
        # The warm-up drew the mover as a static smear along its path: those Gaussians go on
        # the mover first (they would keep drawing it where it is not), then the faintest.
        swept = near_path(self.model.means.detach(), points, radius)
        faintest = torch.argsort(self.model.opacities().detach())
        faintest = faintest[~swept[faintest]]
        m = max(1, int(mc.fraction * n), int(swept.sum()))
        rows = torch.cat([torch.nonzero(swept).reshape(-1), faintest[: m - int(swept.sum())]])
        place_on_mover(self.model, self.optimizer, rows, ref, radius, mc.opacity, cfg.seed)
        # The fit follows the path on a grid of times (the spin needs more than the windows).
        grid = np.linspace(data.t_start_us, data.t_end_us, FIT_GRID).astype(np.int64)
        t_ref = int(path.times_us[k])
        turns, spin = self._mover_spin(path, times, points, radius, t_ref, grid)
        t_norm = torch.tensor([self.renderer.time(int(t)) for t in grid], dtype=torch.float32)
        offsets = torch.from_numpy((interp_rows(grid, times, points) - ref).astype(np.float32))
        rms = fit_mlp_to_path(
            self.mlp,
            self.model.means[rows],
            t_norm,
            offsets,
            None if turns is None else torch.from_numpy(turns.astype(np.float32)),
            ref,
            mc.fit_steps,
            mc.fit_lr,
            cfg.seed,
        )
        self.mlp_optimizer = self._mlp_adam()  # the fit's moments are not training's
        if mc.track_weight > 0:
            reach = int(mc.track_reach * (data.t_end_us - data.t_start_us))
            self.mover_track = MoverTrack(times, points, radius, reach)
        static = torch.ones(n, dtype=torch.bool)
        static[rows] = False
        self.renderer.static_mask = static
        return {
            "mover_found": found,
            "mover_depth": depth,
            "mover_radius_px": radius_px,
            "mover_fit_rms": rms,
            "mover_gaussians": float(m),
            "mover_swept": float(swept.sum()),
        } | spin

    def _track_loss(self, means: torch.Tensor, t_us: int) -> torch.Tensor | None:
        """The track prior on the mover's deformed ``means`` [N,3] (all rows) at ``t_us``."""
        static = self.renderer.static_mask
        if self.mover_track is None or static is None:
            return None
        moving = ~static
        opacities = self.model.opacities(self.renderer.time(t_us))[moving]
        return self.mover_track.loss(means[moving], opacities, t_us)

    def _mover_spin(
        self,
        path: MoverPath,
        times: np.ndarray,
        points: np.ndarray,
        radius: float,
        t_ref: int,
        grid: np.ndarray,
    ) -> tuple[np.ndarray | None, dict[str, float]]:
        """The mover's turn from ``t_ref`` to each ``grid`` time [G,3,3], from the angular
        velocities its events show (``evsplat.train.spin``) in the windows where its disc is
        inside the image; None when it is off, the mover is not round (the events are
        back-projected onto a sphere: on the duck that found 10 rad/s for a body turning less
        than 2, docs/results.md, session 16) or no window shows a spin. Numbers for the log."""
        mc, data = self.cfg.mover, self.data
        if not mc.spin or not path.round:
            return None, {}
        duration = data.t_end_us - data.t_start_us
        half = max(int(mc.spin_window * duration) // 2, 1)
        centres = np.arange(data.t_start_us + half, data.t_end_us - half + 1, 2 * half)
        centres = centres[(centres >= times[0]) & (centres <= times[-1])]
        r_px = float(np.median(path.radius_px[path.found]))
        centres = centres[disc_inside(path.at(centres), r_px, data.width, data.height)]
        if len(centres) == 0:
            return None, {"spin_windows": 0.0}

        def events_in(t0: int, t1: int) -> tuple[np.ndarray, np.ndarray]:
            ev = data.events.read(t0, t1)
            return np.stack([ev.x, ev.y], 1).astype(np.float64) + 0.5, ev.t

        settings = SpinSettings(
            mc.spin_rim,
            mc.spin_events,
            mc.spin_max_rate,
            mc.spin_min_gain,
            mc.spin_steps,
            self.cfg.seed,
        )
        omegas, gains = find_spin(
            events_in,
            lambda t: interp_rows(t, times, points),
            lambda t: data.trajectory.pose(np.asarray(t, dtype=np.float64)),
            radius,
            data.K,
            (data.width, data.height),
            centres,
            half,
            settings,
        )
        used = gains >= mc.spin_min_gain
        stats = {"spin_windows": float(used.sum()), "spin_gain": float(np.nanmedian(gains))}
        if not used.any():
            return None, stats
        rate = np.linalg.norm(omegas[used], axis=1)
        stats["spin_rate"] = float(np.median(rate))
        turns = integrate(centres[used], omegas[used], t_ref, grid)
        return turns, stats

    @torch.no_grad()
    def _mover_depth(self, path: MoverPath) -> float:
        """The mover's camera depth: per found window, a near quantile of the static model's
        rendered depth in the mover's disc (the warm-up drew the mover there as a smear, partly
        in front of the background it passes), then the median over the windows. One window's
        median depth lay up to 1.1 m behind the ball and put the mover behind the wall
        (docs/results.md, session 14). It reads the mover's front surface, not its centre;
        placing the centre one radius further made training drift the mover deeper still
        (session 15). The depth range's middle when no disc was drawn."""
        found = []
        for k in np.flatnonzero(path.found):
            t = int(path.times_us[k])
            out = self.renderer.render(t, self._pose(t))
            d = disc_depth(
                out.depth,
                out.alpha,
                path.uv[k],
                float(path.radius_px[k]),
                self.cfg.mover.depth_quantile,
            )
            if d is not None:
                found.append(d)
        return float(np.median(found)) if found else float(np.mean(self.depth_range))

    def _mlp_adam(self) -> torch.optim.Adam:
        return torch.optim.Adam(self.mlp.parameters(), lr=self.cfg.model.mlp_lr)

    def _classify_static(self) -> None:
        """Mark the dynamic Gaussians that stopped moving static and bake their deformation;
        static ones stay static, so only the dynamic ones go through the MLP."""
        first = self.renderer.static_mask is None
        n = self.model.num_gaussians
        old = torch.zeros(n, dtype=torch.bool) if first else self.renderer.static_mask
        dynamic = torch.nonzero(~old).reshape(-1)
        means = self.model.means[dynamic]
        centre = torch.from_numpy(self.pose_samples[1][:, :3, 3].mean(0).astype(np.float32))
        scale = pixels_per_unit(means, centre, float(self.data.K[0, 0]), 1e-2)
        sk = self.cfg.skips
        static, scene_static, mean = classify_static(self.mlp, means, scale, sk)
        if first and float(scene_static.float().mean()) >= sk.static_scene_fraction:
            # The MLP learned no motion, which does not show that nothing moves (time-local
            # opacity may carry the moving object): the scene is static, with nothing left for
            # the MLP or the motion losses to explain, only when its events agree.
            if sk.static_scene_unexplained >= 1 or (
                self._unexplained_events() <= sk.static_scene_unexplained
            ):
                static[:] = True
                self.static_scene = True
        bake(self.model, dynamic[static], mean.select(static))
        new = old.clone()
        new[dynamic[static]] = True
        self.renderer.static_mask = new

    def _unexplained_events(self) -> float:
        """The largest share of one region's events that the scene frozen at each evidence
        window's middle time (deformation and time-local opacity evaluated there) leaves
        unexplained, seen from the poses at the window's ends (skips.unexplained_events); 0 when
        no window has events."""
        data, sk = self.data, self.cfg.skips
        windows = evidence_windows(
            self._esi, data.t_start_us, data.t_end_us, self.cfg.loss, sk, self.cfg.seed
        )

        def log_image_at(t_scene: int, t_pose: int) -> torch.Tensor:
            return self._log_image(self.renderer.render(t_scene, self._pose(t_pose)))

        mlp, self.renderer.mlp = self.renderer.mlp, self.mlp
        try:
            share = unexplained_events(windows, log_image_at, sk)
        finally:
            self.renderer.mlp = mlp
        return float(share.max()) if share.numel() else 0.0

    def _motion_losses(self, view, t1, dtau, pose1, out1, rng) -> dict[str, torch.Tensor]:
        """L_ef and L_m for the render ``out1`` that ``view`` (full or coarse) made at ``t1``."""
        lc, data = self.cfg.loss, self.data
        coarse = view is not self.renderer
        out: dict[str, torch.Tensor] = {}
        # L_ef (eq. 13): linearised event model over [t1, t1 + dtau].
        window = self._esi(t1, t1 + dtau, coarse) if lc.w_flow > 0 else (None, None, 0)
        short, _, count = window
        if count > 0:
            flow_cam = camera_flow(
                out1.depth, view.K, viewmat(pose1), viewmat(self._pose(t1 + dtau))
            )
            pred = self._linearized_change(out1, flow_cam + out1.extra, coarse)
            out["ef"] = event_flow_loss(short, pred)
        # L_m (eq. 15): patches of m equal-count sub-windows around the moving centres.
        if lc.w_motion <= 0:
            return out
        span = int(lc.motion_window * (data.t_end_us - data.t_start_us))
        ev = data.events.read(t1, min(t1 + span, data.t_end_us))
        if len(ev) >= lc.patch_m:
            gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
            idx = select_visible(
                out1.meta["means2d"],
                out1.meta["depths"],
                out1.depth.detach(),
                lc.patch_n,
                lc.depth_tolerance,
                gen,
            )
            if idx.numel() > 0:
                bounds = ev.split_equal_count(0, len(ev), lc.patch_m)
                frames, centres = [], []
                for j in range(lc.patch_m):
                    a, b = int(bounds[j]), int(bounds[j + 1])
                    frames.append(torch.from_numpy(ev.esi(a, b, data.c_pos, data.c_neg)))
                    t_mid = 0.5 * (int(ev.t[a]) + int(ev.t[max(b - 1, a)]))
                    means = deformed_means(
                        self.model,
                        self.mlp,
                        self.renderer.time(t_mid),
                        idx,
                        self.renderer.static_mask,
                    )
                    centres.append(
                        project_points(means, viewmat(self._pose(t_mid)), self.renderer.K)
                    )
                out["m"] = patch_motion_loss(
                    torch.stack(frames), torch.stack(centres, dim=1), lc.patch_side
                )
        return out

    def _refine_losses(self, t1, out1, delta, mask) -> dict[str, torch.Tensor]:
        lc = self.cfg.loss
        out = {}
        if lc.w_non_event > 0:
            out["ne"] = non_event_loss(delta, mask, min(self.data.c_pos, self.data.c_neg))
        if lc.w_spatial > 0:
            out["sp"] = spatial_gradient_loss(out1.image)
        if self.depth_prior is not None and lc.w_depth > 0:
            prior = self.depth_prior.depth(t1, out1.image.detach())
            if prior is not None:
                valid = (prior > 0) & (out1.alpha.detach() > lc.depth_min_alpha)
                if bool(valid.any()):
                    out["d"] = silog(out1.depth, prior, valid)
        return out

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
        value = holdout_loss(self.holdout, self._log_image_at, self.cfg.loss.lambda_ssim)
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
