"""Depth priors for the refinement stage's SiLog loss (paper §4.4).

A prior takes the time and the current render and returns a depth map, or None when it has
nothing for that time. Implementations:

* ``PrecomputedDepthPrior``: depth files ``<time_us>.npy`` or ``.exr`` in a folder (any source).
* ``OracleDepthPrior``: for the built-in synthetic scenes only — ground-truth depth corrupted with
  an unknown scale, shift and noise. Results that use it are labelled "oracle depth prior".
* ``VggtDepthPrior``: runs VGGT on the render when the ``vggt`` package and its weights are
  present locally (``EVSPLAT_VGGT_WEIGHTS``); nothing is ever downloaded.

No prior means no depth stage and no depth work.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from evsplat.errors import EvsplatError


class DepthPrior(Protocol):
    name: str

    def depth(self, t_us: int, render: torch.Tensor) -> torch.Tensor | None:
        """Depth ``[H,W]`` at ``t_us`` (0 = unknown), given the current render ``[H,W,C]``."""


class PrecomputedDepthPrior:
    """Depth maps stored as ``<time_us>.npy`` or ``<time_us>.exr``; the nearest time is used
    when it lies within ``tolerance_us``."""

    name = "precomputed"

    def __init__(self, folder: Path, tolerance_us: int = 5_000):
        self.folder = Path(folder)
        files = sorted(
            p for p in self.folder.glob("*") if p.suffix in (".npy", ".exr") and p.stem.isdigit()
        )
        if not files:
            raise EvsplatError(
                f"{self.folder}: no depth files named <time_us>.npy or <time_us>.exr; "
                "write some or pass --depth-prior none"
            )
        self.times = np.array([int(p.stem) for p in files], dtype=np.int64)
        self.files = files
        self.tolerance_us = tolerance_us

    def depth(self, t_us: int, render: torch.Tensor) -> torch.Tensor | None:
        i = int(np.argmin(np.abs(self.times - t_us)))
        if abs(int(self.times[i]) - t_us) > self.tolerance_us:
            return None
        path = self.files[i]
        if path.suffix == ".npy":
            d = np.load(path)
        else:
            from evsplat.data.images import read_exr

            d = read_exr(path)
        if d.shape != render.shape[:2]:
            raise EvsplatError(
                f"{path}: depth is {d.shape[1]}x{d.shape[0]} but renders are "
                f"{render.shape[1]}x{render.shape[0]}; resize the depth files"
            )
        d = np.nan_to_num(d.astype(np.float32), nan=0.0, posinf=0.0)
        return torch.from_numpy(d).to(render.device)


class OracleDepthPrior:
    """Ground-truth depth of a built-in scene, corrupted by a fixed unknown affine map and noise.

    SiLog is invariant to depth scale, so the scale is harmless by design; the shift and the 2%
    multiplicative noise stand in for a monocular estimator's errors. Synthetic data only.
    """

    name = "oracle"

    def __init__(self, scene, seed: int = 0, noise: float = 0.02):
        self.scene = scene
        rng = np.random.default_rng(seed)
        self.scale = float(rng.uniform(0.5, 2.0))
        self.shift = float(rng.uniform(0.0, 0.1))
        self.noise = noise
        self.seed = seed

    def depth(self, t_us: int, render: torch.Tensor) -> torch.Tensor | None:
        _, gt, _ = self.scene.render(int(t_us))
        rng = np.random.default_rng([self.seed, int(t_us)])
        noisy = gt * (1.0 + self.noise * rng.standard_normal(gt.shape))
        d = np.where(gt > 0, self.scale * noisy + self.shift, 0.0)
        return torch.from_numpy(d.astype(np.float32)).to(render.device)


class VggtDepthPrior:
    """VGGT depth on the render, only when the package and local weights exist."""

    name = "vggt"

    def __init__(self, weights: Path):
        from vggt.models.vggt import VGGT

        self.model = VGGT()
        self.model.load_state_dict(torch.load(weights, map_location="cpu"))
        self.model.eval()

    @torch.no_grad()
    def depth(self, t_us: int, render: torch.Tensor) -> torch.Tensor | None:
        img = render.detach().clamp(0, 1).cpu()  # where the weights were loaded
        if img.shape[-1] == 1:
            img = img.expand(*img.shape[:2], 3)
        h, w = img.shape[:2]
        # VGGT takes 518-px-wide images whose sides are multiples of its 14-px patches.
        size = (max(14, round(h * 518 / w / 14) * 14), 518)
        x = torch.nn.functional.interpolate(
            img.permute(2, 0, 1)[None], size=size, mode="bilinear", align_corners=False
        )
        pred = self.model(x[None])["depth"].reshape(1, 1, *size)
        depth = torch.nn.functional.interpolate(pred, size=(h, w), mode="bilinear")[0, 0]
        return depth.to(render.device)


def vggt_status() -> str | None:
    """None when VGGT can run locally, else why not (a one-line message)."""
    if importlib.util.find_spec("vggt") is None:
        return "the vggt package is not installed"
    weights = os.environ.get("EVSPLAT_VGGT_WEIGHTS")
    if not weights or not Path(weights).is_file():
        return "EVSPLAT_VGGT_WEIGHTS does not name a local weights file (nothing is downloaded)"
    return None


def make_depth_prior(kind: str, dataset) -> DepthPrior | None:
    """Build the prior named by ``kind``: none | auto | oracle | vggt | a folder of depth files.

    ``auto`` takes ``<dataset>/depth_prior/`` if present, else VGGT if available, else the oracle
    for built-in synthetic scenes, else none.
    """
    if kind == "none":
        return None
    folder = Path(dataset.root) / "depth_prior"
    if kind == "auto":
        if folder.is_dir():
            return PrecomputedDepthPrior(folder)
        if vggt_status() is None:
            kind = "vggt"
        elif simulated_scene(dataset) is not None:
            kind = "oracle"
        else:
            return None
    if kind == "oracle":
        scene = simulated_scene(dataset)
        if scene is None:
            raise EvsplatError(
                f"{dataset.root}: the oracle depth prior needs a built-in synthetic scene "
                "(meta.json 'scene'); pass --depth-prior none or a folder of depth files"
            )
        return OracleDepthPrior(scene, seed=int(dataset.meta.get("seed", 0)))
    if kind == "vggt":
        why = vggt_status()
        if why is not None:
            raise EvsplatError(f"VGGT depth prior unavailable: {why}; pass --depth-prior none")
        return VggtDepthPrior(Path(os.environ["EVSPLAT_VGGT_WEIGHTS"]))
    if Path(kind).is_dir():
        return PrecomputedDepthPrior(Path(kind))
    raise EvsplatError(
        f"--depth-prior {kind!r}: expected none, auto, oracle, vggt or an existing folder"
    )


def simulated_scene(dataset):
    """The built-in scene a simulated dataset came from, or None for other data."""
    from evsplat.scenes import get_scene, is_scene

    meta = dataset.meta
    if meta.get("generator") != "evsplat simulate" or not is_scene(str(meta.get("scene"))):
        return None
    return get_scene(meta["scene"], size=(meta["width"], meta["height"]), tiny=meta["tiny"])
