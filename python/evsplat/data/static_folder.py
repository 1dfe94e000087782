"""A dataset folder around a converted recording from a camera that never moved
(``evsplat convert --static-camera``): meta.json says the camera is static (the dataset then
needs no poses.txt) and intrinsics.json holds the given pinhole intrinsics or a guess."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsplat.data.atomic import write_text_atomic
from evsplat.data.poses import CAMERA_KEY, STATIC_CAMERA
from evsplat.data.simulator import BAYER_PATTERNS
from evsplat.errors import EvsplatError
from evsplat.intensity import LOG_EPS

#: Without a focal length, one is guessed from this horizontal field of view: a common
#: small-sensor lens (a DAVIS346's 346 px then get fx = 225.5 px). A guess only: it sets the
#: scale of the model's depths, not what a static camera's renders look like.
GUESS_FOV_DEG = 75.0
#: Contrast threshold written when none is given: the simulator's default C (docs/dataset.md),
#: a guess for a real sensor, whose thresholds depend on its biases.
GUESS_CONTRAST = 0.2


@dataclass
class Lens:
    """What the command line gave of the intrinsics; missing values are derived or guessed."""

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None

    def matrix(self, width: int, height: int) -> tuple[np.ndarray, str | None]:
        """(K, a warning when the focal length was guessed)."""
        note = None
        fx = self.fx
        if fx is None:
            fx = width / 2 / math.tan(math.radians(GUESS_FOV_DEG) / 2)
            note = (
                f"no --fx: focal length GUESSED as {fx:.1f} px (a {GUESS_FOV_DEG:g}° horizontal "
                "field of view); depths are then in arbitrary units. Pass --fx/--fy/--cx/--cy "
                "from your calibration"
            )
        fy = self.fy if self.fy is not None else fx
        cx = self.cx if self.cx is not None else width / 2
        cy = self.cy if self.cy is not None else height / 2
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), note


def check_output(out: Path, lens: Lens, bayer: str, contrast: float | None) -> None:
    """Refuse, before converting, what would not make a dataset folder."""
    given = [v for v in (lens.fx, lens.fy, lens.cx, lens.cy) if v is not None]
    focal = [v for v in (lens.fx, lens.fy) if v is not None]
    if not all(math.isfinite(v) for v in given) or any(v <= 0 for v in focal):
        raise EvsplatError(
            f"--fx/--fy/--cx/--cy: must be finite, the focal lengths positive (pixels), got "
            f"{lens.fx}, {lens.fy}, {lens.cx}, {lens.cy}"
        )
    if out.name != "events.h5":
        raise EvsplatError(
            f"{out}: --static-camera writes a dataset folder around the events; name the "
            "output DIR/events.h5"
        )
    if bayer not in BAYER_PATTERNS:
        raise EvsplatError(f"--bayer {bayer!r}: choose one of {', '.join(BAYER_PATTERNS)}")
    if contrast is not None and not (math.isfinite(contrast) and contrast > 0):
        raise EvsplatError(f"--contrast {contrast}: must be a positive log-intensity step")


def write_static_folder(
    folder: Path,
    source: Path,
    size: tuple[int, int],
    span_us: tuple[int, int],
    lens: Lens,
    bayer: str,
    contrast: float | None,
) -> list[str]:
    """Write meta.json and intrinsics.json (atomically) into ``folder``, which holds the
    events of ``source`` (sensor ``size``, first and last event at ``span_us``); returns the
    warnings for what was guessed, one line each."""
    (width, height), (t0, t1) = size, span_us
    K, focal_note = lens.matrix(width, height)
    notes = [] if focal_note is None else [focal_note]
    if contrast is None:
        contrast = GUESS_CONTRAST
        notes.append(
            f"no --contrast: contrast threshold GUESSED as {contrast:g} (meta.json c_pos, c_neg); "
            "pass your sensor's"
        )
    meta = {
        "width": width,
        "height": height,
        "c_pos": contrast,
        "c_neg": contrast,
        "bayer": bayer,
        "t_start_us": int(t0),
        "t_end_us": int(t1),
        CAMERA_KEY: STATIC_CAMERA,
        "log_eps": LOG_EPS,
        "description": f"{source.name}, converted by `evsplat convert --static-camera`",
    }
    intrinsics = {"K": K.tolist(), "width": width, "height": height, "distortion": None}
    write_text_atomic(folder / "intrinsics.json", json.dumps(intrinsics, indent=1) + "\n")
    write_text_atomic(folder / "meta.json", json.dumps(meta, indent=1) + "\n")
    return notes
