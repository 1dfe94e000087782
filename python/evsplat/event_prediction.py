"""Scoring a run without ground-truth frames: how well it predicts events.

Over each window [t0, t1), the rendered log change (the log render at t1 minus at t0, in the
sensor's channels, as training's L_e compares: ``Views.log_image_at``) is set against the
window's event image (ESI: the events' polarities times the contrast thresholds, summed per
pixel). Two numbers per window: the Pearson correlation of the two images over the pixels
(scale-free: a model whose contrast is off by a factor still scores 1 if its pattern is right)
and L_e itself (``losses.event.event_loss``). The windows are the ones the run held out
(``train.heldout``: training never read them), else ``FALLBACK_WINDOWS`` fixed windows that
training did read.

Beside the model: the static model (the same Gaussians with the deformation MLP and the
objects' rigid motion off, each object held where it was placed, so only what training baked
into them moves) and a flat image, which predicts no change anywhere: its
correlation is 0 by construction (a prediction without any change is given correlation 0: it
has none to give), its L_e is the loss of predicting nothing."""

from __future__ import annotations

import numpy as np
import torch

from evsplat.data.dataset import Dataset
from evsplat.errors import EvsplatError
from evsplat.losses.event import event_loss
from evsplat.render import Renderer
from evsplat.train.views import Views

#: Without held-out windows: this many windows of ``FALLBACK_LENGTH`` of the sequence, evenly
#: spread (their centres at (k + 0.5) / FALLBACK_WINDOWS of it).
FALLBACK_WINDOWS = 16
FALLBACK_LENGTH = 0.02
MODELS = ("model", "static", "flat")


def pearson(a: np.ndarray, b: np.ndarray) -> float | None:
    """The Pearson correlation of two images over their pixels; None when either is constant
    (no correlation is defined)."""
    x = np.asarray(a, np.float64).ravel() - np.mean(a)
    y = np.asarray(b, np.float64).ravel() - np.mean(b)
    denom = float(np.sqrt((x @ x) * (y @ y)))
    return None if denom == 0.0 else float(x @ y) / denom


def fallback_windows(t_start_us: int, t_end_us: int) -> list[tuple[int, int]]:
    """``FALLBACK_WINDOWS`` evenly spread windows of ``FALLBACK_LENGTH`` of the sequence."""
    duration = t_end_us - t_start_us
    half = int(FALLBACK_LENGTH * duration) // 2
    centres = t_start_us + (np.arange(FALLBACK_WINDOWS) + 0.5) * duration / FALLBACK_WINDOWS
    return [(int(c) - half, int(c) + half) for c in centres]


@torch.no_grad()
def predict_events(
    renderer: Renderer, data: Dataset, heldout: list[tuple[int, int]], lambda_ssim: float
) -> dict:
    """Correlation and L_e per window and their means, for the model, the static model and a
    flat image, over the run's ``heldout`` windows (else the fallback windows, said so in
    ``windows_source``). Windows without events are listed but not scored."""
    views = Views.of(data, renderer)
    windows = [tuple(map(int, w)) for w in heldout] or fallback_windows(
        data.t_start_us, data.t_end_us
    )
    outside = [w for w in windows if not data.t_start_us <= w[0] < w[1] <= data.t_end_us]
    if outside:
        raise EvsplatError(
            f"{data.root}: the run's held-out window {outside[0]} µs lies outside the "
            f"dataset's time range [{data.t_start_us}, {data.t_end_us}] µs; evaluate on the "
            "dataset the run was trained on"
        )
    mlp, motion = renderer.mlp, renderer.motion
    rows = []
    for t0, t1 in windows:
        esi, mask, count = views.esi(t0, t1)
        row: dict = {"t0_us": t0, "t1_us": t1, "events": int(count)}
        for name in MODELS:
            if count == 0:
                row[name] = None
                continue
            if name == "flat":
                delta = torch.zeros_like(esi)
            else:
                renderer.mlp, renderer.motion = (mlp, motion) if name == "model" else (None, None)
                delta = views.log_image_at(t1) - views.log_image_at(t0)
            corr = pearson(delta.numpy(), esi.numpy())
            if corr is None and bool((delta == delta.flatten()[0]).all()):
                corr = 0.0  # no change predicted: no correlation, as for the flat image
            loss = float(event_loss(delta, esi, mask, lambda_ssim))
            row[name] = {"correlation": corr, "l_e": loss}
        rows.append(row)
    renderer.mlp, renderer.motion = mlp, motion
    return {
        "t_start_us": data.t_start_us,
        "windows_source": "held out (training never read them)"
        if heldout
        else f"the run held no windows out: {FALLBACK_WINDOWS} fixed windows of "
        f"{FALLBACK_LENGTH:g} of the sequence, which training did read",
        "windows": rows,
        "mean": {name: _means(rows, name) for name in MODELS},
        "flat_note": "a flat image predicts no change: correlation 0 by construction",
    }


def _means(rows: list[dict], name: str) -> dict:
    scored = [r[name] for r in rows if r[name] is not None]
    out = {"windows": len(scored)}
    for key in ("correlation", "l_e"):
        vals = [s[key] for s in scored if s[key] is not None]
        out[key] = float(np.mean(vals)) if vals else None
    return out


def format_event_table(result: dict) -> str:
    """Markdown: per window and mean, each model's correlation and L_e."""

    def cell(v: dict | None, key: str) -> str:
        return "-" if v is None or v[key] is None else f"{v[key]:.3f}"

    lines = [
        f"Event prediction over {len(result['windows'])} windows, {result['windows_source']}: "
        "Pearson correlation of the rendered log change with the window's events (ESI), and L_e.",
        "",
        "| window (µs from start) | events | corr model | corr static | corr flat "
        "| L_e model | L_e static | L_e flat |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["windows"]:
        where = f"{r['t0_us'] - result['t_start_us']}-{r['t1_us'] - result['t_start_us']}"
        corr = [cell(r[m], "correlation") for m in MODELS]
        loss = [cell(r[m], "l_e") for m in MODELS]
        lines.append(f"| {where} | {r['events']} | " + " | ".join(corr + loss) + " |")
    m = result["mean"]
    corr = [cell(m[k], "correlation") for k in MODELS]
    loss = [cell(m[k], "l_e") for k in MODELS]
    lines.append("| **mean** | | " + " | ".join(f"**{c}**" for c in corr + loss) + " |")
    lines += [
        "",
        f"Static model: the same Gaussians with the deformation MLP and the objects' motion off; "
        f"{result['flat_note']}.",
    ]
    return "\n".join(lines) + "\n"


def event_headline(result: dict) -> str:
    """One line: the mean correlation of the model, the static model and a flat image."""
    m = result["mean"]

    def corr(name: str) -> str:
        v = m[name]["correlation"]
        return "missing" if v is None else f"{v:.3f}"

    return (
        f"event prediction ({m['model']['windows']} windows, "
        f"{result['windows_source'].split(':')[0]}): correlation {corr('model')}, static model "
        f"{corr('static')}, flat image 0 (by construction)"
    )
