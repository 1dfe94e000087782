"""World-to-camera matrices and pinhole projection shared by training, rendering and evaluation
(OpenCV convention, +z forward). The camera's trajectory is evsplat.data.trajectory."""

from __future__ import annotations

import numpy as np
import torch


def world_to_camera(c2w: np.ndarray) -> np.ndarray:
    """Rigid inverse of camera-to-world poses ``[...,4,4]`` (float64), without a general inverse."""
    c2w = np.asarray(c2w, dtype=np.float64)
    r = c2w[..., :3, :3]
    t = c2w[..., :3, 3:]
    out = np.zeros_like(c2w)
    rt = np.swapaxes(r, -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3:] = -rt @ t
    out[..., 3, 3] = 1.0
    return out


def viewmat(c2w: np.ndarray, device: torch.device | None = None) -> torch.Tensor:
    """World-to-camera matrix as the float32 tensor the rasterizer takes (on ``device``, default
    the CPU)."""
    return torch.from_numpy(world_to_camera(c2w).astype(np.float32)).to(device)


def project_points(points: torch.Tensor, w2c: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Pixel coordinates ``[N,2]`` (x, y; pixel centres at +0.5) of world points ``[N,3]``.

    Depth is clamped to a small positive value so points behind the camera stay finite; callers
    that care filter them with the rasterizer's visibility.
    """
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2:3].clamp(min=1e-6)
    uv = cam[:, :2] / z
    return uv * torch.stack([K[0, 0], K[1, 1]]) + torch.stack([K[0, 2], K[1, 2]])


def back_project(uv: np.ndarray, depth: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """World points [T,3] at camera ``depth`` [T] (z) along the rays of pixel coordinates ``uv``
    [T,2] seen from ``c2w`` [T,4,4] (or one [4,4] for all): ``project_points``' inverse."""
    rays = np.stack(
        [(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))], 1
    )
    cam = rays * np.asarray(depth, dtype=np.float64).reshape(-1, 1)
    c2w = np.broadcast_to(c2w, (len(uv), 4, 4))
    return np.einsum("tij,tj->ti", c2w[:, :3, :3], cam) + c2w[:, :3, 3]


def project(points: np.ndarray, c2w: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixel coordinates [N,2], camera depths z [N]) of world points [N,3] seen from ``c2w``
    [4,4]: ``project_points`` in numpy. Points at z <= 0 get finite, meaningless pixels: callers
    test z."""
    cam = (np.asarray(points, dtype=np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    z = cam[:, 2]
    safe = np.where(z > 1e-9, z, 1.0)
    uv = cam[:, :2] / safe[:, None] * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    return uv, z
