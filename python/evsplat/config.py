"""Configuration, all of it: one plain dataclass per concern, composed into ``TrainConfig``,
and the named presets as data.

``TrainConfig()`` *is* the default preset; the presets ``tiny`` and ``paper`` are overrides
of it (``PRESETS``), and a run writes its resolved config to ``config.json``. FastEventDGS (the
paper) names its losses and schedule but defers hyperparameters to a supplementary that is not
available; where it gives no value the default is a documented choice taken from 3DGS,
Deformable-3DGS or EventNeRF practice, and the comment says so; where a value was measured,
the comment names the docs section that holds the measurements (docs/results.md and
docs/experiments/). Times are
fractions of the sequence duration and iteration counts fractions of the run, so a short run
keeps the proportions of the paper's 30k-iteration schedule.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from evsplat.errors import EvsplatError


@dataclass
class ModelConfig:
    """Gaussians, deformation MLP and their learning rates."""

    sh_degree: int = 0  # documented choice: events carry little view dependence; 3DGS uses 3
    init_depth_range: tuple[float, float] = (0.5, 10.0)  # documented choice: random-init depths
    init_opacity: float = 0.1  # 3DGS §5.1: initial opacity 0.1
    # The deformation MLP: 6x128 with the input again at layer 3 (documented choice: the
    # `paper` preset has Deformable-3DGS's 8x256 with the input again at layer 4, paper §3.2).
    mlp_width: int = 128
    mlp_depth: int = 6
    mlp_skip: int = 3
    pe_x: int = 10  # Deformable-3DGS: positional encoding frequencies of x (synthetic scenes)
    pe_t: int = 6  # Deformable-3DGS: positional encoding frequencies of t
    means_lr: float = 1.6e-4  # 3DGS: position lr (times the scene extent) ...
    means_lr_final: float = 1.6e-6  # ... decaying exponentially to this (times the extent)
    scales_lr: float = 5e-3  # 3DGS: scaling lr
    quats_lr: float = 1e-3  # 3DGS: rotation lr
    opacity_lr: float = 5e-2  # 3DGS: opacity lr
    colors_lr: float = 2.5e-3  # 3DGS: feature (SH DC) lr, used for all SH bands
    mlp_lr: float = 8e-4  # Deformable-3DGS: 1.6e-4 x 5 (its fixed spatial scale) ...
    mlp_lr_final: float = 1.6e-6  # ... decaying exponentially to this
    # The MLP rate's decay spans this fraction of the run from iteration 0: the authors' code
    # decays over 40k iterations of a 30k run (measured:
    # docs/experiments/training.md, "The MLP rate settles").
    mlp_lr_span: float = 4 / 3
    # Time-local opacity (not in the paper): each Gaussian's opacity is modulated by a Gaussian
    # in time, so an object can be drawn by different Gaussians at different times. Off: the
    # MLP carries the motion (measured:
    # docs/experiments/motion.md, "The MLP carries the ball"). `--temporal-opacity`
    # turns it on; never on for a static run (deform=False).
    temporal_opacity: bool = False
    # Learning rates of the time centre (units of the sequence) and of the log-width in time:
    # slow, or Gaussians flicker in time (measured:
    # docs/experiments/paper-tables.md, "Slower time parameters").
    t_mean_lr: float = 3e-3
    t_scale_lr: float = 6e-3
    # (fraction, width): Gaussians that start time-local, and their width in normalised time
    # (measured: docs/experiments/paper-tables.md, "Longer event windows, Gaussians that start
    # time-local"). The others start at width 1.
    init_time_local: tuple[float, float] = (0.3, 0.05)


@dataclass
class DensifyConfig:
    """3DGS adaptive density control.

    The densification window is a fraction of the run so short runs keep 3DGS's proportions; the
    interval and the opacity-reset period stay in iterations, since they count the views that the
    gradient statistics and the recovery after a reset need. A run shorter than one reset period
    therefore never resets (a reset 20 iterations before a prune would empty a short run).
    """

    grad_threshold: float = 2e-4  # 3DGS: mean screen-space gradient that triggers densification
    interval: int = 100  # 3DGS: densify every 100 iterations
    start_fraction: float = 500 / 30_000  # 3DGS: from iteration 500 of 30k
    stop_fraction: float = 15_000 / 30_000  # 3DGS: until iteration 15k of 30k
    opacity_reset_interval: int = 3000  # 3DGS: opacity reset every 3000 iterations (0 = never)
    prune_opacity: float = 0.005  # 3DGS: prune Gaussians with opacity below this
    percent_dense: float = 0.01  # 3DGS: clone if max scale <= this x extent, else split
    split_count: int = 2  # 3DGS: a split Gaussian becomes two
    split_scale_divisor: float = 1.6  # 3DGS: children are 1/(0.8 x 2) the parent's scale
    max_screen_radius: float = 20.0  # 3DGS: prune projections wider than 20 px (after a reset)
    max_world_scale: float = 0.1  # 3DGS: prune Gaussians larger than 0.1 x extent
    max_gaussians: int = 1_000_000  # documented choice: memory cap, least opaque pruned first
    # At the cap, densification may remove up to this fraction of the budget per interval, the
    # faintest first (peak opacity below recycle_opacity), to make room (3DGS-MCMC-like).
    recycle_fraction: float = 0.05  # documented choice
    recycle_opacity: float = 0.05  # documented choice
    # With time-local opacity, split children of Gaussians narrower in time than
    # time_local_width (normalised time) are also sampled in time (4D-GS).
    split_in_time: bool = True
    time_local_width: float = 0.25  # documented choice: shown in under about half the sequence


@dataclass
class LossConfig:
    """Weights and sampling of the paper's six losses (eq. 19)."""

    lambda_ssim: float = 0.2  # eq. 9 λ_e; documented choice: 3DGS's D-SSIM weight 0.2
    window_min: float = 0.02  # eq. 7 Δt_k, shortest L_e window; documented choice (EventNeRF)
    # eq. 7 Δt_k, longest L_e window: long windows tie each time to more of the sequence's
    # brightness (measured: docs/experiments/paper-tables.md, "Longer event windows").
    window_max: float = 0.3
    views: int = 2  # renders per step; L_e on every pair of them (2: the paper's one window)
    flow_window: float = 0.005  # eq. 13 Δτ, short window for L_ef; documented choice
    # Whether L_ef's gradient reaches the Gaussian flow (the MLP's motion): off, as in the
    # authors' code; on, it drove the ball's Gaussians off their path in the oracle test
    # (docs/experiments/motion.md, "Can the losses carry motion?") and left the full method
    # level (docs/experiments/paper-tables.md, "Table 3's steps again"). L_ef then
    # trains appearance and depth.
    flow_moves_gaussians: bool = False
    motion_window: float = 0.02  # §4.3 Δt split into m sub-windows for L_m; documented choice
    patch_n: int = 128  # §4.3 n sampled Gaussians; documented choice
    patch_m: int = 4  # §4.3 m equal-count sub-windows; documented choice
    patch_side: int = 9  # §4.3 patch side in pixels; documented choice
    depth_tolerance: float = 0.1  # §4.3 depth filter: relative tolerance to rendered depth
    depth_min_alpha: float = 0.5  # §4.4 L_d only where the render is opaque; documented choice
    w_flow: float = 0.1  # eq. 19 λ_ef; documented choice
    w_motion: float = 0.1  # eq. 19 λ_m; documented choice
    w_depth: float = 0.05  # eq. 19 λ_d; documented choice
    w_non_event: float = 0.1  # eq. 19 λ_ne; documented choice
    w_spatial: float = 0.01  # eq. 19 λ_sp; documented choice (TV-like weight on [0,1] images)


