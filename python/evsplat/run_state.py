"""The state of a training run, which is also its checkpoint.

``RunState.save`` is the one writer and ``RunState.load`` the one reader: training resumes from
it, and rendering, evaluation, the viewer and the CLI read the trained scene from it. The file
mechanics (atomic write, pruning, ``latest``, damaged files) are ``evsplat.checkpoint``'s;
older layouts are upgraded here, one version at a time.

No random generator state is kept: every iteration seeds its generators from (seed,
iteration), so a resumed run makes the choices of an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from evsplat.checkpoint import Upgrades, load_checkpoint, run_checkpoint, save_checkpoint
from evsplat.config import TrainConfig
from evsplat.data.trajectory import Trajectory
from evsplat.errors import EvsplatError
from evsplat.model.gaussians import clamped_to_softplus

# 2: the MLP saved once, with whether renders use it; counters beside the history; ``poses``.
# 3: colour through a softplus (``model.gaussians.color_activation``), not a clamp at 0.
# 4: the moving objects' rigid paths and each Gaussian's object (``model.motion``); ``heldout``,
#    the event intervals training never read.
VERSION = 4


@dataclass
class Camera:
    """The sensor and the recording's time span: all a render needs besides the scene."""

    K: np.ndarray  # [3,3] float64 intrinsics
    width: int
    height: int
    t_start_us: int
    t_end_us: int
    channels: int  # 1 for a mono sensor, 3 for a colour (Bayer) one
    bayer: str  # the dataset's Bayer pattern ("mono" for none)

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, np.float64)  # version 1 saved it as nested lists


@dataclass
class Poses:
    """The measured camera poses: renders along the training trajectory need no dataset."""

    times_us: np.ndarray  # [P] int64
    c2w: np.ndarray  # [P,4,4] camera-to-world

    def trajectory(self) -> Trajectory:
        """The camera at any time between the poses (``data.trajectory``)."""
        return Trajectory.fit(np.asarray(self.times_us), np.asarray(self.c2w))


@dataclass
class RunState:
    """A run after ``iteration`` completed iterations: enough to resume it or to render it.
    The stage follows from ``iteration`` and ``config.schedule`` (``train.stages.stage_at``)."""

    iteration: int
    config: TrainConfig
    camera: Camera
    poses: Poses
    dataset: str  # the dataset folder training read (for the events of videos and the viewer)
    gaussians: dict[str, Any]  # GaussianModel.state_for_checkpoint
    mlp: dict[str, torch.Tensor]  # DeformationMLP.state_dict, kept while renders skip it too
    mlp_active: bool  # renders use the MLP: after the warm-up, unless the scene is static
    optimizer: dict[str, Any]  # Adam on the Gaussians
    mlp_optimizer: dict[str, Any]  # Adam on the MLP
    densifier: dict[str, torch.Tensor]  # Densifier.state_dict: its gradient statistics
    static_mask: torch.Tensor | None  # [N] bool: skip the MLP; None before any classification
    static_scene: bool  # the static classification found the whole scene static
    # The moving objects, once found: {"motion": ObjectMotion.state(), "object_id": [N] long}
    objects: dict[str, Any] | None
    early_stop: dict[str, Any]  # Plateau.state_dict: the held-out loss's best and patience
    skipped_nonfinite: int = 0  # steps without an update: a non-finite loss or gradient
    skipped_empty: int = 0  # steps without an update: no events in the windows
    seconds: float = 0.0  # training time so far
    history: list[dict] = field(default_factory=list)  # the loss log's lines (log.jsonl)
    # [t0, t1) µs event intervals training never read (``train.heldout``): `evsplat eval`
    # scores the model's prediction of their events.
    heldout: list[tuple[int, int]] = field(default_factory=list)

    def save(self, run_dir: Path, keep: int) -> Path:
        """Write as the run's checkpoint of ``iteration``, atomically; keep the newest ``keep``."""
        payload = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        payload |= {
            "config": self.config.to_dict(),
            "camera": dataclasses.asdict(self.camera),
            "poses": dataclasses.asdict(self.poses),
        }
        return save_checkpoint(run_dir, self.iteration, payload, VERSION, keep)

    @classmethod
    def load(cls, path: str | Path) -> RunState:
        """A checkpoint file, or the newest checkpoint of a run folder."""
        path = run_checkpoint(Path(path))
        payload = load_checkpoint(path, VERSION, UPGRADES)
        names = [f.name for f in dataclasses.fields(cls)]
        missing = [n for n in names if n not in payload]
        if missing:
            raise EvsplatError(f"{path}: checkpoint lacks {', '.join(missing)}; retrain")
        values = {n: payload[n] for n in names}
        try:
            values |= {
                "config": TrainConfig.from_dict(payload["config"]),
                "camera": Camera(**payload["camera"]),
                "poses": Poses(**payload["poses"]),
            }
        except (KeyError, TypeError) as e:  # a config or camera of another layout
            raise EvsplatError(
                f"{path}: checkpoint's settings do not load ({type(e).__name__}: {e}); retrain"
            ) from None
        return cls(**values)


def _v1_to_v2(v1: dict[str, Any]) -> dict[str, Any]:
    """Version 1 saved the MLP twice (``mlp_full``, and ``mlp`` as None while renders did not
    use it), the counters under ``stats`` and the poses as ``trajectory``; entries added during
    version 1 may be missing (they take what training without them did)."""
    renamed = {"mlp", "mlp_full", "stats", "trajectory"}
    stats = v1["stats"]
    fresh_plateau = {"best": float("inf"), "since_best": 0, "stopped_at": None}
    return {k: v for k, v in v1.items() if k not in renamed} | {
        "mlp": v1["mlp_full"],
        "mlp_active": v1["mlp"] is not None,
        "poses": v1["trajectory"],
        "static_mask": v1.get("static_mask"),
        "static_scene": bool(v1.get("static_scene", False)),
        "mover_track": v1.get("mover_track"),
        "early_stop": v1.get("early_stop", fresh_plateau),
        "skipped_nonfinite": stats["skipped_nonfinite"],
        "skipped_empty": stats["skipped_empty"],
        "seconds": stats["seconds"],
    }


def _v2_to_v3(v2: dict[str, Any]) -> dict[str, Any]:
    """Version 2's colours were max(SH + 0.5, 0): band 0 is rewritten to give the same colours
    through the softplus (exact for degree 0, the default; higher bands are kept as they are)."""
    sh = torch.as_tensor(v2["gaussians"]["sh"]).clone()
    sh[:, 0] = clamped_to_softplus(sh[:, 0])
    return v2 | {"gaussians": v2["gaussians"] | {"sh": sh}}


def _v3_to_v4(v3: dict[str, Any]) -> dict[str, Any]:
    """Version 3 kept one mover's track prior (its motion lived in the MLP, which still loads);
    version 4 keeps the objects' rigid paths. Version 3 runs held no event windows out."""
    return {k: v for k, v in v3.items() if k != "mover_track"} | {"objects": None, "heldout": []}


UPGRADES: Upgrades = {1: _v1_to_v2, 2: _v2_to_v3, 3: _v3_to_v4}
