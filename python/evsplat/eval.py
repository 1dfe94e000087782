"""`evsplat eval`: render the held-out intermediate test frames and score them (paper §5)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from evsplat.data.atomic import write_text_atomic
from evsplat.data.dataset import Dataset, load_dataset
from evsplat.data.images import read_png
from evsplat.intensity import LUMA
from evsplat.metrics import Lpips, fit_log_linear, psnr, ssim
from evsplat.render import Renderer


def to_sensor_channels(rgb: np.ndarray, channels: int) -> np.ndarray:
    """Ground truth in the model's channels: RGB as is, or the sensor's luma for mono."""
    if rgb.ndim == 2:
        rgb = rgb[..., None]
    if channels == rgb.shape[-1]:
        return rgb
    if channels == 1:
        return (rgb[..., :3] @ LUMA)[..., None]
    return np.repeat(rgb[..., :1], channels, axis=-1)


@torch.no_grad()
def render_test_frames(renderer: Renderer, data: Dataset) -> list[dict]:
    """Render every test frame at its time and ground-truth pose; returns arrays per frame."""
    frames = []
    for f in data.test_frames:
        out = renderer.render(f.time_us, f.c2w)
        frames.append(
            {
                "time_us": f.time_us,
                "render": out.image.clamp(min=0).numpy(),
                "depth": out.depth.numpy(),
                "gt": read_png(f.rgb_path),
                "mask": read_png(f.mask_path) > 0.5 if f.mask_path is not None else None,
            }
        )
    return frames


@torch.no_grad()
def evaluate(renderer: Renderer, data: Dataset) -> dict:
    """Per-frame and mean PSNR/SSIM/LPIPS after the log-space colour fit, plus PSNR on the
    moving-object mask where the dataset provides one."""
    lp = Lpips()
    rows = []
    for fr in render_test_frames(renderer, data):
        gt = to_sensor_channels(fr["gt"], fr["render"].shape[-1])
        fitted = fit_log_linear(fr["render"], gt)
        mask = fr["mask"]
        if mask is not None and mask.ndim == 3:
            mask = mask[..., 0]
        rows.append(
            {
                "time_us": int(fr["time_us"]),
                "psnr": psnr(fitted, gt),
                "ssim": ssim(fitted, gt),
                "lpips": lp(fitted, gt),
                "psnr_moving": psnr(fitted, gt, mask) if mask is not None and mask.any() else None,
            }
        )

    def mean(key: str) -> float | None:
        vals = [r[key] for r in rows if r[key] is not None]
        return float(np.mean(vals)) if vals else None

    return {
        "frames": rows,
        "mean": {k: mean(k) for k in ("psnr", "ssim", "lpips", "psnr_moving")},
        "lpips_missing": lp.missing,
        "protocol": "per-image per-channel linear colour fit in log space, metrics on [0,1]",
    }


def format_table(result: dict) -> str:
    """A Markdown table of the per-frame and mean metrics."""

    def f(v, nd=3):
        return "missing" if v is None else f"{v:.{nd}f}"

    lines = [
        "| time (µs) | PSNR | SSIM | LPIPS | PSNR moving |",
        "|---:|---:|---:|---:|---:|",
    ]
    for r in result["frames"]:
        lines.append(
            f"| {r['time_us']} | {f(r['psnr'], 2)} | {f(r['ssim'])} | {f(r['lpips'])} "
            f"| {f(r['psnr_moving'], 2)} |"
        )
    m = result["mean"]
    lines.append(
        f"| **mean** | **{f(m['psnr'], 2)}** | **{f(m['ssim'])}** | **{f(m['lpips'])}** "
        f"| **{f(m['psnr_moving'], 2)}** |"
    )
    if result["lpips_missing"]:
        lines.append(f"\nLPIPS missing: {result['lpips_missing']}.")
    return "\n".join(lines) + "\n"


def evaluate_run(run_dir: Path, data_dir: Path, out_dir: Path | None = None) -> dict:
    """Evaluate a run folder on a dataset folder; writes eval.json and eval.md atomically."""
    renderer, _ = Renderer.from_run(run_dir)
    data = load_dataset(data_dir)
    result = evaluate(renderer, data)
    out = Path(out_dir or run_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "eval.json", json.dumps(result, indent=2))
    write_text_atomic(out / "eval.md", format_table(result))
    return result
