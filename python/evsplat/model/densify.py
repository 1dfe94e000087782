"""3DGS adaptive density control: clone, split, prune and opacity reset, Adam state kept in sync."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor, nn

from evsplat.config import DensifyConfig
from evsplat.model.gaussians import PARAM_NAMES, GaussianModel, quat_to_rotmat, time_width

RESET_OPACITY = 0.01  # 3DGS: opacities are capped to this at each reset


def update_params(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    transform: Callable[[str, Tensor, bool], Tensor],
) -> None:
    """Replace every Gaussian parameter by ``transform(name, old, is_state)`` and apply the same
    row operation to its per-row optimizer state (``is_state`` True), keeping the optimizer's
    groups pointing at the new parameters."""
    for name in PARAM_NAMES:
        old = getattr(model, name)
        new = nn.Parameter(transform(name, old.detach(), False))
        for group in optimizer.param_groups:
            for k, p in enumerate(group["params"]):
                if p is old:
                    group["params"][k] = new
        state = optimizer.state.pop(old, None)
        if state is not None:
            for key, value in state.items():
                if torch.is_tensor(value) and value.shape == old.shape:
                    state[key] = transform(name, value, True)
            optimizer.state[new] = state
        setattr(model, name, new)


def set_rows(
    model: GaussianModel,
    optimizer: torch.optim.Optimizer,
    rows: Tensor,
    values: dict[str, Tensor | float],
) -> None:
    """Set the parameters named in ``values`` at ``rows`` (long [M]) to their values (one per
    row, or one for all); their optimizer state there starts afresh."""

    def transform(name: str, old: Tensor, is_state: bool) -> Tensor:
        if name not in values:
            return old
        new = old.clone()
        new[rows] = 0.0 if is_state else values[name]
        return new

    update_params(model, optimizer, transform)


class Densifier:
    """Gradient statistics and the 3DGS density-control schedule.

    ``accumulate`` after each backward pass, ``step`` after each optimizer step. The window
    [start, stop) comes from fractions of ``total_iterations``; see ``DensifyConfig``.
    """

    def __init__(self, cfg: DensifyConfig, scene_extent: float, total_iterations: int = 30_000):
        self.cfg = cfg
        self.extent = float(scene_extent)
        self.start = int(round(cfg.start_fraction * total_iterations))
        self.stop = int(round(cfg.stop_fraction * total_iterations))
        self.reset_interval = cfg.opacity_reset_interval  # 0: never
        self.grad_accum = torch.zeros(0)
        self.denom = torch.zeros(0)
        self.max_radii = torch.zeros(0)
        # For each Gaussian after the last `step`, its row before it (-1: created by it), so
        # per-Gaussian state kept elsewhere (the static mask) can follow clones and prunes.
        self.origin = torch.zeros(0, dtype=torch.long)

    def _reset_stats(self, n: int, device: torch.device) -> None:
        self.grad_accum = torch.zeros(n, device=device)
        self.denom = torch.zeros(n, device=device)
        self.max_radii = torch.zeros(n, device=device)

    def _ensure_size(self, n: int, device: torch.device) -> None:
        if self.grad_accum.shape[0] != n:
            self._reset_stats(n, device)

    def accumulate(
        self,
        means2d_grad: Tensor | None,
        radii: Tensor,
        width: int,
        height: int,
    ) -> None:
        """Add this view's screen-space gradient norms of the visible Gaussians (radius > 0).

        The rasterizer gives a radius only to Gaussians in the view and opaque enough to draw
        (opacity >= 1/255). The opacity test matters with time-local opacity: a Gaussian shown
        only while a fast object passes would otherwise count every view of other times as one
        without gradient, and its mean gradient (accumulated / views) would fall below the
        threshold however badly it fits when it is shown. Pixel gradients are converted to NDC
        units (x W/2, x H/2) as in 3DGS, so its threshold 2e-4 keeps its meaning at any
        resolution.
        """
        if means2d_grad is None:
            return
        self._ensure_size(means2d_grad.shape[0], means2d_grad.device)
        visible = radii.reshape(-1) > 0
        ndc = torch.tensor([width / 2.0, height / 2.0], device=means2d_grad.device)
        g = means2d_grad.detach().reshape(-1, 2) * ndc
        norm = torch.nan_to_num(g.norm(dim=-1), nan=0.0, posinf=0.0)
        # Whole-array updates that add 0 (and keep the old maximum) where not visible: the same
        # values as updating the visible rows through boolean indexing, in fewer calls.
        self.grad_accum += torch.where(visible, norm, 0.0)
        self.denom += visible
        wider = torch.maximum(self.max_radii, radii.reshape(-1).to(self.max_radii.dtype))
        self.max_radii = torch.where(visible, wider, self.max_radii)

    def densifies(self, iteration: int) -> bool:
        """Whether ``step`` clones, splits and prunes at ``iteration``."""
        return self.start < iteration < self.stop and iteration % self.cfg.interval == 0

    def step(
        self,
        model: GaussianModel,
        optimizer: torch.optim.Adam,
        iteration: int,
        ruled_out: Tensor | None = None,
    ) -> dict:
        """Density control for ``iteration`` (after its optimizer step).

        Inside [start, stop): every ``interval`` iterations clone small / split large
        high-gradient Gaussians and prune transparent (and, after the first opacity reset, huge)
        ones and those ``ruled_out`` [N] (clones of them too); every ``reset_interval``
        iterations cap opacities at 0.01. Any time: prune the least opaque Gaussians down to
        ``max_gaussians``. Returns the counts of what was done, empty when nothing was;
        ``origin`` maps the rows after it to the rows before (a new row to its clone or split
        parent).
        """
        cfg, counts = self.cfg, {}
        device = model.means.device
        self.origin = torch.arange(model.num_gaussians, device=device)
        if self.densifies(iteration):
            counts.update(self._densify_and_prune(model, optimizer, iteration, ruled_out))
        resets = self.reset_interval > 0 and 0 < iteration < self.stop
        if resets and iteration % self.reset_interval == 0:
            self._reset_opacity(model, optimizer)
            counts["reset"] = 1
        excess = model.num_gaussians - cfg.max_gaussians
        if excess > 0:
            keep = torch.ones(model.num_gaussians, dtype=torch.bool, device=device)
            keep[torch.argsort(model.opacity_logits.detach())[:excess]] = False
            self._prune(model, optimizer, keep)
            counts["capped"] = excess
        return counts

    def _densify_and_prune(
        self, model: GaussianModel, optimizer, iteration: int, ruled_out: Tensor | None
    ) -> dict:
        cfg = self.cfg
        n0, device = model.num_gaussians, model.means.device
        self._ensure_size(n0, device)
        grads = self.grad_accum / self.denom.clamp_min(1)
        high = grads >= cfg.grad_threshold
        room = cfg.max_gaussians - n0  # a clone adds one Gaussian, a split into two one net
        recycled = self._recycle(model, high, int(high.sum()) - room)
        room += int(recycled.sum())
        if int(high.sum()) > max(room, 0):
            # Budget: densify only the strongest gradients that fit, rather than growing past
            # the cap and pruning what was just added.
            keep = torch.zeros_like(high)
            keep[torch.argsort(grads, descending=True)[: max(room, 0)]] = True
            high &= keep
        max_scale = model.scales().detach().max(dim=-1).values
        small = max_scale <= cfg.percent_dense * self.extent
        clone, split = high & small, high & ~small
        n_clone, n_split = int(clone.sum()), int(split.sum())

        # New rows: clones are copies; each split parent gives split_count children sampled
        # from the parent Gaussian, with scales divided by split_scale_divisor.
        k = cfg.split_count
        with torch.no_grad():
            # Every parameter but position and size is copied: once per clone, k times per split.
            new = {
                n: torch.cat([p[clone], p[split].repeat(k, *(1,) * (p.dim() - 1))])
                for n in PARAM_NAMES
                if n not in ("means", "log_scales")
                for p in [getattr(model, n).detach()]
            }
            means = model.means.detach()
            parent_scale = model.scales().detach()[split].repeat(k, 1)
            rot = quat_to_rotmat(model.rotations().detach()[split]).repeat(k, 1, 1)
            offset = torch.bmm(rot, (torch.randn_like(parent_scale) * parent_scale)[..., None])
            new["means"] = torch.cat([means[clone], means[split].repeat(k, 1) + offset[..., 0]])
            child_log = torch.log(parent_scale / cfg.split_scale_divisor)
            new["log_scales"] = torch.cat([model.log_scales.detach()[clone], child_log])
            if model.temporal and cfg.split_in_time:
                self._split_in_time(new, n_clone)

        def append(name: str, old: Tensor, is_state: bool) -> Tensor:
            extra = torch.zeros_like(new[name]) if is_state else new[name]
            return torch.cat([old, extra])

        update_params(model, optimizer, append)
        n_new = model.num_gaussians - n0
        # Children remember their parent, so per-Gaussian flags (static) carry over to them.
        parents = torch.nonzero(clone).reshape(-1), torch.nonzero(split).reshape(-1).repeat(k)
        self.origin = torch.cat([self.origin, *parents])
        opac = model.opacities().detach()
        none = torch.zeros(n_new, dtype=torch.bool, device=device)
        prune = torch.cat([split | recycled, none]) | (opac < cfg.prune_opacity)
        if ruled_out is not None:
            prune |= ruled_out[self.origin]  # a clone or split child of one is ruled out too
        # 3DGS: size pruning only once opacities were reset
        if 0 < self.reset_interval < iteration:
            radii = torch.cat([self.max_radii, torch.zeros(n_new, device=device)])
            big_world = (
                model.scales().detach().max(dim=-1).values > cfg.max_world_scale * self.extent
            )
            prune |= (radii > cfg.max_screen_radius) | big_world
        # Split parents are replaced and recycled ones make room: neither counts as pruned.
        n_recycled = int(recycled.sum())
        n_pruned = int(prune.sum()) - n_split - n_recycled
        self._prune(model, optimizer, ~prune)
        # Statistics restart after every density change.
        self._reset_stats(model.num_gaussians, device)
        counts = {"cloned": n_clone, "split": n_split, "pruned": n_pruned, "recycled": n_recycled}
        return counts | ({} if ruled_out is None else {"swept": int(ruled_out.sum())})

    def _split_in_time(self, new: dict[str, Tensor], n_clone: int) -> None:
        """Sample the split children (rows after ``n_clone`` of ``new``, the new parameters) of
        time-local Gaussians in time too (4D-GS style): each child's time centre is drawn from
        its parent's temporal Gaussian and its width divided like its scales, so a fast object's
        time slices are refined where its gradients are large. Wide (static) parents keep their
        time: a static background must not become time-local.
        """
        cfg = self.cfg
        t_mean, t_log = new["t_mean"][n_clone:], new["t_log_scale"][n_clone:]
        width = time_width(t_log)
        local = width < cfg.time_local_width
        jitter = torch.randn(t_mean.shape, device=t_mean.device) * width
        new["t_mean"][n_clone:] = torch.where(local, (t_mean + jitter).clamp(0.0, 1.0), t_mean)
        shrunk = t_log - math.log(cfg.split_scale_divisor)
        new["t_log_scale"][n_clone:] = torch.where(local, shrunk, t_log)

    def _recycle(self, model: GaussianModel, high: Tensor, shortfall: int) -> Tensor:
        """[N] bool: the faintest Gaussians to remove so that ``shortfall`` more high-gradient
        ones can be densified under the budget.

        Without this a run that fills its budget early (the tiny preset does within its warm-up)
        never densifies again, so what only the motion stage fits (a fast object's later
        positions) gets no new Gaussians. Faint ones (peak opacity below ``recycle_opacity``,
        not themselves densified) go first, at most ``recycle_fraction`` of the budget per
        densification: a bounded version of 3DGS-MCMC's relocation of dead Gaussians.
        """
        cfg = self.cfg
        out = torch.zeros_like(high)
        limit = min(shortfall, int(cfg.recycle_fraction * cfg.max_gaussians))
        if limit <= 0:
            return out
        peak = torch.sigmoid(model.opacity_logits.detach())
        faint = torch.nonzero(~high & (peak < cfg.recycle_opacity)).reshape(-1)
        out[faint[torch.argsort(peak[faint])[:limit]]] = True
        return out

    def _prune(self, model: GaussianModel, optimizer, keep: Tensor) -> None:
        update_params(model, optimizer, lambda _n, old, _s: old[keep])
        self.origin = self.origin[keep]
        if self.grad_accum.shape[0] == keep.shape[0]:
            self.grad_accum = self.grad_accum[keep]
            self.denom = self.denom[keep]
            self.max_radii = self.max_radii[keep]

    def _reset_opacity(self, model: GaussianModel, optimizer) -> None:
        cap = math.log(RESET_OPACITY / (1 - RESET_OPACITY))

        def reset(name: str, old: Tensor, is_state: bool) -> Tensor:
            if name != "opacity_logits":
                return old
            return torch.zeros_like(old) if is_state else old.clamp_max(cap)

        update_params(model, optimizer, reset)

    def state_dict(self) -> dict:
        """Gradient statistics, for checkpoints."""
        return {"grad_accum": self.grad_accum, "denom": self.denom, "max_radii": self.max_radii}

    def load_state_dict(self, state: dict, device: torch.device | str = "cpu") -> None:
        """Restore ``state_dict`` onto ``device`` (the model's)."""
        self.grad_accum = state["grad_accum"].to(device, copy=True)
        self.denom = state["denom"].to(device, copy=True)
        self.max_radii = state["max_radii"].to(device, copy=True)