@dataclass
class MoverConfig:
    """Finding the moving objects in the events and starting their motion after the warm-up
    (``evsplat.motion``; not in the paper, which starts from a point cloud that event data does
    not have). What each was measured on: docs/motion.md, "Tuning numbers"."""

    enabled: bool = True  # find moving objects after the warm-up and move each rigidly
    windows: int = 48  # segmentation windows spread over the sequence
    window: float = 0.015  # their length, a fraction of the sequence (9 ms of 0.6 s)
    slow_window: float = 0.0  # a longer one at each for slow or small objects, e.g. 0.03 (0: none)
    still_window: float = 0.05  # under a still camera, the longer one's length instead (0: none)
    pool: int = 3  # px box that averages the ESI's steps of C before the residual
    blur_px: float = 1.0  # spreads an object's edge events over its body (sigma, px)
    low: float = 3.0  # a region: residual above median + low robust sigmas (MAD) ...
    high: float = 9.0  # ... that reaches median + high robust sigmas somewhere
    close_px: int = 2  # closing radius joining an object's pieces (px)
    min_area_px: int = 12  # smaller regions are noise: under a 4x4 px square
    join: float = 0.5  # regions within this many of the larger one's radii are one object
    gate: float = 1.5  # a region joins a track within this many radii (or steps) of its guess
    coast: int = 3  # windows a track lives on unseen and not hidden in another's region
    min_windows: int = 4  # a track seen in fewer windows is noise
    min_evidence: float = 30.0  # a track's peaks over `high` summed: less is noise (moving camera)
    events: float = 0.1  # a region's events: at least this share of the render's change there
    together: float = 1.5  # tracks within this many summed radii in most windows are one object
    align: float = 0.5  # a centre moves at most this many radii to match the object's template
    depth_quantile: float = 0.25  # of the static render's depth in its regions: its front
    fraction: float = 0.15  # of the Gaussians placed on the objects, split by area (or their smear)
    min_gaussians: int = 64  # at least this many per object
    opacity: float = 0.5  # their initial opacity: an object occludes what is behind it
    turn: bool = True  # estimate each object's in-plane turn from its events
    sphere: bool = True  # a round object's turn about three axes, from its outline (needs turn)
    turn_window: float = 0.05  # the turn's windows, a fraction of the sequence
    held_window: float = 0.2  # theirs for an object held in place in the image (0: as others')
    turn_min_gain: float = 0.05  # a turn is used where it sharpens the warped events this much
    turn_min_events: int = 50  # ... from at least this many of the object's events
    turn_min_windows: int = 3  # ... in at least this many windows
    turn_axes: bool = True  # a steady turn from the long axes of an elongated object's regions
    knots: int = 61  # knots of the objects' rigid paths over the sequence
    path_lr: float = 1e-3  # Adam's rate on the paths' translations (world units)
    turn_lr: float = 1e-3  # Adam's rate on the paths' rotation vectors (rad)
    track_weight: float = 1.0  # the prior holding each knot near the events' path (0 = off)
    again: float = 0.3  # look again at this fraction of the run, against all found (0 = off)
    residual: bool = True  # the MLP adds a non-rigid residual to the objects' rigid motion
    # For built-in synthetic scenes only: none | turn | path | both of the simulator's true motion
    # for the objects found (an upper bound; train/motion_oracle.py)
    oracle: str = "none"


