"""Canonical 3-D Gaussians: parameters, guarded activations, SH colour and optimizer groups."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from evsplat.config import ModelConfig
from evsplat.data.poses import rotation_entries

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh", "t_mean", "t_log_scale")
# Time-local opacity (not in the paper): a Gaussian is visible around t_mean with width
# exp(t_log_scale) in normalised time. The log-width is clamped: 0.02 of the sequence at the
# narrowest (a few of the shortest L_e windows), 20x it at the widest (static).
T_LOG_SCALE_RANGE = (math.log(0.02), math.log(20.0))
SCALE_MIN, SCALE_MAX = 1e-6, 1e3  # guard: keeps exp(log_scale) and its inverse finite
QUAT_EPS = 1e-12  # below this norm a quaternion carries no rotation and becomes the identity
# Colour is softplus(SH + 0.5) with this sharpness, not 3DGS's max(SH + 0.5, 0): the clamp passes no
# gradient below 0, so a channel pushed under it once stays black for the rest of the run (after the
# demo's run 36% of the static Gaussians had a dead channel, after `camo`'s 88%). Within 0.005 of
# the clamp above 0.3 (documented choice; docs/experiments/training.md, "Colour through a
# softplus").
COLOR_BETA = 10.0

# Real spherical-harmonic constants (as in 3DGS), bands 0..3.
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)  # fmt: skip
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)  # fmt: skip


def scale_activation(log_scales: Tensor) -> Tensor:
    """exp(log_scales) clamped to [SCALE_MIN, SCALE_MAX] (clamped in log space: no overflow)."""
    return torch.exp(log_scales.clamp(math.log(SCALE_MIN), math.log(SCALE_MAX)))


def color_activation(x: Tensor) -> Tensor:
    """Non-negative colour of SH value + 0.5: a sharp softplus (``COLOR_BETA``), finite for
    any input and with a gradient everywhere."""
    return torch.nn.functional.softplus(x, beta=COLOR_BETA)


def clamped_to_softplus(sh_dc: Tensor) -> Tensor:
    """The band-0 SH ``[...,C]`` whose ``color_activation`` colour is the one 3DGS's
    max(C0 dc + 0.5, 0) gives ``sh_dc``: models trained before the softplus render as trained.
    Their black (a channel at or under 0) becomes 1e-6, which the softplus reaches."""
    y = (SH_C0 * sh_dc + 0.5).clamp_min(1e-6)
    x = y + torch.log(-torch.expm1(-COLOR_BETA * y)) / COLOR_BETA  # softplus^-1, stable
    return (x - 0.5) / SH_C0


def time_width(t_log_scale: Tensor) -> Tensor:
    """Time widths (normalised time) of time-local opacity: exp of the clamped log-widths."""
    return torch.exp(t_log_scale.clamp(*T_LOG_SCALE_RANGE))


def normalize_quats(q: Tensor) -> Tensor:
    """Unit quaternions (w, x, y, z); a (near) zero quaternion becomes the identity, never NaN."""
    # Divide by the largest |component| (a constant) when it exceeds 1: |q|^2 of a quaternion
    # above ~1e19 overflows float32 and would turn it into zeros.
    peak = q.detach().abs().amax(-1, keepdim=True)
    q = torch.where(peak > 1.0, q / peak.clamp_min(1.0), q)
    sq = (q * q).sum(-1, keepdim=True)
    norm = torch.sqrt(sq.clamp_min(QUAT_EPS * QUAT_EPS))
    identity = torch.zeros_like(q)
    identity[..., 0] = 1.0
    return torch.where(sq > QUAT_EPS * QUAT_EPS, q / norm, identity)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Rotation matrices [N,3,3] of unit quaternions [N,4] (w, x, y, z), differentiable."""
    return torch.stack(rotation_entries(*q.unbind(-1)), dim=-1).reshape(*q.shape[:-1], 3, 3)


