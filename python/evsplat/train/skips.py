"""Skipping what a scene does not need: the deformation MLP for Gaussians that do not move, and
the iterations after a fixed held-out event loss has stopped improving (see ``SkipConfig``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from evsplat.config import LossConfig, SkipConfig
from evsplat.losses.event import event_loss
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel, normalize_quats

CHUNK = 65_536  # Gaussians per MLP pass when classifying: bounds the activations' memory
HOLDOUT_STREAM = 2**40  # RNG stream of the held-out windows; no iteration's seed reaches it
HOLDOUT_TRIES = 4  # candidate windows drawn per wanted one, to step over event-free windows

# ---- static Gaussians ----------------------------------------------------------------------


def static_due(cfg: SkipConfig, iteration: int, iterations: int) -> bool:
    """Whether the static classification is (re)computed at the start of ``iteration``."""
    start = int(round(cfg.static_start_fraction * iterations))
    return cfg.static and iteration >= start and (iteration - start) % cfg.static_every == 0


@dataclass
class Deformation:
    """A time-averaged deformation per Gaussian: what a static one keeps for good."""

    dx: Tensor  # [N,3]
    dq: Tensor  # [N,4]
    ds: Tensor  # [N,3]

    def select(self, rows: Tensor) -> Deformation:
        return Deformation(self.dx[rows], self.dq[rows], self.ds[rows])


@torch.no_grad()
def classify_static(
    mlp: DeformationMLP, means: Tensor, pixels_per_unit: Tensor, cfg: SkipConfig
) -> tuple[Tensor, Tensor, Deformation]:
    """([N] bool static, [N] bool still within the looser ``cfg.static_scene_px``, the
    time-averaged deformation) from ``cfg.static_times`` times in [0, 1].

    A Gaussian is static when its deformation hardly *changes* with time: Δx stays within
    ``cfg.static_px`` pixels of its mean (``pixels_per_unit`` [N] converts world units to
    pixels at the Gaussian's distance), Δq within ``static_dq`` and Δs within ``static_ds`` of
    theirs. A constant offset is no motion: the MLP's heads learn one for every Gaussian early
    on, and baking it into the canonical Gaussian keeps the render unchanged.
    """
    times = torch.linspace(0.0, 1.0, cfg.static_times).tolist()
    n = means.shape[0]
    static = torch.zeros(n, dtype=torch.bool)
    scene_static = torch.zeros(n, dtype=torch.bool)
    mean = Deformation(torch.zeros(n, 3), torch.zeros(n, 4), torch.zeros(n, 3))
    for a in range(0, n, CHUNK):
        x = means[a : a + CHUNK].detach()
        dx, dq, ds = (torch.stack(d) for d in zip(*(mlp(x, t) for t in times)))
        mean.dx[a : a + CHUNK], mean.dq[a : a + CHUNK] = dx.mean(0), dq.mean(0)
        mean.ds[a : a + CHUNK] = ds.mean(0)
        moved_px = (dx - dx.mean(0)).norm(dim=-1).amax(0) * pixels_per_unit[a : a + CHUNK]
        turned = ((dq - dq.mean(0)).norm(dim=-1).amax(0) <= cfg.static_dq) & (
            (ds - ds.mean(0)).abs().amax(-1).amax(0) <= cfg.static_ds
        )
        static[a : a + CHUNK] = (moved_px <= cfg.static_px) & turned
        scene_static[a : a + CHUNK] = (moved_px <= cfg.static_scene_px) & turned
    return static, scene_static, mean


@torch.no_grad()
def bake(model: GaussianModel, rows: Tensor, deformation: Deformation) -> None:
    """Fold ``deformation`` (one row per index in ``rows`` [K]) into those Gaussians' canonical
    parameters, exactly as ``deformed`` applies it, so they render the same without the MLP."""
    d = deformation
    model.means[rows] += d.dx
    model.log_scales[rows] += d.ds
    model.quats[rows] = normalize_quats(model.rotations()[rows] + d.dq)


def pixels_per_unit(means: Tensor, centre: Tensor, focal: float, near: float) -> Tensor:
    """[N] pixels per world unit of sideways motion at each Gaussian's distance from ``centre``
    (the cameras' mean position); distances below ``near`` count as ``near``."""
    return focal / (means.detach() - centre).norm(dim=-1).clamp_min(near)


def follow_rows(mask: Tensor, origin: Tensor) -> Tensor:
    """``mask`` re-indexed after densification: row i takes ``mask[origin[i]]`` (clones and
    split children take their parent's), pruned rows are gone."""
    return mask[origin]


# ---- early stop ----------------------------------------------------------------------------


@dataclass
class Window:
    """One held-out L_e window: its ends and the event image and mask observed over it."""

    t0: int
    t1: int
    esi: Tensor
    mask: Tensor


def holdout_windows(
    esi_of: Callable[[int, int], tuple[Tensor, Tensor, int]],
    t_start_us: int,
    t_end_us: int,
    lc: LossConfig,
    count: int,
    seed: int,
) -> list[Window]:
    """``count`` fixed windows with L_e's random lengths, drawn once from their own seeded
    stream; event-free ones are passed over. ``esi_of(t0, t1)`` gives (ESI, mask, events)."""
    rng = np.random.default_rng([seed, HOLDOUT_STREAM])
    duration = t_end_us - t_start_us
    windows: list[Window] = []
    for _ in range(count * HOLDOUT_TRIES):
        if len(windows) == count:
            break
        dt = int(rng.uniform(lc.window_min, lc.window_max) * duration)
        t1 = int(rng.integers(t_start_us + dt, t_end_us + 1))
        esi, mask, events = esi_of(t1 - dt, t1)
        if events > 0:
            windows.append(Window(t1 - dt, t1, esi, mask))
    return windows


@torch.no_grad()
def holdout_loss(
    windows: list[Window], log_image_at: Callable[[int], Tensor], lambda_ssim: float
) -> float:
    """Mean L_e over ``windows``; ``log_image_at(t)`` renders the log image the sensor sees."""
    total = 0.0
    for w in windows:
        delta = log_image_at(w.t1) - log_image_at(w.t0)
        total += float(event_loss(delta, w.esi, w.mask, lambda_ssim))
    return total / len(windows)


@dataclass
class Plateau:
    """Best held-out loss so far and how many evaluations have not improved on it."""

    best: float = float("inf")
    since_best: int = 0
    stopped_at: int | None = None  # completed iterations when training stopped early

    def update(self, value: float, done: int, cfg: SkipConfig) -> bool:
        """Record the loss after ``done`` iterations; True when training should stop."""
        if value < self.best * (1.0 - cfg.early_stop_min_delta):
            self.best, self.since_best = value, 0
        else:
            self.since_best += 1
        if self.since_best >= cfg.early_stop_patience:
            self.stopped_at = done
        return self.stopped_at is not None

    def state_dict(self) -> dict:
        return {"best": self.best, "since_best": self.since_best, "stopped_at": self.stopped_at}

    def load_state_dict(self, state: dict) -> None:
        self.best = float(state["best"])
        self.since_best = int(state["since_best"])
        self.stopped_at = state["stopped_at"]