@dataclass
class SkipConfig:
    """Skipping work a scene does not need: the MLP for static Gaussians, full resolution early
    on, and the iterations after the held-out event loss has stopped improving. None is in the
    paper."""

    # Static Gaussians: the MLP is evaluated at `static_times` times in [0, 1] for every dynamic
    # Gaussian; those whose deformation hardly changes over time get its time mean folded into
    # their canonical parameters and skip the MLP from then on (static is for good).
    static: bool = True  # documented choice: on; from the refinement stage only, see below
    # Documented choice: the refinement stage (paper §5: 20k of 30k). The MLP's heads start at
    # zero, so classifying soon after the warm-up would mark nearly every Gaussian static and
    # starve the MLP of the gradients it needs to learn the motion.
    static_start_fraction: float = 2 / 3
    static_every: int = 100  # documented choice: 16 MLP passes per 100 steps, ~2% of training
    # Documented choice: γ(t)'s fastest band (2^5 with pe_t=6) has period ~0.2; 16 samples
    # see each of its lobes.
    static_times: int = 16
    # Largest change over time (from its time mean) that still counts as static. Documented
    # choice: an MLP trained on a static scene still wiggles every Gaussian by ~0.4 px, 2° and
    # 2% (measured on the `still` scene); a moving object moves by tens of pixels.
    static_px: float = 1.0  # Δx seen from the mean camera position, in pixels
    static_dq: float = 5e-2  # |Δq| (about 3° of rotation)
    static_ds: float = 5e-2  # Δs in log scale (5% size change)
    # Static scene: when the first classification finds at least this fraction of the Gaussians
    # within the static_scene_* bounds, the scene is taken as static: every Gaussian is baked and
    # the MLP and the motion losses are off for the rest of the run. Documented choices, measured on
    # `still` with the tiny preset (docs/experiments/skips.md, "The static-scene check fires on
    # `still` again"): its MLP moves the Gaussians by up to 2.1-2.3 px, |Δq| 0.056-0.07 and Δs
    # 0.076-0.094 (95th percentiles, iterations 1500-2000 of 2000; 2.7 px, 0.12, 0.15 at the 99th of
    # a 4000-iteration run), so the scene needs looser bounds than one Gaussian; a moving object
    # moves by tens of pixels.
    static_scene_px: float = 3.0
    static_scene_dq: float = 0.15
    static_scene_ds: float = 0.15
    static_scene_fraction: float = 0.95
    # ... and only when the events agree (both must hold): over `static_scene_windows` fixed
    # windows, the model frozen at each window's middle time and seen from the poses at its
    # ends must explain the events of every ~`static_scene_block` px region, all but at most
    # `static_scene_unexplained` of their energy (1 - ρ², ρ the correlation of ESI and predicted
    # change, both averaged over `static_scene_pool` px squares; skips.unexplained_events).
    # A moving object leaves its region's events unexplained, while the MLP learning no motion
    # does not show that nothing moves (it found the moving `ball` static). 1 or more turns the
    # evidence off. Documented choices between `still`'s worst region (0.12-0.26) and the
    # moving scenes' (0.49-0.94), with short windows, which separate best (measured:
    # docs/experiments/skips.md, "How the skips decide").
    static_scene_unexplained: float = 0.35
    static_scene_windows: int = 32  # 64 renders, once per run; documented choice
    static_scene_window_lengths: tuple[float, float] = (0.02, 0.1)  # fractions of the sequence
    static_scene_block: int = 32  # region side in pixels; documented choice (3x3 at 96 px)
    static_scene_pool: int = 4  # documented choice: 4x4 averaging, see skips.unexplained_events
    # Coarse-to-fine: iterations before this fraction of the run render at half resolution and
    # compare with 2x2-binned events (never in the refinement stage, whose losses want detail).
    coarse_fraction: float = 0.0
    # Early stop: L_e on fixed held-out windows, evaluated after the warm-up every
    # `early_stop_every` iterations; training stops after `early_stop_patience` evaluations
    # without a relative improvement above `early_stop_min_delta`.
    early_stop: bool = True  # documented choice: on, with the patience below
    early_stop_windows: int = 8  # documented choice: fixed seeded windows of L_e's lengths
    early_stop_every: int = 100  # documented choice: 16 renders per 100 steps, ~5% overhead
    # Documented choice: 10 evaluations = 1000 iterations without progress, half of the tiny
    # preset's run, so a run stops only when the held-out loss is truly flat.
    early_stop_patience: int = 10
    early_stop_min_delta: float = 1e-3  # relative improvement that counts; documented choice


