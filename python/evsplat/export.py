"""`evsplat export`: the Gaussians deformed to one time, as a standard 3DGS PLY file.

Fields follow the original 3DGS layout that common viewers read: x y z, nx ny nz (zeros),
f_dc_0..2, f_rest_* (channel-major), opacity (logit), scale_0..2 (log), rot_0..3 (w x y z).
A monochrome model is written with its one channel in all three colour slots.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from evsplat.data.atomic import write_atomic
from evsplat.model.gaussians import SH_C0
from evsplat.render import Renderer


def gaussian_arrays(renderer: Renderer, t_us: float) -> dict[str, np.ndarray]:
    """Means, log-scales, unit quaternions, opacity logits and SH [N,K,3] at ``t_us``."""
    with torch.no_grad():
        means, rotations, scales = renderer.gaussians_at(t_us)
        sh = renderer.model.sh.detach().clone()
        # Viewers draw max(SH + 0.5, 0); the band-0 term written is the one whose colour that
        # gives is evsplat's (exact for degree 0, the default; higher bands as they are).
        sh[:, 0] = (renderer.model.colors() - 0.5) / SH_C0
        if sh.shape[-1] == 1:
            sh = sh.expand(-1, -1, 3)
        opacity = renderer.opacities(t_us).clamp(1e-6, 1 - 1e-6)
        return {
            "means": means.numpy().astype(np.float32),
            "log_scales": torch.log(scales).numpy().astype(np.float32),
            "quats": rotations.numpy().astype(np.float32),
            "opacity_logits": torch.logit(opacity).numpy().astype(np.float32),
            "sh": sh.numpy().astype(np.float32),
        }


def write_ply(path: Path, g: dict[str, np.ndarray]) -> None:
    """Write a binary little-endian 3DGS PLY atomically."""
    n, k, _ = g["sh"].shape
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    rest = g["sh"][:, 1:, :].transpose(0, 2, 1).reshape(n, -1)
    columns = [
        g["means"],
        np.zeros((n, 3), np.float32),
        g["sh"][:, 0, :],
        rest,
        g["opacity_logits"][:, None],
        g["log_scales"],
        g["quats"],
    ]
    table = np.concatenate(columns, axis=1).astype("<f4")
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {n}\n"
    header += "".join(f"property float {name}\n" for name in names)
    header += "end_header\n"
    payload = header.encode("ascii") + np.ascontiguousarray(table).tobytes()
    write_atomic(path, lambda tmp: tmp.write_bytes(payload))


def export_ply(run_dir: Path, t_us: float, out: Path) -> int:
    """Export a run's Gaussians at ``t_us``; returns the number of Gaussians written."""
    renderer, _ = Renderer.from_run(run_dir)
    g = gaussian_arrays(renderer, t_us)
    write_ply(Path(out), g)
    return int(g["means"].shape[0])
