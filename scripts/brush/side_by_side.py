"""Brush's rasterizer next to evsplat's on the same Gaussians, image size and adapter.

Writes the scene of ``evsplat bench raster`` (its generator, camera and loss weights) to a
folder, then alternates, round by round, evsplat's timed calls (in this process, as
``bench raster`` times them) with a run of the Brush bench binary (``cargo build --release``
in this folder; see README.md), and compares the two images (and, converted to evsplat's
parameters, the gradients). With ``--reference`` the dense torch oracle of evsplat's tests
renders the scene twice, with evsplat's conventions and with Brush's (no 3-sigma cut, alpha
clamp 0.999), to say which part of the image difference the conventions explain;
``--reference-grads`` does the same for the gradients (small sizes only).

Run from the repository root with evsplat importable, e.g.::

    OMP_NUM_THREADS=1 PYTHONPATH=python python scripts/brush/side_by_side.py \\
        --brush $HOME/.cache/evsplat/target-brush/release/evsplat-brush-bench
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from evsplat.bench import raster as bench
from evsplat.gpu import adapter_info

SH_C0 = 0.2820948  # Brush's degree-0 SH constant: colour = SH_C0 * coefficient + 0.5


def write_scene(folder: Path, size: int, n: int) -> dict:
    """The benchmark scene (3 channels) and loss weights as Brush's binary reads them."""
    params, view, K = bench._scene(size, n, 3)
    means, quats, scales, opac, feats = params
    w_img, _w_depth, w_alpha = bench._weights(size, 3)
    assert torch.equal(view, torch.eye(4)) and float(K[0, 0]) == float(K[1, 1])
    assert float(K[0, 2]) == float(K[1, 2]) == size / 2
    folder.mkdir(parents=True, exist_ok=True)
    parts = [means, quats, scales, opac, feats, w_img, w_alpha]
    flat = np.concatenate([p.reshape(-1).numpy().astype("<f4") for p in parts])
    flat.tofile(folder / "scene.f32")
    meta = {"n": n, "size": size, "focal": float(K[0, 0])}
    (folder / "scene.json").write_text(json.dumps(meta))
    return meta


