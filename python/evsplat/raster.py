"""The differentiable Gaussian splatting rasterizer (wgpu compute passes behind a torch autograd
Function).

``rasterize`` takes float32 tensors and returns the image, expected depth and alpha plus a
``meta`` dict; gradients flow to means, quats, scales, opacities and features. The tensors may
live on any torch device: the core works on host memory, so tensors elsewhere (CUDA) go to the
host in one copy per render and the outputs, and later the gradients, come back in one copy
each, on the Gaussians' device. Conventions
(gsplat's): quaternions (w, x, y, z), scales are standard deviations, the camera looks along +z,
pixel (row i, column j) has its centre at (j + 0.5, i + 0.5) in K's pixel coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from evsplat import _core
from evsplat.errors import EvsplatError, core_call

MAX_FEATURES = 32


#: The Gaussians' inputs as the core names them, in ``rasterize``'s order.
_GAUSSIANS = ("means", "quats", "scales", "opacities", "features", "background")


NEAR, FAR = 0.01, 1e4  # default clip planes (camera z): nearer or farther Gaussians are culled


@dataclass(frozen=True)
class _Camera:
    """One render's settings, and its inputs on the host (``host``: flat float32 arrays under
    the core's names, copied from another device once and reused by the backward)."""

    width: int
    height: int
    near: float
    far: float
    atomics: str | None
    profile: dict | None
    work: dict | None  # filled with the compositing step counts when not None
    host: dict[str, np.ndarray]
    device: torch.device  # the Gaussians': outputs and gradients go there


def _to_host(tensors: list[torch.Tensor]) -> list[np.ndarray]:
    """Flat host arrays of ``tensors``: views of CPU tensors (no copy when contiguous), and the
    others concatenated on their device and copied to the host in one transfer."""
    out = [t.detach().reshape(-1).contiguous() for t in tensors]
    away = [i for i, t in enumerate(out) if t.device.type != "cpu"]
    if away:
        host = torch.cat([out[i] for i in away]).cpu()
        for i, part in zip(away, host.split([out[i].numel() for i in away])):
            out[i] = part
    return [t.numpy() for t in out]


def _to_device(arrays: list[np.ndarray], device: torch.device) -> list[torch.Tensor]:
    """The core's flat 4-byte arrays (float32 or int32) as tensors on ``device``: wrapped
    without a copy on the CPU, else joined on the host and sent in one transfer."""
    if device.type == "cpu":
        return [torch.from_numpy(a) for a in arrays]
    bits = torch.from_numpy(np.concatenate([a.reshape(-1).view(np.float32) for a in arrays]))
    parts = bits.to(device).split([a.size for a in arrays])
    return [p.view(torch.int32) if a.dtype == np.int32 else p for p, a in zip(parts, arrays)]


def _check(name: str, t: object, shape: tuple[int | None, ...]) -> torch.Tensor:
    if not isinstance(t, torch.Tensor):
        raise EvsplatError(f"rasterize: {name} must be a torch.Tensor, got {type(t).__name__}")
    if t.dtype != torch.float32:
        raise EvsplatError(f"rasterize: {name} must be float32, got {t.dtype}; use .float()")
    ok = t.dim() == len(shape) and all(w is None or w == s for w, s in zip(shape, t.shape))
    if not ok:
        want = "[" + ", ".join("*" if w is None else str(w) for w in shape) + "]"
        raise EvsplatError(f"rasterize: {name} has shape {list(t.shape)}, expected {want}")
    return t


