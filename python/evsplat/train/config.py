"""Training configuration: the schedule and the run-level settings, with named presets.

Model, densification and loss settings live in ``evsplat.config`` (one dataclass per concern);
this module composes them into a ``TrainConfig`` and defines the presets the CLI offers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from evsplat.config import DensifyConfig, LossConfig, ModelConfig, MoverConfig, SkipConfig
from evsplat.errors import EvsplatError


@dataclass
class ScheduleConfig:
    """Iterations and stage boundaries, as fractions so short runs keep the paper's proportions."""

    iterations: int = 30_000  # paper §5: 30k iterations
    warmup_fraction: float = 0.1  # paper §5: warm-up 3k of 30k (static Gaussians, L_e only)
    refine_fraction: float = 2 / 3  # paper §5: refinement from 20k of 30k (+L_d, L_ne, L_sp)
    checkpoint_every: int = 1000  # iterations between atomic checkpoints
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
    """Everything a run needs besides the data; saved with every checkpoint."""

    preset: str = "default"
    seed: int = 0
    num_gaussians: int = 20_000  # initial random Gaussians (documented: no SfM/RGB available)
    background: float = 0.5  # grey background intensity where no Gaussian covers a pixel
    threads: int = 0  # torch intra-op threads (0 = torch's default)
    deform: bool = True  # False: a static scene, no deformation MLP at all (also a baseline)
    # Seconds from the recording's start (meta.json t_start_us) to train on; None = that end.
    time_range: tuple[float | None, float | None] | None = None
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    skips: SkipConfig = field(default_factory=SkipConfig)
    mover: MoverConfig = field(default_factory=MoverConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        return TrainConfig(
            preset=d["preset"],
            seed=d["seed"],
            num_gaussians=d["num_gaussians"],
            background=d["background"],
            threads=d.get("threads", 0),
            deform=d.get("deform", True),
            time_range=tuple(d["time_range"]) if d.get("time_range") else None,
            schedule=ScheduleConfig(**d["schedule"]),
            model=ModelConfig(**d["model"]),
            densify=DensifyConfig(**d["densify"]),
            loss=LossConfig(**d["loss"]),
            skips=_skips(d.get("skips", {})),
            # Runs saved before the mover initialisation existed trained without it.
            mover=MoverConfig(**d["mover"]) if "mover" in d else MoverConfig(enabled=False),
        )


def _skips(d: dict) -> SkipConfig:
    """Skip settings of a saved config; configs saved before a setting existed (or after one
    was renamed) take its default, since skips change speed, not what a checkpoint holds."""
    known = {f.name for f in dataclasses.fields(SkipConfig)}
    return SkipConfig(**{k: v for k, v in d.items() if k in known})


def _tiny() -> TrainConfig:
    """Small enough to train the tiny built-in scene in about 3.5 minutes on 2 CPU cores with
    lavapipe (2000 iterations, densified to the 6000 budget: 214 s); early stop ends it sooner
    if the held-out loss plateaus. A short schedule needs larger colour and scale learning
    rates than 3DGS's 30k-iteration ones (documented choice: 10x and 2x).

    One torch thread: at 96x96 torch's ops are too small to gain from more, and on a CPU
    adapter its idle workers spin on the cores lavapipe's rasterizer needs (2 cores: 13.2 ->
    17.3 it/s; at 400x400 one thread is 23% slower, so the other presets keep torch's default;
    docs/benchmarks.md)."""
    cfg = TrainConfig(preset="tiny", num_gaussians=1500, threads=1)
    cfg.schedule = ScheduleConfig(iterations=2000, checkpoint_every=500, log_every=10)
    cfg.model = dataclasses.replace(
        cfg.model, mlp_width=64, mlp_depth=4, mlp_skip=2, colors_lr=0.025, scales_lr=0.01
    )
    cfg.densify = dataclasses.replace(cfg.densify, max_gaussians=6000)
    return cfg


def _default() -> TrainConfig:
    cfg = TrainConfig(preset="default", num_gaussians=20_000)
    cfg.schedule = ScheduleConfig(iterations=6000, checkpoint_every=500)
    cfg.model = dataclasses.replace(cfg.model, mlp_width=128, mlp_depth=6, mlp_skip=3)
    return cfg


def _paper() -> TrainConfig:
    """The paper's schedule (§5) and Deformable-3DGS's MLP (8x256, skip at layer 4)."""
    return TrainConfig(preset="paper", num_gaussians=50_000)


PRESETS = {"tiny": _tiny, "default": _default, "paper": _paper}


def preset(name: str) -> TrainConfig:
    """The named preset; unknown names are a one-line error listing the choices."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise EvsplatError(
            f"unknown preset {name!r}; choose one of {', '.join(sorted(PRESETS))}"
        ) from None


def load_config(path) -> TrainConfig:
    """A TrainConfig from a JSON file such as a run's config.json."""
    import json
    from pathlib import Path

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
