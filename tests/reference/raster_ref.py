"""Dense pure-torch Gaussian splatting: the oracle for evsplat.rasterize (values and gradients).

Written from the maths, not from the shaders: every Gaussian is projected in torch (EWA with the
0.3 px low-pass, near/far culling, gsplat's guard band on the Jacobian, 3-sigma radius), evaluated
at every pixel, and composited front to back in depth order with 3DGS's rules (skip beyond 3 sigma
and alpha < 1/255, clamp alpha at 0.99, stop before transmittance drops below 1e-4). O(N*H*W)
memory and time; pass float64 tensors for a float64 reference. Autograd gives the gradients.
"""

from __future__ import annotations

import math

import torch

# The renderer's tile side (TILE in shaders/splat_common.wgsl): a Gaussian is visible when its
# 3-sigma square reaches a tile of the image, whose tiles may extend past its right and bottom edge.
TILE = 8
LOW_PASS = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
POWER_CUT = -4.5
MAX_VAR_PX = 1e12
QUAT_EPS2 = 1e-12
ALPHA_EPS = 1e-6


def quat_to_rot(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] of unit quaternions (w, x, y, z)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def project(
    means, quats, scales, opacities, viewmat, K, width: int, height: int, near: float, far: float
):
    """Per-Gaussian 2-D mean, conic (a, b, c), camera z, radius and visibility. A Gaussian
    fainter than ALPHA_MIN is not visible: no fragment of it could pass the alpha test."""
    rot_w, t_w = viewmat[:3, :3], viewmat[:3, 3]
    p = means @ rot_w.T + t_w
    z = p[:, 2]
    in_range = (z >= near) & (z <= far)
    zs = torch.where(in_range, z, torch.ones_like(z))  # keeps culled rows finite
    qn = quats / torch.sqrt(torch.clamp((quats * quats).sum(-1, keepdim=True), min=QUAT_EPS2))
    rot = quat_to_rot(qn)
    m = rot * scales[:, None, :]
    cov_cam = rot_w @ (m @ m.transpose(1, 2)) @ rot_w.T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    xz, yz = p[:, 0] / zs, p[:, 1] / zs
    u = torch.clamp(xz, min=-(cx / fx + 0.3 * tan_x), max=(width - cx) / fx + 0.3 * tan_x)
    v = torch.clamp(yz, min=-(cy / fy + 0.3 * tan_y), max=(height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(zs)
    jac = torch.stack(
        [
            torch.stack([fx / zs, zero, -fx * u / zs], -1),
            torch.stack([zero, fy / zs, -fy * v / zs], -1),
        ],
        -2,
    )
    cov2d = jac @ cov_cam @ jac.transpose(1, 2)
    a = cov2d[:, 0, 0] + LOW_PASS
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + LOW_PASS
    ok = in_range & (opacities.detach() >= ALPHA_MIN) & (a <= MAX_VAR_PX) & (c <= MAX_VAR_PX)
    det = a * c - b * b
    ok = ok & (det > 0)
    det_s = torch.where(ok, det, torch.ones_like(det))
    conic = torch.stack([c / det_s, -b / det_s, a / det_s], -1)
    mean2d = torch.stack([fx * xz + cx, fy * yz + cy], -1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
        radius = torch.ceil(3 * torch.sqrt(torch.clamp(lam, min=0)))
        tx, ty = math.ceil(width / TILE), math.ceil(height / TILE)
        mx, my = mean2d[:, 0], mean2d[:, 1]
        x0 = torch.clamp(torch.floor((mx - radius) / TILE), 0, tx)
        x1 = torch.clamp(torch.floor((mx + radius) / TILE) + 1, 0, tx)
        y0 = torch.clamp(torch.floor((my - radius) / TILE), 0, ty)
        y1 = torch.clamp(torch.floor((my + radius) / TILE) + 1, 0, ty)
        ok = ok & (x1 > x0) & (y1 > y0)
    radius = torch.where(ok, radius, torch.zeros_like(radius))
    return mean2d, conic, z, radius, ok


def render(
    means,
    quats,
    scales,
    opacities,
    features,
    viewmat,
    K,
    width: int,
    height: int,
    near: float = 0.01,
    far: float = 1e4,
    background=None,
    rows: tuple[int, int] | None = None,
):
    """(image [h, W, D], depth [h, W], alpha [h, W], meta) for pixel rows `rows` (default all)."""
    r0, r1 = rows if rows is not None else (0, height)
    dtype = means.dtype
    mean2d, conic, z, radius, ok = project(
        means, quats, scales, opacities, viewmat, K, width, height, near, far
    )
    d = features.shape[1]
    bg = torch.zeros(d, dtype=dtype) if background is None else background.to(dtype)
    order = torch.argsort(torch.where(ok, z, torch.full_like(z, math.inf)).detach(), stable=True)
    order = order[ok[order]]
    jj, ii = torch.meshgrid(
        torch.arange(width, dtype=dtype), torch.arange(r0, r1, dtype=dtype), indexing="xy"
    )
    pix = torch.stack([jj.reshape(-1) + 0.5, ii.reshape(-1) + 0.5], -1)  # [P, 2]
    npix = pix.shape[0]
    if order.numel() == 0:
        img = bg.expand(npix, d).clone()
        zeros = torch.zeros(npix, dtype=dtype)
        t_final = torch.ones(npix, dtype=dtype)
        wz = zeros
    else:
        dd = mean2d[order][None] - pix[:, None]  # [P, n, 2]
        co = conic[order]
        power = (
            -0.5 * (co[:, 0] * dd[..., 0] ** 2 + co[:, 2] * dd[..., 1] ** 2)
            - co[:, 1] * dd[..., 0] * dd[..., 1]
        )
        raw = opacities[order][None] * torch.exp(torch.clamp(power, max=0.0))
        alpha = torch.clamp(raw, max=ALPHA_MAX)
        use = (power >= POWER_CUT) & (alpha >= ALPHA_MIN)
        alpha = torch.where(use, alpha, torch.zeros_like(alpha))
        one_minus = 1 - alpha
        t_after = torch.cumprod(one_minus, dim=1)
        # Transmittance only decreases, so the fragments kept before the stop form a prefix.
        keep = (t_after >= T_MIN).detach()
        t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], 1)
        w = torch.where(keep, alpha * t_before, torch.zeros_like(alpha))
        t_final = torch.where(keep, one_minus, torch.ones_like(one_minus)).prod(1)
        img = w @ features[order] + t_final[:, None] * bg
        wz = w @ z[order]
    a = 1 - t_final
    depth = torch.where(a > ALPHA_EPS, wz / torch.clamp(a, min=ALPHA_EPS), torch.zeros_like(a))
    h = r1 - r0
    meta = {"means2d": mean2d, "depths": z, "radii": radius, "visible": ok}
    return img.reshape(h, width, d), depth.reshape(h, width), a.reshape(h, width), meta
