"""`evsplat eval`: render the held-out intermediate test frames and score them (paper §5).

Two colour-fit protocols, both next to the score a flat grey image reaches under the same fit
(events carry no absolute brightness, so the fit alone already earns a flat image some dB):
per image and channel in log space with metrics on linear [0, 1] (the paper's), and one fit per
channel for the whole sequence with metrics on display gamma (EventNeRF's stricter one). Where
the dataset gives each moving object's centre, ``evsplat.motion_metrics`` measures whether the
model's Gaussians follow it, and ``evsplat.eval_objects`` scores each object on its own mask.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from evsplat.data.atomic import write_text_atomic
from evsplat.data.dataset import Dataset, load_dataset
from evsplat.data.images import read_png
from evsplat.eval_objects import (
    evaluate_objects,
    frame_labels,
    mask2d,
    object_mask,
    object_table,
    unscored,
    worst_object_headline,
)
from evsplat.event_prediction import event_headline, format_event_table, predict_events
from evsplat.intensity import LUMA
from evsplat.metrics import DISPLAY_GAMMA, Lpips, fit_log_linear, flat_fit, psnr, ssim, to_display
from evsplat.motion_metrics import PERCENTILES
from evsplat.object_output import object_count, tinted
from evsplat.plots import plot_segmentation, plot_track, track_colour
from evsplat.render import Renderer

SCORE_KEYS = ("psnr", "psnr_flat", "ssim", "lpips", "psnr_moving", "psnr_moving_flat")
PER_IMAGE = "per-image per-channel linear colour fit in log space, metrics on linear [0,1]"
SEQUENCE = (
    "one per-channel linear colour fit in log space over all test frames jointly, "
    f"metrics on display values x^(1/{DISPLAY_GAMMA})"
)


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


def score(
    fitted: np.ndarray, flat: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, lp: Lpips
) -> dict:
    """PSNR/SSIM/LPIPS of a colour-fitted render, and the PSNR the flat image reaches, on the
    whole image and (where ``mask`` has pixels) on the moving object."""
    moving = mask is not None and bool(mask.any())
    return {
        "psnr": psnr(fitted, gt),
        "psnr_flat": psnr(flat, gt),
        "ssim": ssim(fitted, gt),
        "lpips": lp(fitted, gt),
        "psnr_moving": psnr(fitted, gt, mask) if moving else None,
        "psnr_moving_flat": psnr(flat, gt, mask) if moving else None,
    }


def summarise(rows: list[dict]) -> dict:
    """Means over frames (frames without a value left out) and the margins over the flat image."""

    def mean(key: str) -> float | None:
        vals = [r[key] for r in rows if r[key] is not None]
        return float(np.mean(vals)) if vals else None

    out = {k: mean(k) for k in SCORE_KEYS}
    for key in ("psnr", "psnr_moving"):
        flat = out[f"{key}_flat"]
        out[f"{key}_margin"] = None if out[key] is None or flat is None else out[key] - flat
    return out


@torch.no_grad()
def evaluate(renderer: Renderer, data: Dataset, labels: list[np.ndarray] | None = None) -> dict:
    """Scores under two colour-fit protocols (per image, as the paper; per sequence on display
    gamma, as EventNeRF's stricter one), each next to a flat grey image's, and per moving
    object its mask PSNR, tracking and segmentation (``evsplat.eval_objects``; ``labels``:
    ``frame_labels``, rendered there when not given) where the dataset gives its centre;
    ``tracking`` is the first object's, as with one tracked object."""
    lp = Lpips()
    frames = render_test_frames(renderer, data)
    renders, gts, masks = [], [], []
    for fr in frames:
        renders.append(fr["render"])
        gts.append(to_sensor_channels(fr["gt"], fr["render"].shape[-1]))
        masks.append(mask2d(fr["mask"]))
    fitted = [fit_log_linear(r, g) for r, g in zip(renders, gts)]
    flat = [flat_fit(g) for g in gts]
    rows = [
        {"time_us": int(fr["time_us"])} | score(f, fl, g, m, lp)
        for fr, f, fl, g, m in zip(frames, fitted, flat, gts, masks)
    ]
    seq_fit, seq_flat = fit_log_linear(np.stack(renders), np.stack(gts)), flat_fit(np.stack(gts))
    seq_rows = [
        {"time_us": row["time_us"]}
        | score(to_display(seq_fit[i]), to_display(seq_flat[i]), to_display(g), m, lp)
        for i, (row, g, m) in enumerate(zip(rows, gts, masks))
    ]
    depths = [fr["depth"] for fr in frames]
    objects, why = evaluate_objects(renderer, data, fitted, flat, gts, depths, labels)
    return {
        "frames": rows,
        "mean": summarise(rows),
        "protocol": PER_IMAGE,
        "sequence": {"frames": seq_rows, "mean": summarise(seq_rows), "protocol": SEQUENCE},
        "tracking": objects[0]["tracking"] if objects else None,
        "objects": objects,
        "tracking_missing": why,
        "lpips_missing": lp.missing,
    }


def _fmt(v: float | None, nd: int = 3, sign: bool = False) -> str:
    if v is None:
        return "missing"
    return f"{v:+.{nd}f}" if sign else f"{v:.{nd}f}"


def _score_table(rows: list[dict], mean: dict, extra: list[str] | None = None) -> list[str]:
    """Markdown rows: per frame and mean, PSNR beside the flat image's, SSIM, LPIPS; ``extra``
    adds one column (header first, then a cell per frame and one for the mean)."""
    head = "| time (µs) | PSNR | flat | SSIM | LPIPS | PSNR moving | flat |"
    lines = [head + (f" {extra[0]} |" if extra else ""), "|---:" * (7 + bool(extra)) + "|"]
    for i, r in enumerate([*rows, mean]):
        bold = "**" if r is mean else ""
        cells = [
            "mean" if r is mean else str(r["time_us"]),
            _fmt(r["psnr"], 2),
            _fmt(r["psnr_flat"], 2),
            _fmt(r["ssim"]),
            _fmt(r["lpips"]),
            _fmt(r["psnr_moving"], 2),
            _fmt(r["psnr_moving_flat"], 2),
            *([extra[i + 1]] if extra else []),
        ]
        lines.append("| " + " | ".join(f"{bold}{c}{bold}" for c in cells) + " |")
    return lines


def _margins(mean: dict) -> str:
    return (
        f"Over a flat grey image: whole image {_fmt(mean['psnr_margin'], 2, sign=True)} dB, "
        f"moving object {_fmt(mean['psnr_moving_margin'], 2, sign=True)} dB."
    )


def _region_fmt(p: dict) -> str:
    """A test time's region error: a number, out of view, or not drawn."""
    if p.get("not_drawn"):
        return "not drawn"
    return "out of view" if p["error_px"] is None else _fmt(p["error_px"], 2)


def _tracking_lines(tr: dict, what: str = "the moving object") -> list[str]:
    """The tracking of one object, ``what``, in words."""
    used = sum(1 for p in tr["paths"] if p["n"] > 0)
    if used == 0:
        return [f"Tracking {what}: no Gaussian draws it at any test frame."]
    region = tr["region"]

    def dist(d: dict) -> str:
        vals = "/".join(_fmt(d[f"p{q}"], 2) for q in PERCENTILES)
        return f"{vals} (n = {d['n']})"

    return [
        f"Tracking {what} (evsplat.motion_metrics): the region its {region['members']} "
        "Gaussians draw is off the true object's by a median "
        f"{_fmt(region['error_px_median'], 2)} px (track err; {region['in_view']} test "
        f"times with the object in view, {region['not_drawn']} of them not drawn).",
        "",
        f"Following the Gaussians ({used} of {len(tr['paths'])} test frames as reference): "
        "median error "
        f"{_fmt(tr['error_px_median'], 2)} px, mean {_fmt(tr['error_px_mean'], 2)} px over all "
        "(reference, other test time) pairs; carried by the set's rigid motion "
        f"(for a turning object): median error {_fmt(tr['rigid_error_px_median'], 2)} px; "
        f"path through the test times {_fmt(tr['pred_path_px'], 1)} px against the object's "
        f"{_fmt(tr['gt_path_px'], 1)} px, ratio {_fmt(tr['path_ratio'], 3)} "
        "(1 = moves with the object, 0 = stands still).",
        "",
        f"Largest displacement |Δx| from the time-mean (px, median/90th/99th percentile): "
        f"object Gaussians {dist(tr['dx_px']['object'])}, others {dist(tr['dx_px']['other'])}.",
    ]


def format_table(result: dict) -> str:
    """Markdown: both protocols' tables, the margins over a flat image, one row per moving
    object and its tracking (a per-frame column too for a single object); the event prediction
    (``evsplat.event_prediction``) where it was scored; only that for a dataset without test
    frames."""
    events = result.get("event_prediction")
    if "frames" not in result:
        return format_event_table(events)
    tail = "" if events is None else "\n" + format_event_table(events)
    return _frames_table(result) + tail


def _frames_table(result: dict) -> str:
    tr, objects = result.get("tracking"), result.get("objects") or []
    track_col = None
    if tr is not None and len(objects) == 1:
        region = tr["region"]
        track_col = ["track err (px)"] + [_region_fmt(p) for p in region["per_time"]]
        track_col.append(_fmt(region["error_px_median"], 2) + " (median)")
    seq = result["sequence"]
    lines = [
        f"Per-image fit (paper §5): {result['protocol']}.",
        "",
        *_score_table(result["frames"], result["mean"], track_col),
        "",
        _margins(result["mean"]),
        "",
        f"Sequence fit (EventNeRF, stricter): {seq['protocol']}.",
        "",
        *_score_table(seq["frames"], seq["mean"]),
        "",
        _margins(seq["mean"]),
        "",
    ]
    if objects:
        lines += ["Per moving object (per-image fit):", "", *object_table(objects), ""]
    for k, o in enumerate(objects):
        what = "the moving object" if len(objects) == 1 else f"'{o['name']}'"
        lines += ([""] if k else []) + _tracking_lines(o["tracking"], what)
    if not objects:
        lines.append(f"Tracking not reported: {result['tracking_missing']}.")
    if result["lpips_missing"]:
        lines += ["", f"LPIPS missing: {result['lpips_missing']}."]
    return "\n".join(lines) + "\n"


def headline(result: dict) -> str:
    """One line: the moving object's PSNR against the flat image's, the tracking error and the
    mask IoU with the object found for it (with several objects, the worst object's mask margin
    and each one's tracking and IoU); the event prediction where it was scored."""
    events = result.get("event_prediction")
    parts = [] if events is None else [event_headline(events)]
    if "frames" not in result:
        return parts[0]
    objects = result.get("objects") or []
    if len(objects) > 1:
        return "; ".join([*parts, worst_object_headline(objects)])
    m, tr = result["mean"], result.get("tracking")
    if m["psnr_moving"] is not None:
        parts.append(
            f"moving object: PSNR {m['psnr_moving']:.2f} dB vs {m['psnr_moving_flat']:.2f} dB "
            f"for a flat image ({m['psnr_moving_margin']:+.2f})"
        )
    if tr is not None and tr["error_px_median"] is not None:
        parts.append(
            f"tracking: object region off by {_fmt(tr['region']['error_px_median'], 1)} px "
            f"(its Gaussians followed: {tr['error_px_median']:.1f} px, rigid "
            f"{_fmt(tr['rigid_error_px_median'], 1)} px), path ratio "
            f"{_fmt(tr['path_ratio'], 2)} (1 = moves with the object)"
        )
    if objects:
        seg = objects[0]["segmentation"]
        found = "no object found for it" if seg["object"] is None else f"{seg['iou_mean']:.2f}"
        parts.append(f"mask IoU with the object found for it: {found}")
    return "; ".join(parts) or "no moving object in the test frames"


def write_track_plot(result: dict, data: Dataset, out: Path) -> bool:
    """Draw ``out`` (track.png): every moving object's predicted paths over its true one on
    the middle test frame's ground truth; False (nothing drawn) when tracking was not measured."""
    objects = result.get("objects") or []
    if not objects:
        return False
    middle = data.test_frames[len(data.test_frames) // 2]
    tracks = {t.name: t for t in data.tracks}
    plot_track(
        read_png(middle.rgb_path),
        middle.c2w,
        data.K,
        [(o["name"], o["tracking"], tracks.get(o["name"])) for o in objects],
        out,
        title=f"{data.meta.get('scene', data.root.name)}: object paths seen at "
        f"t = {middle.time_us / 1e6:.3f} s",
    )
    return True


def write_segmentation_plot(
    result: dict, renderer: Renderer, data: Dataset, labels: list[np.ndarray], out: Path
) -> bool:
    """Draw ``out`` (segmentation.png): at each test time, every true object's outline and the
    pixels of the found object matched to it (``eval_objects.segmentation``, from the same
    ``labels``) tinted in its colour, white where a found object is matched to none; False
    (nothing drawn) when the objects were not scored."""
    objects = result.get("objects") or []
    if not objects:
        return False
    matched = {o["segmentation"]["object"]: j for j, o in enumerate(objects)}
    found = [matched.get(k) for k in range(object_count(renderer))]
    colours = np.stack(
        [np.ones(3) if j is None else track_colour(j) for j in found] or [np.ones(3)]
    )
    frames = data.test_frames
    plot_segmentation(
        [
            tinted(np.clip(to_display(read_png(f.rgb_path)), 0, 1), drawn, colours)
            for f, drawn in zip(frames, labels)
        ],
        [f.time_us for f in frames],
        [[object_mask(f.objects[j]) for f in frames] for j in range(len(objects))],
        [o["segmentation"]["object"] for o in objects],
        [o["name"] for o in objects],
        out,
        title=f"{data.meta.get('scene', data.root.name)}: moving objects as segmented",
    )
    return True


def evaluate_run(run_dir: Path, data_dir: Path, out_dir: Path | None = None) -> dict:
    """Evaluate a run folder on a dataset folder; writes eval.json, eval.md and (with a
    tracked object) track.png and segmentation.png atomically. The test frames are scored where
    the dataset has them; the event prediction (``evsplat.event_prediction``) where the run held
    windows out or there are no test frames."""
    renderer, state = Renderer.from_run(run_dir)
    data = load_dataset(data_dir)
    # Once, for the IoU and the picture; neither is made where the objects are not scored.
    labels = frame_labels(renderer, data) if unscored(data) is None else []
    result = evaluate(renderer, data, labels) if data.test_frames else {}
    if state.heldout or not data.test_frames:
        lambda_ssim = state.config.loss.lambda_ssim
        result["event_prediction"] = predict_events(renderer, data, state.heldout, lambda_ssim)
    out = Path(out_dir or run_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "eval.json", json.dumps(result, indent=2))
    write_text_atomic(out / "eval.md", format_table(result))
    write_track_plot(result, data, out / "track.png")
    write_segmentation_plot(result, renderer, data, labels, out / "segmentation.png")
    return result
