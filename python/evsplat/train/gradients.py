"""A step's gradients looked at before the update: which loss teaches the deformation (each
loss's gradient norm on the MLP) and whether the step must be skipped (a non-finite one)."""

from __future__ import annotations

import math

import torch


def grad_norms_due(every: int, iteration: int) -> bool:
    """Whether ``iteration`` logs the per-loss gradient norms (``every`` 0: never)."""
    return every > 0 and iteration % every == 0


def mlp_grad_norms(mlp: torch.nn.Module, weighted: dict[str, torch.Tensor]) -> dict[str, float]:
    """L2 norm of each weighted loss's gradient on the MLP's parameters (``g_<loss>``),
    measured without changing the step (each loss gets its own backward pass through the
    retained graph)."""
    params = [p for p in mlp.parameters() if p.requires_grad]
    norms = {}
    for name, value in weighted.items():
        if not value.requires_grad:
            continue
        grads = torch.autograd.grad(value, params, retain_graph=True, allow_unused=True)
        sq = sum(float((g.detach() ** 2).sum()) for g in grads if g is not None)
        norms[f"g_{name}"] = math.sqrt(sq)
    return norms


def first_nonfinite_grad(*modules: torch.nn.Module) -> str | None:
    """``gradient of <parameter>`` for the first parameter with a NaN or Inf gradient."""
    grads = [
        (name, p.grad) for m in modules for name, p in m.named_parameters() if p.grad is not None
    ]
    # One test of them all first: a step almost never has a bad one, and each test costs a call.
    if not grads or bool(torch.isfinite(torch.cat([g.reshape(-1) for _, g in grads])).all()):
        return None
    return next(f"gradient of {name}" for name, g in grads if not bool(torch.isfinite(g).all()))