def _host_inputs(named: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """``named`` tensors on the host under the core's names, each checked finite."""
    host = dict(zip(named, _to_host(list(named.values()))))
    for name, a in host.items():
        # numpy's isfinite: torch's took 53 ms per 3 M floats here (~300 ms of a 1 M Gaussian
        # call).
        if not np.isfinite(a).all():
            shown = "K" if name == "k" else name
            raise EvsplatError(f"rasterize: {shown} contains NaN or Inf; pass finite values")
    return host


def _inputs(cam: _Camera) -> dict[str, np.ndarray]:
    """The Gaussians as the core takes them: flat float32 host arrays."""
    return {k: cam.host[k] for k in _GAUSSIANS}


def _args(cam: _Camera, d: int) -> dict:
    return dict(**cam.host, d=d, width=cam.width, height=cam.height, near=cam.near, far=cam.far)


def _core_call(fn, *args, **kwargs) -> dict:
    """GPU failures (RuntimeError) get the "rasterize:" prefix the core's input errors carry."""
    try:
        return core_call(None, fn, *args, **kwargs)
    except RuntimeError as e:
        raise EvsplatError(f"rasterize: {e}") from None


class _Render:
    """What a render's backward needs of it: its core state, set by the forward, or by
    ``PendingRaster.result`` when the render was started by ``rasterize_async``."""

    def __init__(self, state: object = None):
        self.state = state


_OUTPUTS = ("image", "depth", "alpha", "radii", "means2d", "depths")


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, features, viewmat, K, background, cam,
                means2d_grad, started):  # fmt: skip
        n, d = features.shape
        h, w = cam.height, cam.width
        shapes = ((h, w, d), (h, w), (h, w), (n,), (n, 2), (n,))
        if started is None:
            out = _core_call(
                _core.rasterize_forward,
                **_args(cam, d),
                profile=cam.profile is not None,
                count_work=cam.work is not None,
            )
            if cam.profile is not None:
                cam.profile["forward"] = dict(out["times"])
            if cam.work is not None:
                cam.work.update(out["work"])
            flat = _to_device([out[k] for k in _OUTPUTS], cam.device)
            outputs = [t.reshape(s) for t, s in zip(flat, shapes)]
            ctx.render = _Render(out["state"])
        else:
            # Started by rasterize_async: the node is made now, where a render in place would
            # be (torch sums gradients in the order of its nodes), and the outputs are filled
            # when the render is read back (PendingRaster.result), before anything sees them.
            dtypes = (torch.float32,) * 3 + (torch.int32,) + (torch.float32,) * 2
            outputs = [torch.empty(s, dtype=t, device=cam.device) for s, t in zip(shapes, dtypes)]
            started.outputs = outputs
            ctx.render = started.render
        # The render's inputs, saved so that torch rejects their in-place change before the
        # backward: it renders again from their host copies when later renders took its buffers.
        ctx.save_for_backward(means, quats, scales, opacities, features, background)
        ctx.cam = cam
        ctx.shape = (n, d)
        ctx.means2d_grad = means2d_grad
        image, depth, alpha, radii, means2d, depths = outputs
        ctx.mark_non_differentiable(radii, means2d, depths)
        return image, depth, alpha, radii, means2d, depths

    @staticmethod
    def backward(ctx, g_image, g_depth, g_alpha, _r, _m, _d):
        cam: _Camera = ctx.cam
        n, d = ctx.shape
        h, w = cam.height, cam.width

        grads, sizes = (g_image, g_depth, g_alpha), (h * w * d, h * w, h * w)
        sent = iter(_to_host([g.float() for g in grads if g is not None]))
        image, depth, alpha = (
            np.zeros(s, np.float32) if g is None else next(sent) for g, s in zip(grads, sizes)
        )
        out = _core_call(
            _core.rasterize_backward,
            ctx.render.state,
            **_inputs(cam),
            grad_image=image,
            grad_depth=depth,
            grad_alpha=alpha,
            atomics=cam.atomics,
            profile=cam.profile is not None,
        )
        if cam.profile is not None:
            cam.profile["backward"] = dict(out["times"])
        names = ("means2d", "means", "quats", "scales", "opacities", "features")
        m2d, means, quats, scales, opacities, features = _to_device(
            [out[k] for k in names], cam.device
        )
        ctx.means2d_grad.copy_(m2d.reshape(n, 2))
        return (
            means.reshape(n, 3),
            quats.reshape(n, 4),
            scales.reshape(n, 3),
            opacities,
            features.reshape(n, d),
            None,
            None,
            None,
            None,
            None,
            None,
        )


def rasterize(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near: float = NEAR,
    far: float = FAR,
    background: torch.Tensor | None = None,
    *,
    atomics: str | None = None,
    profile: dict | None = None,
    count_work: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict]:
    """Render N Gaussians with D feature channels into an H x W view.

    Args: means [N,3], quats [N,4] (w,x,y,z, any norm), scales [N,3] (standard deviations),
    opacities [N] (in [0,1]), features [N,D] (1 <= D <= 32), viewmat [4,4] world->camera,
    K [3,3]; background [D] (default 0). ``atomics`` picks the gradient accumulation
    ("float", "cas"; default: the adapter's, ``EVSPLAT_ATOMICS=cas`` forces CAS). ``profile``, a
    dict, receives per-pass host times in seconds (passes then run one submission each).
    ``count_work`` runs the compositing pass's counting build (slower) and adds meta["work"]:
    tile-Gaussian "pairs" and pixel-Gaussian steps "evaluated", "contributed" (composited) and
    "saturated" (walked after the pixel's transmittance fell below the cut-off), and the tiles'
    side in pixels, "tile_size".

    Returns image [H,W,D] = sum f_i w_i + T_final * background, depth [H,W] = sum w_i z_i / alpha
    (0 where alpha is 0), alpha [H,W] = 1 - T_final, and meta with "radii" int32 [N] (0 = culled),
    "means2d" [N,2], "depths" [N] (camera z), "visible" bool [N] and "means2d_grad" [N,2], zeros
    that the backward pass overwrites with dLoss/dmeans2d (for densification).
    """
    args = _checked(
        means, quats, scales, opacities, features, viewmat, K, width, height, near, far,
        background, atomics, profile, count_work,
    )  # fmt: skip
    return _results(*_apply(args, None), args[-1])


