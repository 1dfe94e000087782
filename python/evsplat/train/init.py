"""The Gaussians training starts from, and the scene's scale (no point cloud: events carry no
RGB or SfM points, so the camera's frusta are the only geometric prior)."""

from __future__ import annotations

import numpy as np
import torch

from evsplat.config import TrainConfig
from evsplat.data.dataset import Dataset
from evsplat.model.gaussians import GaussianModel
from evsplat.projection import back_project


def _init_points(data: Dataset, n: int, rng: np.random.Generator, depth_range: tuple[float, float]):
    """Random points in the volume the trajectory sees: random time, pixel and inverse depth.

    Event data carries no RGB or SfM points, so the frusta are the only geometric prior.
    Returns (points [n,3], depths [n]) — depth sets each Gaussian's initial size.
    """
    times = rng.uniform(data.trajectory.t_min_us, data.trajectory.t_max_us, size=n)
    c2w = data.trajectory.pose(times)
    px = np.stack([rng.uniform(0, data.width, n), rng.uniform(0, data.height, n)], axis=1)
    near, far = depth_range
    depth = 1.0 / rng.uniform(1.0 / far, 1.0 / near, size=n)
    return back_project(px, depth, c2w, data.K), depth


def scene_extent(data: Dataset, depth_range: tuple[float, float]) -> float:
    """Radius used to scale learning rates and densification (3DGS: camera spread x 1.1),
    never below the far depth so a nearly static camera still gets a sensible scale."""
    times = np.linspace(data.trajectory.t_min_us, data.trajectory.t_max_us, 64)
    centres = data.trajectory.pose(times)[:, :3, 3]
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) * 1.1
    return max(spread, depth_range[1])


def initial_gaussians(
    data: Dataset, cfg: TrainConfig, channels: int, depth_range: tuple[float, float]
) -> GaussianModel:
    """``cfg.num_gaussians`` random Gaussians in the volume the trajectory sees, each about two
    pixels wide where it was sampled (visible, but no initial blur); time-local when the
    config asks for it."""
    rng = np.random.default_rng(cfg.seed)
    points, depth = _init_points(data, cfg.num_gaussians, rng, depth_range)
    lo, hi = points.min(0), points.max(0)
    model = GaussianModel.random_init(
        cfg.num_gaussians, channels, lo, hi, sh_degree=cfg.model.sh_degree, seed=cfg.seed
    )
    model.temporal = cfg.deform and cfg.model.temporal_opacity
    if model.temporal:
        model.start_time_local(*cfg.model.init_time_local, seed=cfg.seed)
    focal = float(data.K[0, 0])
    with torch.no_grad():
        model.means.copy_(torch.from_numpy(points.astype(np.float32)))
        size = np.log(np.maximum(2.0 * depth / focal, 1e-6)).astype(np.float32)
        model.log_scales.copy_(torch.from_numpy(size)[:, None].expand(-1, 3))
    return model