@dataclass
class HoldoutConfig:
    """Held-out event windows (``evsplat.train.heldout``; not in the paper): intervals that
    training never reads, evenly spread and seeded, on which `evsplat eval` scores the model's
    prediction of unseen events. Off by default: they take events away from training."""

    windows: int = 0  # how many (0 = off)
    length: float = 0.02  # each one's length, a fraction of the sequence


@dataclass
class ScheduleConfig:
    """Iterations and stage boundaries, as fractions so short runs keep the paper's proportions."""

    iterations: int = 6000  # documented choice; the `paper` preset has paper §5's 30k
    warmup_fraction: float = 0.1  # paper §5: warm-up 3k of 30k (static Gaussians, L_e only)
    refine_fraction: float = 2 / 3  # paper §5: refinement from 20k of 30k (+L_d, L_ne, L_sp)
    checkpoint_every: int = 500  # iterations between atomic checkpoints
    log_every: int = 10  # iterations between loss-log lines
    keep_checkpoints: int = 2  # older complete checkpoints are deleted
    # Iterations between logs of each loss's gradient norm on the MLP (0 = never): one extra
    # backward pass per loss, ~1% of a tiny run at 100.
    grad_norms_every: int = 100

    @property
    def warmup_end(self) -> int:
        return int(round(self.iterations * self.warmup_fraction))

    @property
    def refine_start(self) -> int:
        return int(round(self.iterations * self.refine_fraction))