def rasterize_async(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near: float = NEAR,
    far: float = FAR,
    background: torch.Tensor | None = None,
    *,
    atomics: str | None = None,
    count_work: bool = False,
) -> PendingRaster:
    """``rasterize``, started on the device without waiting: ``.result()`` of what it returns
    waits for the render and gives what ``rasterize`` would have (the same values, the same
    gradients). The device renders while the caller does other work (on a CPU adapter its
    threads take the cores the caller's thread leaves idle). The inputs must not change in
    place before ``.result()``."""
    args = _checked(
        means, quats, scales, opacities, features, viewmat, K, width, height, near, far,
        background, atomics, None, count_work,
    )  # fmt: skip
    cam = args[-1]
    started = _Started(
        _core_call(_core.rasterize_submit, **_args(cam, args[4].shape[1]), count_work=count_work)
    )
    return PendingRaster(args, started, _apply(args, started))


class _Started:
    """A render on its way: the core's handle, its state once read back, and its outputs."""

    def __init__(self, handle: object):
        self.handle = handle
        self.render = _Render()
        self.outputs: list[torch.Tensor] = []


class PendingRaster:
    """A render started by ``rasterize_async``; ``result()`` (once) waits for it."""

    def __init__(self, args: tuple, started: _Started, applied: tuple):
        self._args = args
        self._started: _Started | None = started
        self._applied = applied
        self._versions = [t._version for t in args[:8]]

    def result(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict]:
        started, self._started = self._started, None
        if started is None:
            raise EvsplatError("rasterize_async: result() was taken already")
        if [t._version for t in self._args[:8]] != self._versions:
            raise EvsplatError(
                "rasterize_async: an input changed in place after the render was started"
            )
        cam = self._args[-1]
        out = _core_call(_core.rasterize_finish, started.handle, **_inputs(cam))
        started.render.state = out["state"]
        if cam.work is not None:
            cam.work.update(out["work"])
        with torch.no_grad():
            flat = _to_device([out[k] for k in _OUTPUTS], cam.device)
            for t, value in zip(started.outputs, flat):
                t.view(-1).copy_(value)
        return _results(*self._applied, cam)


def _checked(
    means, quats, scales, opacities, features, viewmat, K, width, height, near, far, background,
    atomics, profile, count_work,
) -> tuple:  # fmt: skip
    """The arguments of ``rasterize`` checked at the boundary: the tensors and the _Camera,
    with the tensors' host copies. The Gaussians (and ``background``) share one device, the
    outputs' and gradients'; ``viewmat`` and ``K`` may be anywhere."""
    means = _check("means", means, (None, 3))
    n = means.shape[0]
    quats = _check("quats", quats, (n, 4))
    scales = _check("scales", scales, (n, 3))
    opacities = _check("opacities", opacities, (n,))
    features = _check("features", features, (n, None))
    d = features.shape[1]
    if not 1 <= d <= MAX_FEATURES:
        raise EvsplatError(f"rasterize: features have {d} channels; use 1 to {MAX_FEATURES}")
    viewmat = _check("viewmat", viewmat, (4, 4))
    K = _check("K", K, (3, 3))
    if background is None:
        background = torch.zeros(d, device=means.device)
    background = _check("background", background, (d,))
    gaussians = dict(zip(_GAUSSIANS, (means, quats, scales, opacities, features, background)))
    devices = {t.device for t in gaussians.values()}
    if len(devices) > 1:
        where = ", ".join(f"{k} on {t.device}" for k, t in gaussians.items())
        raise EvsplatError(f"rasterize: the Gaussians are on several devices ({where}); use .to()")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 16384:
            raise EvsplatError(f"rasterize: {name}={value!r} must be an int in 1..16384")
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
        raise EvsplatError(f"rasterize: need finite 0 < near < far, got near={near}, far={far}")
    if atomics not in (None, "float", "cas"):
        raise EvsplatError(f"rasterize: atomics={atomics!r} must be 'float', 'cas' or None")
    work = {} if count_work else None
    host = _host_inputs(gaussians | {"viewmat": viewmat, "k": K})
    cam = _Camera(
        int(width), int(height), float(near), float(far), atomics, profile, work, host, means.device
    )
    return means, quats, scales, opacities, features, viewmat, K, background, cam


def _apply(args: tuple, started: _Started | None) -> tuple:
    """The render's autograd node: (image, depth, alpha, radii, means2d, depths, means2d_grad)."""
    means, quats, scales, opacities, features, viewmat, K, background, cam = args
    means2d_grad = torch.zeros(means.shape[0], 2, device=means.device)
    outputs = _Rasterize.apply(
        means, quats, scales, opacities, features, viewmat, K, background, cam, means2d_grad,
        started,
    )  # fmt: skip
    return (*outputs, means2d_grad)


def _results(image, depth, alpha, radii, means2d, depths, means2d_grad, cam: _Camera) -> tuple:
    """``rasterize``'s return value from the node's outputs."""
    meta = {
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "visible": radii > 0,
        "means2d_grad": means2d_grad,
    }
    if cam.work is not None:
        meta["work"] = cam.work
    return image, depth, alpha, meta
