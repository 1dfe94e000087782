"""Deformation MLP D(γ(x), γ(t)) -> (Δx, Δq, Δs) in the Deformable-3DGS style (paper eq. 6)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from evsplat.config import ModelConfig
from evsplat.model.gaussians import GaussianModel, normalize_quats, scale_activation
from evsplat.model.motion import ObjectMotion


def positional_encoding(p: Tensor, frequencies: int) -> Tensor:
    """NeRF encoding (p, sin(2^k p), cos(2^k p)) for k < frequencies, as Deformable-3DGS uses.

    ``p [N,D]`` -> ``[N, D·(1 + 2·frequencies)]``.
    """
    if frequencies == 0:
        return p
    freqs = 2.0 ** torch.arange(frequencies, dtype=p.dtype, device=p.device)
    # An explicit width: with N = 0 (every Gaussian static) -1 would be ambiguous.
    scaled = (p[:, None, :] * freqs[:, None]).reshape(p.shape[0], frequencies * p.shape[1])
    return torch.cat([p, torch.sin(scaled), torch.cos(scaled)], dim=-1)


class DeformationMLP(nn.Module):
    """ReLU MLP on the encoded canonical position and time with three zero-initialised heads.

    ``cfg.mlp_depth`` layers of ``cfg.mlp_width``; the encoded input is concatenated again to
    the output of layer ``cfg.mlp_skip`` (Deformable-3DGS: 8x256, skip at 4, L_x=10, L_t=6).
    The heads start at zero so the untrained MLP is the identity deformation.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        if cfg.mlp_width < 1 or not 0 <= cfg.mlp_skip < cfg.mlp_depth - 1:
            raise ValueError(
                f"DeformationMLP: depth={cfg.mlp_depth}, width={cfg.mlp_width}, "
                f"skip={cfg.mlp_skip}; need width >= 1 and 0 <= skip < depth - 1"
            )
        self.pe_x, self.pe_t, self.skip = cfg.pe_x, cfg.pe_t, cfg.mlp_skip
        self.input_dim = 3 * (1 + 2 * cfg.pe_x) + (1 + 2 * cfg.pe_t)
        width = cfg.mlp_width
        layers = [nn.Linear(self.input_dim, width)]
        for i in range(1, cfg.mlp_depth):
            extra = self.input_dim if i == cfg.mlp_skip + 1 else 0
            layers.append(nn.Linear(width + extra, width))
        self.layers = nn.ModuleList(layers)
        self.head_dx = nn.Linear(width, 3)
        self.head_dq = nn.Linear(width, 4)
        self.head_ds = nn.Linear(width, 3)
        for head in (self.head_dx, self.head_dq, self.head_ds):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def encode(self, x: Tensor, t: float | Tensor) -> Tensor:
        """Concatenated encodings γ(x), γ(t) ``[N, input_dim]``; ``t`` scalar, [N] or [N,1]."""
        t = torch.as_tensor(t, dtype=x.dtype, device=x.device)
        t = t.reshape(-1, 1).expand(x.shape[0], 1) if t.numel() == 1 else t.reshape(-1, 1)
        return torch.cat(
            [positional_encoding(x, self.pe_x), positional_encoding(t, self.pe_t)], dim=-1
        )

    def forward(self, x: Tensor, t: float | Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(Δx [N,3], Δq [N,4], Δs [N,3]) for canonical positions ``x [N,3]`` at normalised
        time ``t`` in [0, 1]. Δs is in log-scale units."""
        inp = self.encode(x, t)
        h = inp
        for i, layer in enumerate(self.layers):
            h = torch.relu(layer(h))
            if i == self.skip:
                h = torch.cat([inp, h], dim=-1)
        return self.head_dx(h), self.head_dq(h), self.head_ds(h)


def deformed(
    model: GaussianModel,
    mlp: DeformationMLP | None,
    t: float,
    mask: Tensor | None = None,
    motion: ObjectMotion | None = None,
    object_id: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """(means [N,3], unit rotations [N,4], scales [N,3]) of the Gaussians at time ``t``.

    The objects' rigid paths (``motion``, for the rows of ``object_id`` >= 0) move their
    Gaussians first; the MLP then adds its residual. ``mlp`` None adds none. ``mask`` [N] bool
    selects the Gaussians the MLP deforms; the others skip it (static Gaussians cost nothing).
    As in Deformable-3DGS the MLP sees the canonical means detached (the deformation does not
    move the canonical positions), Δq is added to the unit quaternion and re-normalised, and
    Δs is applied in log space so scales stay positive.
    """
    means, rotations = model.means, model.rotations()
    if motion is not None and object_id is not None:
        means, rotations = motion.apply(means, rotations, object_id, t)
    if mlp is None:
        return means, rotations, model.scales()
    if mask is None:
        dx, dq, ds = mlp(model.means.detach(), t)
    else:
        idx = torch.nonzero(mask.reshape(-1), as_tuple=False).reshape(-1)
        n = means.shape[0]
        sub = mlp(model.means.detach()[idx], t)
        dx, dq, ds = (
            torch.zeros(n, d.shape[1], dtype=d.dtype, device=d.device).index_copy(0, idx, d)
            for d in sub
        )
    rotations = normalize_quats(rotations + dq)
    return means + dx, rotations, scale_activation(model.log_scales + ds)


def deformed_means(
    model: GaussianModel,
    mlp: DeformationMLP,
    t: float,
    rows: Tensor,
    static: Tensor | None = None,
    motion: ObjectMotion | None = None,
    object_id: Tensor | None = None,
) -> Tensor:
    """Deformed means ``[len(rows),3]`` of the Gaussians ``rows`` at time ``t``, as ``deformed``
    places them: the objects' rigid paths, then the MLP for the rows not marked in ``static``."""
    means = model.means[rows]
    if motion is not None and object_id is not None:
        means = motion.apply(means, model.quats[rows], object_id[rows], t)[0]
    moving = (
        torch.arange(rows.numel(), device=rows.device)
        if static is None
        else torch.nonzero(~static[rows])
    )
    moving = moving.reshape(-1)
    dx = mlp(model.means[rows].detach()[moving], t)[0]
    return means.index_add(0, moving, dx)