def run_brush(binary: Path, folder: Path, repeats: int) -> dict:
    out = subprocess.run(
        [str(binary), str(folder), str(repeats)], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def image_stats(a: np.ndarray, b: np.ndarray) -> dict:
    diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
    mse = float((diff**2).mean())
    psnr = math.inf if mse == 0 else -10 * math.log10(mse)
    return {
        "max": float(diff.max()),
        "mean": float(diff.mean()),
        "psnr": psnr,
        "pixels > 1e-3": float((diff.max(-1) > 1e-3).mean()) if diff.ndim == 3 else None,
    }


def brush_grads_as_evsplat(g: np.ndarray, params: list[torch.Tensor]) -> list[np.ndarray]:
    """Brush's gradients (means, quats, log scales | SH | opacity logits) in evsplat's
    parameters (means, quats, scales, opacities, colours) by the chain rule."""
    means, quats, scales, opac, feats = (p.numpy().astype(np.float64) for p in params)
    n = means.shape[0]
    t = g[: 10 * n].reshape(n, 10).astype(np.float64)
    sh = g[10 * n : 13 * n].reshape(n, 3).astype(np.float64)
    raw = g[13 * n : 14 * n].astype(np.float64)
    return [t[:, 0:3], t[:, 3:7], t[:, 7:10] / scales, raw / (opac * (1 - opac)), sh / SH_C0]


def grad_stats(ours: list, theirs: list[np.ndarray]) -> dict:
    """Per parameter: cosine similarity and relative L2 error |a - b| / |a| (a = ``ours``)."""
    out = {}
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colours"), ours, theirs):
        a = np.asarray(a, dtype=np.float64).reshape(-1)
        b = np.asarray(b, dtype=np.float64).reshape(-1)
        na, nb = np.linalg.norm(a), np.linalg.norm(b)
        out[name] = {
            "cosine": float(a @ b / max(na * nb, 1e-300)),
            "rel L2": float(np.linalg.norm(a - b) / max(na, 1e-300)),
        }
    return out


def reference_grads(size: int, n: int, brush_conventions: bool) -> list[np.ndarray]:
    """The dense oracle's gradients of the loss Brush's binary uses (no depth term), with
    evsplat's or Brush's conventions."""
    ref = bench._reference()
    params, view, K = bench._scene(size, n, 3)
    w_img, _w_depth, w_alpha = bench._weights(size, 3)
    leaves = [p.clone().requires_grad_(True) for p in params]
    rows = max(1, bench.REF_PAIRS // (size * n))
    saved = (ref.POWER_CUT, ref.ALPHA_MAX)
    try:
        if brush_conventions:
            ref.POWER_CUT, ref.ALPHA_MAX = -math.inf, 0.999
        for r0 in range(0, size, rows):
            r1 = min(size, r0 + rows)
            image, _depth, alpha, _ = ref.render(*leaves, view, K, size, size, rows=(r0, r1))
            loss = (image * w_img[r0:r1]).sum() + (alpha * w_alpha[r0:r1]).sum()
            loss.backward()
    finally:
        ref.POWER_CUT, ref.ALPHA_MAX = saved
    return [p.grad.numpy() for p in leaves]


def reference_images(size: int, n: int) -> dict[str, np.ndarray]:
    """The dense torch oracle's RGB and alpha with evsplat's and with Brush's conventions."""
    ref = bench._reference()
    if ref is None:
        raise SystemExit("--reference needs the source tree's tests/reference/raster_ref.py")
    params, view, K = bench._scene(size, n, 3)
    rows = max(1, bench.REF_PAIRS // (size * n))
    saved = (ref.POWER_CUT, ref.ALPHA_MAX)
    out = {}
    try:
        for name, cut, amax in (("evsplat", saved[0], saved[1]), ("brush", -math.inf, 0.999)):
            ref.POWER_CUT, ref.ALPHA_MAX = cut, amax
            rgb, alpha = [], []
            with torch.no_grad():
                for r0 in range(0, size, rows):
                    rr = (r0, min(size, r0 + rows))
                    image, _depth, a, _ = ref.render(*params, view, K, size, size, rows=rr)
                    rgb.append(image)
                    alpha.append(a)
            out[name] = torch.cat([torch.cat(rgb, 0), torch.cat(alpha, 0)[..., None]], -1).numpy()
    finally:
        ref.POWER_CUT, ref.ALPHA_MAX = saved
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--brush", type=Path, required=True, help="the evsplat-brush-bench binary")
    p.add_argument("--cases", default="256x20000,512x100000", help="SIZExGAUSSIANS, comma-sep.")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per side and round")
    p.add_argument("--rounds", type=int, default=2, help="rounds of evsplat then Brush")
    p.add_argument("--dir", type=Path, help="scene folder (default: a temporary one)")
    p.add_argument("--reference", default="256", help="sizes to render with the torch oracle")
    p.add_argument("--reference-grads", default="", help="sizes to differentiate with it")
    p.add_argument("--json", type=Path, help="write all samples and comparisons here")
    args = p.parse_args()

    info = adapter_info()
    print(f"evsplat adapter: {info['name']} ({info['device_type']}), atomics "
          f"{info['atomic_mode']}, torch threads {torch.get_num_threads()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")  # fmt: skip
    root = args.dir or Path(tempfile.mkdtemp(prefix="evsplat-brush-"))
    ref_sizes = {int(s) for s in args.reference.split(",") if s}
    ref_grad_sizes = {int(s) for s in args.reference_grads.split(",") if s}
    report = []
    for case in args.cases.split(","):
        size, n = (int(v) for v in case.lower().split("x"))
        folder = root / f"{size}x{n}"
        write_scene(folder, size, n)
        ev: dict[str, list[float]] = {}
        br: dict[str, list[float]] = {}
        brush_meta: dict = {}
        keep = folder / "evsplat.pt"
        for r in range(args.rounds):
            row = bench.measure(size, n, 3, ["float"], args.repeats, keep if r == 0 else None)
            for k in ("fwd", "fwd cpu", "fwd+bwd float", "fwd+bwd float cpu"):
                ev.setdefault(k.replace(" float", ""), []).extend(row[k])
            if "work" in row:
                brush_meta["evsplat work"] = row["work"]
            b = run_brush(args.brush, folder, args.repeats)
            for k in ("fwd", "fwd cpu", "fwd packed", "fwd packed cpu", "fwd+bwd", "fwd+bwd cpu"):
                br.setdefault(k, []).extend(b[k])
            brush_meta.update({k: b[k] for k in ("adapter", "visible", "tile_pairs")})
            print(f"  {size}^2/{n} round {r + 1}: evsplat fwd "
                  f"{1e3 * statistics.median(row['fwd']):.0f} ms, Brush fwd "
                  f"{1e3 * b['fwd median']:.0f} ms", flush=True)  # fmt: skip

        # Images: evsplat's [H, W, 3] and alpha against Brush's RGBA.
        kept = torch.load(keep)
        ours = torch.cat([kept["image"], kept["alpha"][..., None]], -1).numpy()
        theirs = np.fromfile(folder / "brush_image.f32", dtype="<f4").reshape(size, size, 4)
        images = {"evsplat vs Brush": image_stats(ours, theirs)}
        if size in ref_sizes:
            refs = reference_images(size, n)
            images["evsplat vs oracle (evsplat conventions)"] = image_stats(ours, refs["evsplat"])
            images["Brush vs oracle (Brush conventions)"] = image_stats(theirs, refs["brush"])
            images["oracle: evsplat vs Brush conventions"] = image_stats(
                refs["evsplat"], refs["brush"]
            )
        # Gradients of sum(w_img rgb) + sum(w_alpha alpha) (no depth term, as Brush has none).
        params, view, K = bench._scene(size, n, 3)
        w_img, w_depth, w_alpha = bench._weights(size, 3)
        weights = (w_img, torch.zeros_like(w_depth), w_alpha)
        grads = bench._gpu_call(params, view, K, size, True, weights, atomics="float")[4]
        g_brush = np.fromfile(folder / "brush_grads.f32", dtype="<f4")
        g_theirs = brush_grads_as_evsplat(g_brush, params)
        gstats = {"evsplat vs Brush": grad_stats(grads, g_theirs)}
        if size in ref_grad_sizes:
            g_ref = reference_grads(size, n, False)
            g_ref_b = reference_grads(size, n, True)
            gstats["oracle vs evsplat (evsplat conventions)"] = grad_stats(g_ref, grads)
            gstats["oracle vs Brush (Brush conventions)"] = grad_stats(g_ref_b, g_theirs)
            gstats["oracle: evsplat vs Brush conventions"] = grad_stats(g_ref, g_ref_b)

        def med(v: list[float]) -> float:
            return statistics.median(v)

        entry = {
            "size": size,
            "n": n,
            "evsplat": ev,
            "brush": br,
            "brush meta": brush_meta,
            "images": images,
            "gradients": gstats,
            "ratios Brush/evsplat": {
                k: med(br[k]) / med(ev[k]) for k in ("fwd", "fwd cpu", "fwd+bwd", "fwd+bwd cpu")
            },
        }
        report.append(entry)
        print(f"\n{size}x{size}, {n:,} Gaussians, D=3 (Brush: {brush_meta['adapter']}, "
              f"visible {brush_meta['visible']:,}, 16x16 tile pairs "
              f"{brush_meta['tile_pairs']:,}; evsplat 8x8 tile pairs "
              f"{brush_meta.get('evsplat work', {}).get('pairs', 'n/a')})")  # fmt: skip
        print("| timed | evsplat wall | Brush wall | Brush / evsplat | evsplat CPU | Brush CPU "
              "| Brush / evsplat |\n|---|---|---|---|---|---|---|")  # fmt: skip
        for k, bk in (("fwd", "fwd"), ("fwd", "fwd packed"), ("fwd+bwd", "fwd+bwd")):
            ew, ec = med(ev[k]), med(ev[k + " cpu"])
            bw, bc = med(br[bk]), med(br[bk + " cpu"])
            print(f"| {bk} | {1e3 * ew:.0f} | {1e3 * bw:.0f} | {bw / ew:.2f}x | {1e3 * ec:.0f} "
                  f"| {1e3 * bc:.0f} | {bc / ec:.2f}x |")  # fmt: skip
        for name, s in images.items():
            print(f"image {name}: max |diff| {s['max']:.2e}, mean {s['mean']:.2e}, "
                  f"PSNR {s['psnr']:.1f} dB, pixels > 1e-3: {s['pixels > 1e-3']:.4f}")  # fmt: skip
        for name, per in gstats.items():
            cells = ", ".join(f"{k} {s['cosine']:.6f} / {s['rel L2']:.1e}" for k, s in per.items())
            print(f"gradients {name} (cosine / relative L2): {cells}")
        print(flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
