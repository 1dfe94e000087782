"""Skipping what a scene does not need: the deformation MLP for Gaussians that do not move (and
for a whole scene whose events show nothing moving), and the iterations after a fixed held-out
event loss has stopped improving (see ``SkipConfig``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from evsplat.config import LossConfig, SkipConfig
from evsplat.losses.event import event_loss
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel, normalize_quats
from evsplat.render import Renderer
from evsplat.train.views import Views

CHUNK = 65_536  # Gaussians per MLP pass when classifying: bounds the activations' memory
HOLDOUT_STREAM = 2**40  # RNG stream of the held-out windows; no iteration's seed reaches it
HOLDOUT_TRIES = 4  # candidate windows drawn per wanted one, to step over event-free windows
EVIDENCE_STREAM = 2**40 + 1  # RNG stream of the static-scene evidence windows
# A region whose event energy is below this fraction of the median region's has too few events
# to show anything (a textureless wall); it is left out of the static-scene evidence.
MIN_REGION_ENERGY = 0.1

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
    """([N] bool static, [N] bool still within the looser ``cfg.static_scene_*`` bounds, the
    time-averaged deformation) from ``cfg.static_times`` times in [0, 1].

    A Gaussian is static when its deformation hardly *changes* with time: Δx stays within
    ``cfg.static_px`` pixels of its mean (``pixels_per_unit`` [N] converts world units to
    pixels at the Gaussian's distance), Δq within ``static_dq`` and Δs within ``static_ds`` of
    theirs. A constant offset is no motion: the MLP's heads learn one for every Gaussian early
    on, and baking it into the canonical Gaussian keeps the render unchanged.
    """
    times = torch.linspace(0.0, 1.0, cfg.static_times).tolist()
    n, device = means.shape[0], means.device
    static = torch.zeros(n, dtype=torch.bool, device=device)
    scene_static = torch.zeros(n, dtype=torch.bool, device=device)
    mean = Deformation(*(torch.zeros(n, k, device=device) for k in (3, 4, 3)))
    for a in range(0, n, CHUNK):
        x = means[a : a + CHUNK].detach()
        dx, dq, ds = (torch.stack(d) for d in zip(*(mlp(x, t) for t in times)))
        mean.dx[a : a + CHUNK], mean.dq[a : a + CHUNK] = dx.mean(0), dq.mean(0)
        mean.ds[a : a + CHUNK] = ds.mean(0)
        moved_px = (dx - dx.mean(0)).norm(dim=-1).amax(0) * pixels_per_unit[a : a + CHUNK]
        turned = (dq - dq.mean(0)).norm(dim=-1).amax(0)
        scaled = (ds - ds.mean(0)).abs().amax(-1).amax(0)
        static[a : a + CHUNK] = (
            (moved_px <= cfg.static_px) & (turned <= cfg.static_dq) & (scaled <= cfg.static_ds)
        )
        scene_static[a : a + CHUNK] = (
            (moved_px <= cfg.static_scene_px)
            & (turned <= cfg.static_scene_dq)
            & (scaled <= cfg.static_scene_ds)
        )
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


# ---- static scene: evidence in the events ------------------------------------------------
#
# The MLP learning no motion (classify_static's scene mask) does not mean nothing moves: on the
# moving `ball` the MLP learns little motion at short budgets, time-local opacity carries the
# ball instead, and that criterion alone found the scene static. The events decide too: a static
# scene's events over a window are the camera's motion over one unchanging scene, so the model
# *frozen* at the window's middle time (deformation and time-local opacity both evaluated there,
# for both ends) and rendered from the poses at the window's ends must explain them everywhere,
# while a moving object leaves events in its region that no frozen scene explains.
#
# Frozen, not "time-local opacity off" nor "as is" (measured with the defaults on the tiny
# scenes, the worst region's unexplained share after 1333 of 2000 iterations):
#   frozen: `still` 0.12, ball 0.88, clock 0.78 (after 200 of 300: 0.26, 0.72, 0.65);
#   as is (the model at t0 and at t1): `still` 0.10, ball 0.17, clock 0.16: time-local
#     opacity and the MLP learn to explain the motion, so the moving scenes look static;
#   off (every Gaussian at its peak opacity at all times, MLP baked): `still` 0.37 (0.44
#     after 200): all the time-local Gaussians at once are a scene training never saw.


def evidence_windows(
    esi_of: Callable[[int, int], tuple[Tensor, Tensor, int]],
    t_start_us: int,
    t_end_us: int,
    lc: LossConfig,
    cfg: SkipConfig,
    seed: int,
    allowed: Callable[[int, int], bool] = lambda t0, t1: True,
) -> list[Window]:
    """``cfg.static_scene_windows`` fixed windows with lengths drawn uniformly from
    ``cfg.static_scene_window_lengths`` (fractions of the sequence), from their own seeded
    stream; event-free ones, and those not ``allowed``, are passed over (``holdout_windows``)."""
    lo, hi = cfg.static_scene_window_lengths
    lengths = dataclasses.replace(lc, window_min=lo, window_max=hi)
    count = cfg.static_scene_windows
    return holdout_windows(
        esi_of, t_start_us, t_end_us, lengths, count, seed, EVIDENCE_STREAM, allowed
    )


@torch.no_grad()
def unexplained_events(
    windows: list[Window], log_image_at: Callable[[int, int], Tensor], cfg: SkipConfig
) -> Tensor:
    """Per image region (``cfg.static_scene_block`` px squares), the share of its events that
    the scene frozen at each window's middle time does not explain: 1 - ρ², ρ the correlation
    (clamped at 0) of the ESI and the predicted log change ``log_image_at(t_mid, t1) -
    log_image_at(t_mid, t0)`` over the region and all ``windows``, both first averaged over
    ``cfg.static_scene_pool`` px squares. ``log_image_at(t_scene, t_pose)`` renders the model
    at ``t_scene`` from the pose at ``t_pose``. Returns [R] for the regions with enough events
    (``MIN_REGION_ENERGY``); 0 is all explained, 1 nothing.

    1 - ρ² is what stays of the ESI's energy after the best gain times the prediction is taken
    away: the gain forgives a contrast the model has not yet matched, not a different pattern.
    The pooling averages away the ESI's per-pixel quantisation to steps of C (at single pixels
    even the true log change leaves ~30% of the energy; after 4x4 pooling ~8%)."""
    sums = None  # per region: Σ esi², Σ esi·pred, Σ pred²
    for w in windows:
        mid = (w.t0 + w.t1) // 2
        pred = log_image_at(mid, w.t1) - log_image_at(mid, w.t0)
        pool = min(cfg.static_scene_pool, *pred.shape[-2:])
        e, d = (F.avg_pool2d(x.reshape(-1, 1, *x.shape[-2:]).double(), pool) for x in (w.esi, pred))
        if sums is None:
            ids, regions = region_ids(
                e.shape[-2], e.shape[-1], cfg.static_scene_block / pool, e.device
            )
            sums = torch.zeros(3, regions, dtype=torch.float64, device=e.device)
        for k, x in enumerate((e * e, e * d, d * d)):
            sums[k].index_add_(0, ids, x.sum((0, 1)).reshape(-1))
    if sums is None:
        return torch.zeros(0)
    e_e, e_d, d_d = sums
    rho = (e_d / (e_e * d_d).sqrt().clamp_min(1e-30)).clamp_min(0.0)
    enough = (e_e > 0) & (e_e >= MIN_REGION_ENERGY * e_e.median())
    return (1.0 - rho**2)[enough].float()


def region_ids(
    height: int, width: int, size: float, device: torch.device | None = None
) -> tuple[Tensor, int]:
    """([height * width] region index of each pixel, region count): about ``size``-pixel
    squares, round(height / size) x round(width / size) of them (at least one each way)."""
    ny, nx = max(1, round(height / size)), max(1, round(width / size))
    y = torch.arange(height, device=device) * ny // height
    x = torch.arange(width, device=device) * nx // width
    return (y[:, None] * nx + x[None, :]).reshape(-1), ny * nx


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
    stream: int = HOLDOUT_STREAM,
    allowed: Callable[[int, int], bool] = lambda t0, t1: True,
) -> list[Window]:
    """``count`` fixed windows with L_e's random lengths, drawn once from their own seeded
    ``stream``; event-free ones are passed over, and those not ``allowed`` (overlapping the
    held-out intervals of ``train.heldout``) are not read. ``esi_of(t0, t1)`` gives (ESI,
    mask, events)."""
    rng = np.random.default_rng([seed, stream])
    duration = t_end_us - t_start_us
    windows: list[Window] = []
    for _ in range(count * HOLDOUT_TRIES):
        if len(windows) == count:
            break
        dt = int(rng.uniform(lc.window_min, lc.window_max) * duration)
        t1 = int(rng.integers(t_start_us + dt, t_end_us + 1))
        if not allowed(t1 - dt, t1):
            continue
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


# ---- applying the classification during training -------------------------------------------


def update_static(
    model: GaussianModel,
    mlp: DeformationMLP,
    renderer: Renderer,
    centre: Tensor,
    focal: float,
    cfg: SkipConfig,
    scene_unexplained: Callable[[], float],
) -> bool:
    """Mark the dynamic Gaussians that stopped moving static in ``renderer.static_mask`` and
    bake their deformation; static ones stay static, so only the dynamic ones go through the
    MLP. ``centre`` [3] is the mean camera position and ``focal`` the focal length in pixels
    (Gaussians' motion is measured in pixels from there). True when this first classification
    finds the whole scene static, which also needs ``scene_unexplained()`` (the events'
    evidence) to agree: the MLP having learned no motion does not show that nothing moves
    (time-local opacity may carry the moving object)."""
    first = renderer.static_mask is None
    none = torch.zeros(model.num_gaussians, dtype=torch.bool, device=model.means.device)
    old = none if first else renderer.static_mask
    dynamic = torch.nonzero(~old).reshape(-1)
    means = model.means[dynamic]
    scale = pixels_per_unit(means, centre, focal, 1e-2)
    static, scene_static, mean = classify_static(mlp, means, scale, cfg)
    whole = False
    if first and float(scene_static.float().mean()) >= cfg.static_scene_fraction:
        if cfg.static_scene_unexplained >= 1 or (
            scene_unexplained() <= cfg.static_scene_unexplained
        ):
            static[:] = True
            whole = True
    bake(model, dynamic[static], mean.select(static))
    new = old.clone()
    new[dynamic[static]] = True
    renderer.static_mask = new
    return whole


def scene_unexplained(
    views: Views, mlp: DeformationMLP, loss: LossConfig, cfg: SkipConfig, seed: int
) -> float:
    """The largest share of one region's events that the scene frozen at each evidence
    window's middle time (deformation and time-local opacity evaluated there) leaves
    unexplained, seen from the poses at the window's ends (``unexplained_events``); 0 when no
    window has events."""
    data, renderer = views.data, views.renderer
    windows = evidence_windows(
        views.esi, data.t_start_us, data.t_end_us, loss, cfg, seed, views.allowed
    )

    def log_image_at(t_scene: int, t_pose: int) -> Tensor:
        return views.log_image(renderer.render(t_scene, views.pose(t_pose)))

    kept, renderer.mlp = renderer.mlp, mlp
    try:
        share = unexplained_events(windows, log_image_at, cfg)
    finally:
        renderer.mlp = kept
    return float(share.max()) if share.numel() else 0.0