def eval_sh(sh: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate real SH coefficients ``sh [N,K,C]`` (K = (deg+1)^2 <= 16) at unit ``dirs [N,3]``."""
    k = sh.shape[1]
    out = SH_C0 * sh[:, 0]
    if k == 1:
        return out
    x, y, z = (dirs[:, i : i + 1] for i in range(3))
    out = out - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if k == 4:
        return out
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    out = (
        out
        + SH_C2[0] * xy * sh[:, 4]
        + SH_C2[1] * yz * sh[:, 5]
        + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6]
        + SH_C2[3] * xz * sh[:, 7]
        + SH_C2[4] * (xx - yy) * sh[:, 8]
    )
    if k == 9:
        return out
    return (
        out
        + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9]
        + SH_C3[1] * xy * z * sh[:, 10]
        + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
        + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
        + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13]
        + SH_C3[5] * z * (xx - yy) * sh[:, 14]
        + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15]
    )


class GaussianModel(nn.Module):
    """N anisotropic 3-D Gaussians in canonical space.

    Parameters: ``means [N,3]``, ``log_scales [N,3]``, ``quats [N,4]`` (w, x, y, z,
    unnormalised), ``opacity_logits [N]`` and ``sh [N,(deg+1)^2,C]`` (C = 1 for a monochrome
    sensor, 3 for a Bayer colour sensor). Activations are guarded so any finite parameter gives
    finite outputs and gradients.
    """

    def __init__(self, num: int, channels: int, sh_degree: int = 0):
        super().__init__()
        if num < 0 or channels not in (1, 3) or not 0 <= sh_degree <= 3:
            raise ValueError(
                f"GaussianModel: num={num}, channels={channels}, sh_degree={sh_degree}; "
                "need num >= 0, channels 1 or 3, sh_degree 0..3"
            )
        self.channels = channels
        self.sh_degree = sh_degree
        self.means = nn.Parameter(torch.zeros(num, 3))
        self.log_scales = nn.Parameter(torch.zeros(num, 3))
        self.quats = nn.Parameter(torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(num, 1))
        self.opacity_logits = nn.Parameter(torch.zeros(num))
        self.sh = nn.Parameter(torch.zeros(num, (sh_degree + 1) ** 2, channels))
        # Off (every Gaussian visible at all times) unless the trainer turns it on.
        self.temporal = False
        self.t_mean = nn.Parameter(torch.full((num,), 0.5))
        self.t_log_scale = nn.Parameter(torch.zeros(num))

    @property
    def num_gaussians(self) -> int:
        """Current number of Gaussians (changes with densification)."""
        return self.means.shape[0]

    @classmethod
    def random_init(
        cls,
        num: int,
        channels: int,
        bounds_min: Sequence[float] | Tensor,
        bounds_max: Sequence[float] | Tensor,
        sh_degree: int = 0,
        seed: int = 0,
        init_scale: float | None = None,
    ) -> GaussianModel:
        """Initialisation that needs no RGB or SfM: event data has neither.

        Means uniform in the axis-aligned box [bounds_min, bounds_max] (the trainer passes the
        volume seen by the trajectory); isotropic scales equal to the mean spacing of ``num``
        uniform points in that box, (volume / num)^(1/3), unless ``init_scale`` is given;
        identity rotations; opacity 0.1 (3DGS); grey colour 0.5 (zero SH, see ``colors``).
        """
        lo = torch.as_tensor(bounds_min, dtype=torch.float32).reshape(3)
        hi = torch.as_tensor(bounds_max, dtype=torch.float32).reshape(3)
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi >= lo).all()):
            raise ValueError(
                f"random_init: bounds {lo.tolist()}..{hi.tolist()} must be finite with max >= min"
            )
        model = cls(num, channels, sh_degree)
        gen = torch.Generator().manual_seed(seed)
        extent = (hi - lo).clamp_min(SCALE_MIN)  # a flat box still gets a finite spacing
        if init_scale is None:
            init_scale = float((extent.prod() / max(num, 1)) ** (1.0 / 3.0))
        init_scale = min(max(init_scale, SCALE_MIN), SCALE_MAX)
        opacity = ModelConfig.init_opacity
        with torch.no_grad():
            model.means.copy_(lo + (hi - lo) * torch.rand(num, 3, generator=gen))
            model.log_scales.fill_(math.log(init_scale))
            model.opacity_logits.fill_(math.log(opacity / (1.0 - opacity)))
            model.t_mean.copy_(torch.rand(num, generator=gen))
        return model

    def start_time_local(self, fraction: float, width: float, seed: int = 0) -> None:
        """Give a random ``fraction`` of the Gaussians the time width ``width`` (normalised
        time) around their time centres; the others keep theirs. With time-local opacity a fast
        object is then drawn from the first iterations by Gaussians that need not first shrink
        in time (from the initial width 1, they would be shown over most of the sequence)."""
        if not 0.0 <= fraction <= 1.0 or not width > 0.0:
            raise ValueError(
                f"start_time_local: fraction {fraction} must be in [0, 1], width {width} positive"
            )
        gen = torch.Generator().manual_seed(seed)
        local = torch.rand(self.num_gaussians, generator=gen) < fraction
        with torch.no_grad():
            self.t_log_scale[local] = math.log(width)

    def scales(self) -> Tensor:
        """Scales [N,3]: exp(log_scales) clamped to [1e-6, 1e3]."""
        return scale_activation(self.log_scales)

    def opacities(self, t: float | None = None) -> Tensor:
        """Opacities [N] in [0, 1): sigmoid of the logits; with time-local opacity on and a
        normalised time ``t``, times exp(-(t - t_mean)^2 / (2 w^2)), w = exp(t_log_scale)."""
        peak = torch.sigmoid(self.opacity_logits)
        if t is None or not self.temporal:
            return peak
        width = time_width(self.t_log_scale)
        return peak * torch.exp(-0.5 * ((t - self.t_mean) / width) ** 2)

    def rotations(self) -> Tensor:
        """Unit quaternions [N,4] (w, x, y, z); zero quaternions give the identity."""
        return normalize_quats(self.quats)

    def colors(self, camera_center: Tensor | None = None) -> Tensor:
        """Colour [N,C] seen from ``camera_center`` [3]: SH + 0.5 (3DGS offset) through
        ``color_activation``.

        Degree 0, or no camera centre given, uses the view-independent DC band only.
        """
        if self.sh_degree == 0 or camera_center is None:
            value = SH_C0 * self.sh[:, 0]
        else:
            # The viewing direction is a constant: colour must not pull Gaussians around.
            d = self.means.detach() - camera_center.to(self.means.dtype).reshape(1, 3)
            dirs = d / torch.sqrt((d * d).sum(-1, keepdim=True).clamp_min(1e-12))
            value = eval_sh(self.sh, dirs)
        return color_activation(value + 0.5)

    def param_groups(self, cfg: ModelConfig, scene_extent: float = 1.0) -> list[dict]:
        """Adam parameter groups with 3DGS learning rates; the means' rate scales with the
        scene extent. Each group carries ``name`` (the parameter's attribute name)."""
        lrs = {
            "means": cfg.means_lr * scene_extent,
            "log_scales": cfg.scales_lr,
            "quats": cfg.quats_lr,
            "opacity_logits": cfg.opacity_lr,
            "sh": cfg.colors_lr,
            "t_mean": cfg.t_mean_lr,
            "t_log_scale": cfg.t_scale_lr,
        }
        return [{"params": [getattr(self, n)], "lr": lrs[n], "name": n} for n in PARAM_NAMES]

    def state_for_checkpoint(self) -> dict:
        """Plain dict of detached CPU tensors plus the shape settings."""
        state = {n: getattr(self, n).detach().cpu().clone() for n in PARAM_NAMES}
        state["channels"] = self.channels
        state["sh_degree"] = self.sh_degree
        state["temporal"] = self.temporal
        return state

    @classmethod
    def from_checkpoint(cls, state: dict) -> GaussianModel:
        """Rebuild from ``state_for_checkpoint``; a missing or bad entry is a ValueError."""
        # Checkpoints from before time-local opacity lack its parameters: they were static.
        stored = [n for n in PARAM_NAMES if not (n.startswith("t_") and n not in state)]
        missing = [k for k in (*stored, "channels", "sh_degree") if k not in state]
        if missing:
            raise ValueError(f"Gaussian state lacks {', '.join(missing)}; not an evsplat model")
        num = int(state["means"].shape[0])
        model = cls(num, int(state["channels"]), int(state["sh_degree"]))
        model.temporal = bool(state.get("temporal", False))
        with torch.no_grad():
            for n in stored:
                param, value = getattr(model, n), torch.as_tensor(state[n])
                if value.shape != param.shape:
                    raise ValueError(
                        f"Gaussian state: {n} has shape {tuple(value.shape)}, "
                        f"expected {tuple(param.shape)}"
                    )
                if not torch.isfinite(value).all():
                    raise ValueError(f"Gaussian state: {n} contains NaN or Inf")
                param.copy_(value)
        return model