@dataclass
class TrainConfig:
    """Everything a run needs besides the data; saved with every checkpoint. The defaults are
    the `default` preset."""

    preset: str = "default"  # the preset these settings started from (a name in PRESETS)
    seed: int = 0  # seeds the initial Gaussians, the windows drawn and torch
    num_gaussians: int = 20_000  # initial random Gaussians (documented: no SfM/RGB available)
    background: float = 0.5  # grey background intensity where no Gaussian covers a pixel
    threads: int = 0  # torch intra-op threads (0 = torch's default)
    device: str = "auto"  # auto | cpu | cuda: where torch trains (train/device.py)
    deform: bool = True  # False: a static scene, no deformation MLP at all (also a baseline)
    # Seconds from the recording's start (meta.json t_start_us) to train on; None = that end.
    time_range: tuple[float | None, float | None] | None = None
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    skips: SkipConfig = field(default_factory=SkipConfig)
    mover: MoverConfig = field(default_factory=MoverConfig)
    holdout: HoldoutConfig = field(default_factory=HoldoutConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        """A config from ``to_dict``'s form (a run's config.json)."""
        return TrainConfig(
            preset=d["preset"],
            seed=d["seed"],
            num_gaussians=d["num_gaussians"],
            background=d["background"],
            threads=d.get("threads", 0),
            device=d.get("device", "auto"),
            deform=d.get("deform", True),
            time_range=tuple(d["time_range"]) if d.get("time_range") else None,
            schedule=ScheduleConfig(**d["schedule"]),
            model=ModelConfig(**_model_settings(d["model"], d["schedule"]["iterations"])),
            densify=DensifyConfig(**d["densify"]),
            loss=LossConfig(**d["loss"]),
            skips=_known(SkipConfig, d.get("skips", {})),
            # Runs saved before the mover initialisation existed trained without it; settings
            # added to it later take their defaults.
            mover=_known(MoverConfig, d["mover"]) if "mover" in d else MoverConfig(enabled=False),
            # Runs saved before held-out windows existed held none out.
            holdout=HoldoutConfig(**d.get("holdout", {})),
        )


def _model_settings(model: dict, iterations: int) -> dict:
    """A saved run's model settings in today's names: runs saved before 30a96a3 (2026-11-26) give
    the MLP rate's decay as a fixed horizon in iterations (``mlp_lr_horizon``)."""
    model = dict(model)
    horizon = model.pop("mlp_lr_horizon", None)
    if horizon is not None:
        model["mlp_lr_span"] = horizon / max(iterations, 1)
    return model


def _known(kind: type, d: dict):
    """``kind`` from the settings of ``d`` it still has; settings added since ``d`` was saved
    take their defaults and renamed ones are dropped. Only for skips and the mover: skips
    change speed, not what a checkpoint holds, and the mover acts once, before training."""
    known = {f.name for f in dataclasses.fields(kind)}
    return kind(**{k: v for k, v in d.items() if k in known})


# The presets, as overrides of TrainConfig() (nested dicts follow its fields).
PRESETS: dict[str, dict] = {
    "default": {},
    # The tiny built-in scenes (96 px) on 2 CPU cores with lavapipe in minutes. A short
    # schedule needs larger colour and scale learning rates than 3DGS's 30k-iteration ones
    # (documented choice: 10x and 2x). One torch thread: at 96x96 torch's ops gain nothing
    # from more, and on a CPU adapter idle workers spin on the cores lavapipe needs
    # (docs/experiments/paper-tables.md, "The demo on one torch thread").
    "tiny": {
        "num_gaussians": 1500,
        "threads": 1,
        "schedule": {"iterations": 2000},
        "model": {
            "mlp_width": 64,
            "mlp_depth": 4,
            "mlp_skip": 2,
            "colors_lr": 0.025,
            "scales_lr": 0.01,
        },
        "densify": {"max_gaussians": 6000},
    },
    # The paper's schedule (§5) and Deformable-3DGS's MLP (8x256, input again at layer 4).
    "paper": {
        "num_gaussians": 50_000,
        "schedule": {"iterations": 30_000, "checkpoint_every": 1000},
        "model": {"mlp_width": 256, "mlp_depth": 8, "mlp_skip": 4},
    },
}


def _merged(base: dict, over: dict) -> dict:
    """``base`` with the values of ``over`` (nested dicts merged); a key of ``over`` that
    ``base`` lacks is an error, so a misspelt preset setting cannot pass unnoticed."""
    unknown = set(over) - set(base)
    if unknown:
        raise KeyError(f"not a setting: {', '.join(sorted(unknown))}")
    return {
        k: _merged(v, over.get(k, {})) if isinstance(v, dict) else over.get(k, v)
        for k, v in base.items()
    }


def preset(name: str) -> TrainConfig:
    """The named preset; unknown names are a one-line error listing the choices."""
    if name not in PRESETS:
        raise EvsplatError(f"unknown preset {name!r}; choose one of {', '.join(sorted(PRESETS))}")
    over = PRESETS[name] | {"preset": name}
    return TrainConfig.from_dict(_merged(TrainConfig().to_dict(), over))


def load_config(path: str | Path) -> TrainConfig:
    """A TrainConfig from a JSON file such as a run's config.json."""
    path = Path(path)
    try:
        return TrainConfig.from_dict(json.loads(path.read_text()))
    except FileNotFoundError:
        raise EvsplatError(f"{path}: config file not found") from None
    except (ValueError, KeyError, TypeError) as e:
        raise EvsplatError(
            f"{path}: not a TrainConfig JSON ({type(e).__name__}: {e}); start from a run's "
            "config.json"
        ) from None
