"""Rendering a trained dynamic scene: Gaussians deformed to a time, rasterized from a pose.

``Renderer`` is the one place that turns (model, deformation MLP, time, pose) into images; the
trainer, ``evsplat render``, ``evsplat eval`` and ``evsplat export`` all go through it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from evsplat.model.deform import DeformationMLP, deformed
from evsplat.model.gaussians import GaussianModel
from evsplat.model.motion import ObjectMotion
from evsplat.projection import viewmat
from evsplat.raster import PendingRaster, rasterize_async
from evsplat.run_state import RunState

ALPHA_EPS = 1e-4  # below this coverage, alpha-normalised extra channels are set to 0


@dataclass
class RenderOut:
    """One rendered view. ``extra`` holds alpha-normalised extra feature channels, if any."""

    image: torch.Tensor  # [H,W,C] linear intensity
    depth: torch.Tensor  # [H,W] expected camera z (0 where nothing is hit)
    alpha: torch.Tensor  # [H,W]
    meta: dict
    means: torch.Tensor  # [N,3] the deformed means that were rendered
    extra: torch.Tensor | None = None  # [H,W,E]

    def shares(self) -> torch.Tensor:
        """[H,W,E] the extra features composited (``extra`` before its alpha normalisation):
        with features of 1 on some Gaussians and 0 on the rest, the share of each pixel they
        cover."""
        if self.extra is None:
            raise ValueError("RenderOut.shares: rendered without extra features")
        return self.extra * self.alpha[..., None]


@dataclass
class PendingRender:
    """A render started by ``Renderer.render_async``; ``result()`` (once) waits for it."""

    raster: PendingRaster
    means: torch.Tensor  # [N,3] the deformed means being rendered
    channels: int  # colour channels; any after them are the extra features
    has_extra: bool

    def result(self) -> RenderOut:
        image, depth, alpha, meta = self.raster.result()
        c = self.channels
        out_extra = None
        if self.has_extra:
            cover = alpha.unsqueeze(-1)
            out_extra = torch.where(
                cover > ALPHA_EPS, image[..., c:] / cover.clamp(min=ALPHA_EPS), 0.0
            )
        return RenderOut(image[..., :c], depth, alpha, meta, self.means, out_extra)


@dataclass
class Renderer:
    """A dynamic Gaussian scene with its camera: renders at any time and pose."""

    model: GaussianModel
    mlp: DeformationMLP | None
    K: torch.Tensor  # [3,3] float32
    width: int
    height: int
    t_start_us: int
    t_end_us: int
    background: float = 0.5
    static_mask: torch.Tensor | None = None  # Gaussians that skip the MLP (classified static)
    motion: ObjectMotion | None = None  # the moving objects' rigid paths (``evsplat.motion``)
    object_id: torch.Tensor | None = None  # [N] long: each Gaussian's object, -1 the scene

    def time(self, t_us: float) -> float:
        """Normalised time in [0, 1] that the deformation MLP takes."""
        span = max(self.t_end_us - self.t_start_us, 1)
        return float(t_us - self.t_start_us) / span

    def gaussians_at(self, t_us: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Deformed (means, rotations, scales) at time ``t_us``."""
        moving = None if self.static_mask is None else ~self.static_mask
        return deformed(self.model, self.mlp, self.time(t_us), moving, self.motion, self.object_id)

    def opacities(self, t_us: float) -> torch.Tensor:
        """[N] opacities at ``t_us``: time-local ones, and objects only while in view."""
        opacity = self.model.opacities(self.time(t_us))
        if self.motion is None or self.object_id is None:
            return opacity
        return opacity * self.motion.visibility(self.object_id, self.time(t_us))

    def render(
        self,
        t_us: float,
        c2w: np.ndarray,
        extra: torch.Tensor | None = None,
        gaussians: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    ) -> RenderOut:
        """Render at time ``t_us`` from camera-to-world pose ``c2w``.

        ``extra`` ``[N,E]`` are additional per-Gaussian features rendered beside the colour;
        ``gaussians`` reuses an already deformed set (to share one MLP evaluation).
        """
        return self.render_async(t_us, c2w, extra, gaussians).result()

    def render_async(
        self,
        t_us: float,
        c2w: np.ndarray,
        extra: torch.Tensor | None = None,
        gaussians: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    ) -> PendingRender:
        """``render``, started on the device without waiting for it (``rasterize_async``):
        ``.result()`` gives its RenderOut. The trainer prepares its next render and reads its
        events while the device draws."""
        means, rotations, scales = gaussians if gaussians is not None else self.gaussians_at(t_us)
        w2c = viewmat(c2w, self.K.device)
        device = self.K.device
        centre = torch.from_numpy(np.asarray(c2w, np.float32)[:3, 3]).to(device)
        colors = self.model.colors(centre)
        channels = colors.shape[1]
        features = colors if extra is None else torch.cat([colors, extra], dim=1)
        background = torch.zeros(features.shape[1], device=device)
        background[:channels] = self.background
        raster = rasterize_async(
            means,
            rotations,
            scales,
            self.opacities(t_us),
            features,
            w2c,
            self.K,
            self.width,
            self.height,
            background=background,
        )
        return PendingRender(raster, means, channels, extra is not None)

    @classmethod
    def from_state(cls, state: RunState) -> Renderer:
        """The trained scene of a run's state, as its renders saw it at that iteration."""
        mlp = None
        if state.mlp_active:
            mlp = DeformationMLP(state.config.model)
            mlp.load_state_dict(state.mlp)
        cam, static, objects = state.camera, state.static_mask, state.objects
        return cls(
            model=GaussianModel.from_checkpoint(state.gaussians),
            mlp=mlp,
            K=torch.from_numpy(cam.K.astype(np.float32)),
            width=cam.width,
            height=cam.height,
            t_start_us=cam.t_start_us,
            t_end_us=cam.t_end_us,
            background=state.config.background,
            static_mask=None if static is None else torch.as_tensor(static, dtype=torch.bool),
            motion=None if objects is None else ObjectMotion.from_state(objects["motion"]),
            object_id=None if objects is None else torch.as_tensor(objects["object_id"]),
        )

    @classmethod
    def from_run(cls, run_dir: str | Path) -> tuple[Renderer, RunState]:
        """The renderer of a run folder's newest checkpoint (or of a checkpoint file), and
        that checkpoint's state."""
        state = RunState.load(run_dir)
        return cls.from_state(state), state
