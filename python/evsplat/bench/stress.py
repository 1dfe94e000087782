"""`evsplat bench stress`: property-based stress over every numeric component, and SIGKILL trials.

Each component has a case generator ``<component>_cases(rng, n)`` yielding :class:`Case`\\ s that
mix the edge cases named in issue 8 (floods in one pixel, 2^40 µs offsets, empty windows,
extreme contrasts, 180° rotations, zero-variance images, zero depth, degenerate Gaussians, ...)
with random parameters. The invariant checked for every case:

* ``expect="finite"``: the case returns arrays (outputs and gradients) that are all finite and
  pass the case's own oracle checks (e.g. event counts add up, ESI matches numpy);
* ``expect="error"``: the input is invalid and must raise a clear error, i.e. an EvsplatError or
  ValueError with a non-empty one-line message; silently accepting it is a failure.

``--kill-trials N`` SIGKILLs `evsplat train` / `simulate --tiny` / `export` at random moments and
checks that every file a later command would read is absent or complete, and that `--resume`
continues from the newest complete checkpoint. The default tests run a small subset of both
(tests/test_stress_fast.py).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from evsplat.errors import EvsplatError

if TYPE_CHECKING:
    from evsplat.train.config import TrainConfig

HELP = "property-based stress of every numeric component (NaN/Inf, crashes) and SIGKILL trials"

Arrays = Sequence[np.ndarray | torch.Tensor | float]


@dataclass
class Case:
    """One stress case: ``run()`` returns the arrays that must be finite (and may assert its own
    oracle); ``expect`` is "finite" for valid input, "error" for input that must be refused, or
    "either" for input that may be refused with a clear error."""

    component: str
    label: str
    run: Callable[[], Arrays | None]
    expect: str = "finite"


@dataclass
class Tally:
    """Outcome counts of one component."""

    cases: int = 0
    finite: int = 0
    refused: int = 0  # invalid input refused with a clear error, as expected
    nonfinite: int = 0
    failures: list[str] = field(default_factory=list)

    @property
    def failed(self) -> int:
        return len(self.failures)


def _all_finite(values: Arrays | None) -> bool:
    for v in values or ():
        if isinstance(v, torch.Tensor):
            if v.is_floating_point() and not bool(torch.isfinite(v).all()):
                return False
        elif not np.all(np.isfinite(np.asarray(v, dtype=np.float64))):
            return False
    return True


def _clear(e: BaseException) -> bool:
    msg = str(e)
    return isinstance(e, EvsplatError | ValueError) and bool(msg.strip()) and "\n" not in msg


def check_case(case: Case, tally: Tally) -> None:
    """Run one case and record its outcome in ``tally``."""
    tally.cases += 1
    where = f"{case.component}/{case.label}"
    try:
        out = case.run()
    except Exception as e:  # anything else than a clear error is the bug being hunted
        if case.expect in ("error", "either") and _clear(e):
            tally.refused += 1
        else:
            tally.failures.append(f"{where}: {type(e).__name__}: {str(e)[:200]}")
        return
    if case.expect == "error":
        tally.failures.append(f"{where}: invalid input accepted without an error")
    elif not _all_finite(out):
        tally.nonfinite += 1
        tally.failures.append(f"{where}: NaN/Inf in the outputs or gradients")
    else:
        tally.finite += 1


def _grads(*tensors: torch.Tensor) -> list[torch.Tensor]:
    return [t.grad if t.grad is not None else torch.zeros(0) for t in tensors]


def _leaf(a: np.ndarray | torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float32).clone().requires_grad_(True)


# ---- event operations ----------------------------------------------------------------------------


def _event_arrays(rng: np.random.Generator, kind: str) -> tuple[dict, float, float]:
    """Random events of one edge-case ``kind``: (arrays for EventStream.from_arrays, C+, C-)."""
    w, h = int(rng.integers(1, 48)), int(rng.integers(1, 48))
    n = int(rng.integers(0, 3000))
    offset = 0
    c_pos, c_neg = float(np.exp(rng.uniform(np.log(1e-4), np.log(10)))), 0.0
    c_neg = float(np.exp(rng.uniform(np.log(1e-4), np.log(10))))
    if kind == "flood":  # every event in one pixel
        n = int(rng.integers(1, 50_000))
        x = np.full(n, rng.integers(0, w))
        y = np.full(n, rng.integers(0, h))
    else:
        x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    if kind == "offset_2^40":
        offset = 1 << 40
    if kind == "single":
        n = 1
        x, y = x[:1] if len(x) else np.zeros(1, int), y[:1] if len(y) else np.zeros(1, int)
    if kind == "empty":
        n = 0
        x, y = x[:0], y[:0]
    if kind == "contrast_extreme":
        c_pos, c_neg = (float(v) for v in rng.choice([1e-4, 10.0, 1.0], 2))
    if kind == "same_time":  # a burst: every event at one timestamp
        t = np.full(n, offset + int(rng.integers(0, 1 << 20)), np.int64)
    else:
        t = offset + np.sort(rng.integers(0, 1 << 20, n)).astype(np.int64)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return dict(x=x, y=y, t=t, p=p, width=w, height=h), c_pos, c_neg


def _event_ops(arrays: dict, c_pos: float, c_neg: float, rng: np.random.Generator) -> Arrays:
    """Every event operation on one stream, with numpy oracles for counts and ESI."""
    from evsplat.data.events import EventStream

    ev = EventStream.from_arrays(**arrays, source="<stress>")
    n = len(ev)
    i0 = int(rng.integers(0, n + 1))
    i1 = int(rng.integers(i0, n + 1))
    esi, mask = ev.esi_and_mask(i0, i1, c_pos, c_neg)
    count = ev.event_count(i0, i1)
    ref = np.zeros(ev.shape, np.float64)
    c = np.where(ev.p[i0:i1] > 0, c_pos, -c_neg)
    np.add.at(ref, (ev.y[i0:i1].astype(int), ev.x[i0:i1].astype(int)), c)
    assert int(count.sum()) == i1 - i0, "event count lost events"
    assert np.array_equal(mask, count > 0), "mask differs from count > 0"
    tol = 1e-5 * (np.abs(c).sum() + 1.0)
    assert np.abs(esi - ref).max(initial=0.0) <= tol, "ESI differs from the numpy reference"
    t_lo, t_hi = (int(ev.t[0]), int(ev.t[-1]) + 1) if n else (0, 1)
    a, b = ev.window(t_lo, t_hi)
    assert (a, b) == (0, n), "time window over the whole stream misses events"
    m = int(rng.integers(1, 6))
    bounds = ev.split_equal_count(i0, i1, m)
    assert bounds[0] == i0 and bounds[-1] == i1 and np.all(np.diff(bounds) >= 0)
    centres = rng.uniform(-5, max(ev.width, ev.height) + 5, (3, 2)).astype(np.float32)
    patches, _ = ev.patches(centres, bounds, int(rng.integers(1, 6)), c_pos, c_neg)
    vox = ev.voxel_grid(i0, i1, int(rng.integers(1, 6)))
    by_channel = ev.esi_by_channel(i0, i1, c_pos, c_neg, "RGGB")
    assert abs(float(by_channel.sum()) - float(esi.sum())) <= tol, "Bayer split lost events"
    return [esi, patches, vox, by_channel]


def event_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Event core: floods, 2^40 µs offsets, empty/single windows, extreme contrasts, bursts;
    plus invalid streams (unsorted, outside the sensor, NaN times, NaN contrast)."""
    from evsplat.data.events import EventStream

    kinds = ["flood", "offset_2^40", "empty", "single", "contrast_extreme", "same_time", "random"]
    bad = ["unsorted", "outside", "nan_time", "nan_contrast"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 8 == 7:
            kind = bad[(i // 8) % len(bad)]
            arrays, c_pos, c_neg = _event_arrays(r, "random")
            arrays["x"], arrays["y"] = np.append(arrays["x"], 0), np.append(arrays["y"], 0)
            arrays["p"], arrays["t"] = np.append(arrays["p"], 1), np.append(arrays["t"], 1 << 21)
            if kind == "unsorted":
                arrays["t"][-1] = -1
            elif kind == "outside":
                arrays["x"][-1] = arrays["width"]
            elif kind == "nan_time":
                arrays["t"] = arrays["t"].astype(np.float64)
                arrays["t"][-1] = np.nan

            def run(arrays=arrays, kind=kind, c_pos=c_pos) -> Arrays:
                ev = EventStream.from_arrays(**arrays, source="<stress>")
                if kind == "nan_contrast":
                    return [ev.esi(0, len(ev), c_pos, float("nan"))]
                return []

            yield Case("events", kind, run, expect="error")
            continue
        kind = kinds[i % len(kinds)]
        arrays, c_pos, c_neg = _event_arrays(r, kind)
        yield Case(
            "events", kind, lambda a=arrays, cp=c_pos, cn=c_neg, r=r: _event_ops(a, cp, cn, r)
        )


# ---- camera trajectory (SE(3) B-spline) ----------------------------------------------------------


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _spline_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.data.trajectory import Trajectory

    n = int(r.integers(2, 12))
    step = int(r.integers(1, 100_000))
    t = np.arange(n, dtype=np.int64) * step
    if kind == "long_gap":  # a gap of up to 10^3 sample spacings: resampled to uniform knots
        t[n // 2 :] += step * int(r.integers(10, 1000))
    if kind == "offset_2^40":
        t += 1 << 40
    c2w = np.tile(np.eye(4), (n, 1, 1))
    axis = r.normal(size=3)
    if kind == "near_identical":
        omega = float(r.uniform(1e-12, 1e-7))  # rad per sample
    elif kind == "rot_180":  # consecutive poses half a turn apart (antipodal quaternions)
        omega = math.pi - float(r.choice([0.0, 1e-9, 1e-6]))
    else:
        omega = float(r.uniform(-1.0, 1.0))
    for i in range(n):
        c2w[i, :3, :3] = _rot(axis, i * omega)
    # A smooth path (constant velocity plus small jitter) at a random scale.
    scale = float(r.choice([1e-6, 1.0, 1e3]))
    velocity = r.normal(size=3)
    c2w[:, :3, 3] = scale * (np.arange(n)[:, None] * velocity + 0.1 * r.normal(size=(n, 3)))
    knot = None if kind != "knot" else int(r.integers(1, 4 * step))
    traj = Trajectory.fit(t, c2w, knot_interval_us=knot, source="<stress>")
    q = np.sort(r.integers(traj.t_min_us, traj.t_max_us + 1, 16))
    poses = traj.pose(q)
    w, v = traj.velocity(q)
    rot = poses[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max()
    assert err < 1e-6, f"spline rotation not orthonormal (|R^T R - I| = {err:.1e})"
    return [poses, w, v]


def _bad_spline(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.data.trajectory import Trajectory

    n = int(r.integers(3, 8))
    t = np.arange(n, dtype=np.int64) * 1000
    c2w = np.tile(np.eye(4), (n, 1, 1))
    j = int(r.integers(1, n))
    if kind == "repeated_time":
        t[j] = t[j - 1]
    elif kind == "nan_pose":
        c2w[j, int(r.integers(0, 3)), int(r.integers(0, 4))] = float(r.choice([np.nan, np.inf]))
    elif kind == "not_a_rotation":
        c2w[j, :3, :3] *= 2.0
    elif kind == "one_pose":
        t, c2w = t[:1], c2w[:1]
    Trajectory.fit(t, c2w, source="<stress>")
    return []


def spline_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """B-spline: near-identical and 180° rotations, long gaps, 2^40 µs times, explicit knots;
    repeated timestamps, NaN poses, non-rotations and single poses must be refused."""
    kinds = ["near_identical", "rot_180", "long_gap", "offset_2^40", "knot", "random"]
    bad = ["repeated_time", "nan_pose", "not_a_rotation", "one_pose"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 5 == 4:
            kind = bad[(i // 5) % len(bad)]
            yield Case("spline", kind, lambda r=r, k=kind: _bad_spline(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            expect = "either" if kind == "rot_180" else "finite"
            yield Case("spline", kind, lambda r=r, k=kind: _spline_case(r, k), expect=expect)


# ---- losses --------------------------------------------------------------------------------------


def _image(r: np.random.Generator, shape: tuple[int, ...], kind: str) -> np.ndarray:
    if kind == "zero":
        return np.zeros(shape, np.float32)
    if kind == "constant":
        return np.full(shape, float(r.choice([-1e3, -1.0, 1e-8, 0.5, 1e3])), np.float32)
    scale = float(r.choice([1e-6, 1.0, 1e3]))
    return (r.normal(size=shape) * scale).astype(np.float32)


def _loss_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.losses.depth import silog
    from evsplat.losses.event import event_loss, log_render
    from evsplat.losses.flow import camera_flow, event_flow_loss, linearized_brightness_change
    from evsplat.losses.patch import patch_motion_loss
    from evsplat.losses.reg import non_event_loss, spatial_gradient_loss
    from evsplat.losses.ssim import ssim

    h, w = int(r.integers(1, 24)), int(r.integers(1, 24))
    img_kind = str(r.choice(["zero", "constant", "random"]))
    mask = torch.as_tensor(r.random((h, w)) < float(r.choice([0.0, 0.5, 1.0])))
    if kind == "ssim":
        a, b = _leaf(_image(r, (h, w), img_kind)), _leaf(_image(r, (h, w), img_kind))
        out = ssim(a, b, data_range=float(r.choice([1e-3, 1.0, 1e3])))
        out.backward()
        # float32 local variances (E[x^2] - E[x]^2) of values ~1e3 with data_range 1e-3 (C1, C2
        # ~1e-12) round off by ~1e-3 relative; exact SSIM lies in [-1, 1].
        assert -1.0 - 1e-3 <= out.item() <= 1.0 + 1e-3, f"SSIM {out.item()} outside [-1, 1]"
        return [out, *_grads(a, b)]
    if kind == "event_loss":
        a, b = _leaf(_image(r, (h, w), img_kind)), _leaf(_image(r, (h, w), "random"))
        out = event_loss(a, b, mask, float(r.choice([0.0, 0.2, 1.0])))
        out.backward()
        return [out, *_grads(a, b)]
    if kind == "silog":
        depth_kind = str(r.choice(["zero", "partial", "huge", "random"]))
        d = np.abs(_image(r, (h, w), "random")) + 0.1
        if depth_kind == "zero":
            d[:] = 0.0
        elif depth_kind == "partial":
            d[r.random((h, w)) < 0.5] = 0.0
        elif depth_kind == "huge":
            d *= 1e30
        pred, prior = _leaf(d), _leaf(np.abs(_image(r, (h, w), img_kind)))
        out = silog(pred, prior, mask if r.random() < 0.5 else None)
        out.backward()
        return [out, *_grads(pred, prior)]
    if kind == "flow":
        log_img = _leaf(_image(r, (h, w), img_kind))
        depth = _leaf(np.abs(_image(r, (h, w), str(r.choice(["zero", "random"])))))
        fx, fy = float(r.uniform(1, 500)), float(r.uniform(1, 500))
        K = torch.tensor([[fx, 0, w / 2], [0, fy, h / 2], [0, 0, 1]])
        w2c_b = torch.eye(4)
        w2c_b[:3, 3] = torch.as_tensor(r.normal(size=3) * float(r.choice([0.0, 1e-6, 10.0])))
        flow = camera_flow(depth, K, torch.eye(4), w2c_b)
        pred = linearized_brightness_change(log_img, flow)
        obs = _leaf(_image(r, (h, w), str(r.choice(["zero", "random"]))))
        out = event_flow_loss(obs, pred, mask if r.random() < 0.5 else None)
        out.backward()
        return [out, flow, *_grads(log_img, depth, obs)]
    if kind == "patch":
        m = int(r.integers(1, 5))
        frames = _leaf(_image(r, (m, h, w), img_kind))
        far = float(r.choice([1.0, 1e3, 1e6, 1e9]))
        centres = _leaf(r.uniform(-far, far, (int(r.integers(0, 6)), m, 2)))
        out = patch_motion_loss(frames, centres, int(r.integers(1, 8)))
        out.backward()
        return [out, *_grads(frames, centres)]
    if kind == "reg":
        img = _leaf(_image(r, (h, w), img_kind))
        out = non_event_loss(img, mask, float(r.uniform(0.01, 1))) + spatial_gradient_loss(img)
        out = out + log_render(img).mean()
        out.backward()
        return [out, *_grads(img)]
    raise AssertionError(kind)


def _bad_loss(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.losses.depth import silog
    from evsplat.losses.event import event_loss
    from evsplat.losses.flow import event_flow_loss
    from evsplat.losses.ssim import ssim

    a, b = torch.zeros(4, 5), torch.zeros(5, 4)
    {
        "ssim_shape": lambda: ssim(a, b),
        "ssim_range": lambda: ssim(a, a, data_range=0.0),
        "silog_shape": lambda: silog(a, b),
        "event_shape": lambda: event_loss(a, b, None, 0.2),
        "flow_shape": lambda: event_flow_loss(a, b),
    }[kind]()
    return []


def loss_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Losses: SSIM on zero-variance images, SiLog with zero / huge depth, the L2-normalised
    flow loss on all-zero maps, patch loss with centres far outside, regularisers on 1-pixel
    images; mismatched shapes must be refused."""
    kinds = ["ssim", "event_loss", "silog", "flow", "patch", "reg"]
    bad = ["ssim_shape", "ssim_range", "silog_shape", "event_shape", "flow_shape"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 10 == 9:
            kind = bad[(i // 10) % len(bad)]
            yield Case("losses", kind, lambda r=r, k=kind: _bad_loss(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            yield Case("losses", kind, lambda r=r, k=kind: _loss_case(r, k))


# ---- evaluation colour fit and metrics -----------------------------------------------------------


def _colour_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.metrics import fit_log_linear, psnr, ssim

    h, w, c = int(r.integers(1, 20)), int(r.integers(1, 20)), int(r.choice([1, 3]))
    gt = r.random((h, w, c)).astype(np.float32)
    pred = r.random((h, w, c)).astype(np.float32) * float(r.choice([1e-6, 1.0, 1e6]))
    if kind in ("constant_pred", "constant_both"):
        pred[:] = float(r.choice([0.0, 1e-9, 0.5, 1.0, 1e9]))
    if kind in ("constant_gt", "constant_both"):
        gt[:] = float(r.choice([0.0, 0.5, 1.0]))
    if kind == "negative":
        pred = -pred
    fit = fit_log_linear(pred, gt)
    assert fit.shape == pred.shape and fit.min() >= 0 and fit.max() <= 1, "fit outside [0, 1]"
    mask = r.random((h, w)) < 0.5
    return [fit, psnr(fit, gt), ssim(fit, gt), psnr(fit, gt, mask) if mask.any() else 0.0]


def colour_fit_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Evaluation colour fit + PSNR/SSIM: constant renders and ground truths, zeros, negative
    and huge renders, 1-pixel images."""
    kinds = ["constant_pred", "constant_gt", "constant_both", "negative", "random"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        kind = kinds[i % len(kinds)]
        yield Case("colour_fit", kind, lambda r=r, k=kind: _colour_case(r, k))


# ---- model activations ---------------------------------------------------------------------------


def _model_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.model.gaussians import GaussianModel

    n = int(r.integers(1, 16))
    model = GaussianModel(n, int(r.choice([1, 3])), sh_degree=int(r.integers(0, 4)))
    with torch.no_grad():
        model.means.copy_(torch.as_tensor(r.normal(size=(n, 3)) * float(r.choice([1e-6, 1, 1e6]))))
        big = float(r.choice([1e-30, 1.0, 1e4, 1e30]))
        model.log_scales.copy_(torch.as_tensor(r.uniform(-big, big, (n, 3))))
        model.opacity_logits.copy_(torch.as_tensor(r.uniform(-big, big, n)))
        model.sh.copy_(torch.as_tensor(r.normal(size=model.sh.shape)))
        if kind == "zero_quats":
            model.quats.zero_()
        else:
            mag = float(r.choice([1e-30, 1e-12, 1e-6, 1.0, 1e6, 1e18, 1e30]))
            model.quats.copy_(torch.as_tensor(r.normal(size=(n, 4)) * mag))
    centre = torch.as_tensor(r.normal(size=3), dtype=torch.float32)
    if kind == "camera_on_a_mean":
        centre = model.means.detach()[0].clone()
    scales, opac, rots = model.scales(), model.opacities(), model.rotations()
    colors = model.colors(centre)
    loss = scales.sum() + opac.sum() + rots.sum() + colors.sum()
    loss.backward()
    norms = rots.detach().norm(dim=-1)
    assert torch.allclose(norms, torch.ones_like(norms), atol=1e-4), "rotation not unit length"
    assert bool(((opac >= 0) & (opac <= 1)).all()), "opacity outside [0, 1]"
    return [scales, opac, rots, colors, *[p.grad for p in model.parameters() if p.grad is not None]]


def model_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Gaussian activations: log-scales and opacity logits up to ±1e30, zero / tiny / huge
    quaternions, SH colour seen from a camera sitting on a Gaussian."""
    kinds = ["zero_quats", "camera_on_a_mean", "random"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        kind = kinds[i % len(kinds)]
        yield Case("model", kind, lambda r=r, k=kind: _model_case(r, k))


# ---- rasterizer (small cases: each call runs on the GPU context) ---------------------------------


def _raster_case(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.raster import rasterize

    n = int(r.integers(1, 8))
    w, h = int(r.integers(1, 24)), int(r.integers(1, 24))
    if kind == "1x1":
        w = h = 1
    elif kind == "aspect":
        w, h = (1, 96) if r.random() < 0.5 else (96, 1)
    means = np.column_stack([r.normal(size=(n, 2)), r.uniform(1, 5, n)])
    scales = np.exp(r.uniform(-3, 0, (n, 3)))
    quats = r.normal(size=(n, 4))
    near = 0.01
    if kind == "degenerate":
        scales[:] = 0.0
    elif kind == "tiny":
        scales[:] = 1e-7
    elif kind == "huge":
        scales[:] = float(r.choice([1e2, 1e4, 1e6]))
    elif kind == "flat":
        scales[:, int(r.integers(0, 3))] = float(r.choice([0.0, 1e-9]))
    elif kind == "behind":
        means[:, 2] = -np.abs(means[:, 2])
    elif kind == "near_plane":
        means[:, 2] = near + r.choice([-1e-7, 0.0, 1e-7, 1e-4], n)
    elif kind == "coincident":
        means[:] = means[0]
    elif kind == "off_screen":
        means[:, :2] = r.choice([-1.0, 1.0], (n, 2)) * float(r.choice([1e2, 1e6]))
    elif kind == "zero_quats":
        quats[:] = 0.0
    f = float(r.choice([0.5, 50.0, 5e4]))
    K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], dtype=torch.float32)
    m, q, s = _leaf(means), _leaf(quats), _leaf(scales)
    o = _leaf(r.choice([0.0, 1.0, 0.5], n) if kind == "opacity_edges" else r.random(n))
    feats = _leaf(r.random((n, int(r.integers(1, 4)))))
    image, depth, alpha, meta = rasterize(m, q, s, o, feats, torch.eye(4), K, w, h, near=near)
    weights = [
        torch.as_tensor(r.normal(size=t.shape), dtype=torch.float32) for t in (image, depth, alpha)
    ]
    loss = (image * weights[0]).sum() + (depth * weights[1]).sum() + (alpha * weights[2]).sum()
    loss.backward()
    a = alpha.detach()
    assert bool(((a >= 0) & (a <= 1 + 1e-6)).all()), "alpha outside [0, 1]"
    return [image, depth, alpha, meta["means2d"], *_grads(m, q, s, o, feats)]


def _bad_raster(r: np.random.Generator, kind: str) -> Arrays:
    from evsplat.raster import rasterize

    n = 2
    args = [torch.zeros(n, 3), torch.ones(n, 4), torch.ones(n, 3), torch.ones(n), torch.ones(n, 1)]
    args[0][:, 2] = 2.0
    if kind == "nan_means":
        args[0][0, 0] = float("nan")
    elif kind == "inf_scales":
        args[2][1, 1] = float("inf")
    size = (0, 4) if kind == "zero_width" else (4, 4)
    rasterize(*args, torch.eye(4), torch.eye(3), *size)
    return []


def raster_cases(rng: np.random.Generator, n: int) -> Iterator[Case]:
    """Rasterizer: degenerate / tiny / huge / flat / behind-camera / near-plane / coincident /
    off-screen Gaussians, zero quaternions, opacity 0 and 1, 1x1 images, 1x96 and 96x1 images;
    NaN means, infinite scales and a zero-width image must be refused."""
    kinds = ["degenerate", "tiny", "huge", "flat", "behind", "near_plane", "coincident",
             "off_screen", "zero_quats", "opacity_edges", "1x1", "aspect", "random"]  # fmt: skip
    bad = ["nan_means", "inf_scales", "zero_width"]
    for i in range(n):
        r = np.random.default_rng(rng.integers(1 << 62))
        if i % 14 == 13:
            kind = bad[(i // 14) % len(bad)]
            yield Case("raster", kind, lambda r=r, k=kind: _bad_raster(r, k), expect="error")
        else:
            kind = kinds[i % len(kinds)]
            yield Case("raster", kind, lambda r=r, k=kind: _raster_case(r, k))


# The share of the total case count each component gets (the rasterizer is the slowest per call).
COMPONENTS: dict[str, tuple[Callable[[np.random.Generator, int], Iterator[Case]], float]] = {
    "events": (event_cases, 0.30),
    "spline": (spline_cases, 0.15),
    "losses": (loss_cases, 0.25),
    "colour_fit": (colour_fit_cases, 0.10),
    "model": (model_cases, 0.12),
    "raster": (raster_cases, 0.08),
}


def run_stress(
    total: int, seed: int = 0, components: Sequence[str] | None = None
) -> dict[str, Tally]:
    """Run about ``total`` cases split over ``components`` by their shares; a Tally for each."""
    names = list(components or COMPONENTS)
    share = sum(COMPONENTS[c][1] for c in names)
    tallies = {}
    for k, name in enumerate(names):
        gen, weight = COMPONENTS[name]
        rng = np.random.default_rng([seed, k])
        tally = Tally()
        for case in gen(rng, max(1, round(total * weight / share))):
            check_case(case, tally)
        tallies[name] = tally
    return tallies


def format_tallies(tallies: dict[str, Tally], seconds: dict[str, float] | None = None) -> str:
    """The per-component table the bench prints."""
    rows = ["component | cases | finite | refused (clear error) | NaN/Inf | failures | seconds"]
    tot = Tally()
    for name, t in tallies.items():
        s = f"{seconds[name]:.1f}" if seconds else "-"
        rows.append(
            f"{name} | {t.cases} | {t.finite} | {t.refused} | {t.nonfinite} | {t.failed} | {s}"
        )
        tot.cases, tot.finite, tot.refused = (
            tot.cases + t.cases,
            tot.finite + t.finite,
            tot.refused + t.refused,
        )
        tot.nonfinite += t.nonfinite
        tot.failures += t.failures
    rows.append(
        f"total | {tot.cases} | {tot.finite} | {tot.refused} | {tot.nonfinite} | {tot.failed} | -"
    )
    return "\n".join(rows)


# ---- crash safety: SIGKILL at random moments -----------------------------------------------------

KILL_ITERS = 12  # iterations of each killed tiny training run
KILL_CKPT_EVERY = 3
KILL_GAUSSIANS = 300  # the tiny preset with fewer Gaussians: crash safety, not quality


def kill_config() -> TrainConfig:
    """The tiny preset shrunk so that a killed run and its resume take seconds."""
    from evsplat.train.config import preset

    cfg = preset("tiny")
    cfg.num_gaussians = KILL_GAUSSIANS
    cfg.schedule.iterations = KILL_ITERS
    cfg.schedule.checkpoint_every = KILL_CKPT_EVERY
    return cfg


def _cli(*args: str | Path) -> list[str]:
    return [sys.executable, "-m", "evsplat.cli", *map(str, args)]


def _run_and_kill(cmd: list[str], after_s: float) -> bool:
    """Start ``cmd``, SIGKILL it ``after_s`` seconds later; True if it was still running."""
    env = {**os.environ, "EVSPLAT_QUIET": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    try:
        proc.wait(timeout=after_s)
        return False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return True


def _timed(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def check_dataset_output(out: Path) -> list[str]:
    """A killed `simulate`: its --out folder is absent or a complete, valid dataset."""
    from evsplat.data.dataset import check_dataset

    if not out.exists():
        return []
    return [f"{out}: {p}" for p in check_dataset(out)]


def check_ply_output(path: Path, before: bytes | None) -> list[str]:
    """A killed `export`: the PLY is absent, the old file byte for byte, or complete."""
    if not path.exists():
        return [] if before is None else [f"{path}: existing export deleted"]
    data = path.read_bytes()
    if data == before:
        return []
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        return [f"{path}: no complete PLY header"]
    header = data[: end + len(b"end_header\n")].decode("ascii").splitlines()
    n = next(int(h.split()[2]) for h in header if h.startswith("element vertex"))
    props = sum(1 for h in header if h.startswith("property float"))
    want = end + len(b"end_header\n") + 4 * n * props
    return [] if len(data) == want else [f"{path}: {len(data)} bytes, a complete PLY has {want}"]


def check_run_output(run: Path) -> list[str]:
    """A killed `train`: every JSON file parses and every listed checkpoint loads."""
    from evsplat.checkpoint import list_checkpoints, load_checkpoint

    problems = []
    for name in ("config.json", "stats.json"):
        if (run / name).exists():
            try:
                json.loads((run / name).read_text())
            except ValueError:
                problems.append(f"{run / name}: not valid JSON")
    if (run / "log.jsonl").exists():
        try:
            for line in (run / "log.jsonl").read_text().splitlines():
                json.loads(line)
        except ValueError:
            problems.append(f"{run / 'log.jsonl'}: a line is not valid JSON")
    for ckpt in list_checkpoints(run):
        try:
            load_checkpoint(ckpt)
        except EvsplatError as e:
            problems.append(str(e))
    return problems


def resume_and_check(data: Path, run: Path, iters: int) -> list[str]:
    """``--resume`` a killed run: it must start at the newest complete checkpoint's iteration
    (0 when there is none) and finish with a checkpoint at ``iters``."""
    from evsplat.checkpoint import latest_checkpoint, load_checkpoint
    from evsplat.train import loop, train

    latest = latest_checkpoint(run)
    expected = load_checkpoint(latest)["iteration"] if latest is not None else 0
    started: list[int] = []
    original = loop.Trainer.run

    def spy(self: loop.Trainer, progress: bool = True) -> loop.TrainStats:
        started.append(self.start_iteration)
        return original(self, progress)

    loop.Trainer.run = spy  # observe where the resumed loop starts; restored below
    try:
        train(data, run, config=kill_config(), iterations=iters, resume=True, progress=False)
    finally:
        loop.Trainer.run = original
    problems = []
    if started != [expected]:
        problems.append(f"{run}: resumed at {started}, newest complete checkpoint is {expected}")
    final = latest_checkpoint(run)
    if final is None or load_checkpoint(final)["iteration"] != iters:
        problems.append(f"{run}: resumed run did not finish at iteration {iters}")
    return problems


@dataclass
class KillReport:
    """Outcome of the SIGKILL trials."""

    trials: dict[str, int] = field(default_factory=lambda: {"train": 0, "simulate": 0, "export": 0})
    killed_mid_run: int = 0  # trials where the process was still running when killed
    resumed: int = 0
    corrupt: list[str] = field(default_factory=list)


KINDS = ("train", "simulate", "export")


def kill_trials(n: int, work: Path, seed: int = 0, kinds: Sequence[str] = KINDS) -> KillReport:
    """``n`` SIGKILL trials cycling through ``kinds`` (train / simulate --tiny / export), each
    killed at a uniform random moment within the command's measured uninterrupted wall time."""
    from evsplat.data.simulator import simulate_dataset
    from evsplat.train import train

    rng = np.random.default_rng(seed)
    data = work / "data"
    simulate_dataset("ball", data, tiny=True, seed=0, progress=False)
    source_run = work / "source_run"
    if "export" in kinds:
        train(data, source_run, config=kill_config(), iterations=2, progress=False)
    config = work / "kill_config.json"
    config.write_text(json.dumps(kill_config().to_dict()))
    train_args = ("--config", config, "--iters", KILL_ITERS, "--checkpoint-every", KILL_CKPT_EVERY)
    cmds = {
        "train": lambda out: _cli("train", data, "--out", out, *train_args, "--no-progress"),
        "simulate": lambda out: _cli(
            "simulate", "--scene", "ball", "--tiny", "--out", out, "--no-progress"
        ),  # fmt: skip
        "export": lambda out: _cli("export", source_run, "--ply", out),
    }
    # Uninterrupted wall times (interpreter start included) bound the random kill moments.
    duration = {k: _timed(cmds[k](work / f"timing_{k}")) for k in kinds}
    previous_ply = (work / "timing_export").read_bytes() if "export" in kinds else None
    report = KillReport()
    for i in range(n):
        kind = kinds[i % len(kinds)]
        out = work / f"{kind}_{i}"
        if kind == "export":  # an older export sits where the new one goes: it must survive
            out.write_bytes(previous_ply)
        report.killed_mid_run += _run_and_kill(cmds[kind](out), rng.uniform(0, duration[kind]))
        report.trials[kind] += 1
        if kind == "simulate":
            report.corrupt += check_dataset_output(out)
        elif kind == "export":
            report.corrupt += check_ply_output(out, previous_ply)
        else:
            found = check_run_output(out)
            report.corrupt += found
            if not found:
                report.corrupt += resume_and_check(data, out, KILL_ITERS)
                report.resumed += 1
    return report


# ---- the bench -----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cases", type=int, default=10_000, help="total cases (default 10000; 0: none)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--components", default=None, help=f"comma-separated subset of {', '.join(COMPONENTS)}"
    )
    parser.add_argument(
        "--kill-trials", type=int, default=0, help="SIGKILL trials of train/simulate/export"
    )


def run(args: argparse.Namespace) -> int:
    names = args.components.split(",") if args.components else list(COMPONENTS)
    unknown = [c for c in names if c not in COMPONENTS]
    if unknown:
        raise EvsplatError(
            f"--components: unknown {', '.join(unknown)}; choose from {', '.join(COMPONENTS)}"
        )
    tallies, seconds = {}, {}
    for name in names if args.cases > 0 else []:
        t = time.perf_counter()
        share = COMPONENTS[name][1] / sum(COMPONENTS[c][1] for c in names)
        tallies.update(run_stress(max(1, round(args.cases * share)), args.seed, [name]))
        seconds[name] = time.perf_counter() - t
    print(format_tallies(tallies, seconds))
    failures = [f for t in tallies.values() for f in t.failures]
    for f in failures[:50]:
        print(f"FAIL {f}")
    nan = sum(t.nonfinite for t in tallies.values())
    print(f"NaN/Inf found: {nan}; failures: {len(failures)}")
    corrupt = 0
    if args.kill_trials > 0:
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            rep = kill_trials(args.kill_trials, Path(tmp), args.seed)
            wall = time.perf_counter() - t
        corrupt = len(rep.corrupt)
        per = ", ".join(f"{k} {v}" for k, v in rep.trials.items())
        print(
            f"SIGKILL trials: {sum(rep.trials.values())} ({per}); killed mid-run "
            f"{rep.killed_mid_run}; resumed {rep.resumed}; corrupt outputs found: {corrupt}; "
            f"{wall:.0f} s"
        )
        for c in rep.corrupt:
            print(f"CORRUPT {c}")
    return 1 if failures or corrupt else 0


if __name__ == "__main__":
    from evsplat.cli import main

    sys.exit(main(["bench", "stress", *sys.argv[1:]]))
