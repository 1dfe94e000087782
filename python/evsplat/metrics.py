"""Image metrics of the paper's protocol (§5): a per-image linear colour fit in log space, then
PSNR / SSIM / LPIPS in linear space on [0, 1].

Events carry no absolute brightness, so before comparing, each channel of a render is mapped
by ``log(y) = a·log(x) + b`` fitted by least squares to the ground truth (as EventNeRF does).
Fitted to a stack of images ``[N,H,W,C]`` the same function gives one fit per channel for the
whole sequence (EventNeRF's stricter protocol, which then compares display-gamma images, see
``to_display``); fitted to a constant image it gives the best flat image, the floor any render
must beat. LPIPS needs network weights; they are used only when present locally, never
downloaded.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import torch

from evsplat.intensity import LOG_EPS
from evsplat.losses.ssim import ssim as ssim_torch

MSE_FLOOR = 1e-10  # PSNR of identical images is reported as 100 dB rather than infinity
DISPLAY_GAMMA = 2.2  # linear intensity -> display value x^(1/2.2), as EventNeRF compares


def fit_log_linear(pred: np.ndarray, gt: np.ndarray, eps: float = LOG_EPS) -> np.ndarray:
    """``pred`` ``[..., C]`` mapped per channel by the least-squares fit of log(gt) on log(pred)
    over all its pixels: ``[H,W,C]`` is one image, ``[N,H,W,C]`` a sequence fitted jointly.

    A constant channel (no variance to fit a slope to) gets slope 0 and the mean log level.
    """
    out = np.empty_like(pred, dtype=np.float64)
    for c in range(pred.shape[-1]):
        x = np.log(np.clip(pred[..., c], 0, None) + eps).ravel()
        y = np.log(np.clip(gt[..., c], 0, None) + eps).ravel()
        var = x.var()
        a = float(((x - x.mean()) * (y - y.mean())).mean() / var) if var > 1e-12 else 0.0
        b = float(y.mean() - a * x.mean())
        out[..., c] = (np.exp(a * x + b) - eps).reshape(pred.shape[:-1])
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def flat_fit(gt: np.ndarray, eps: float = LOG_EPS) -> np.ndarray:
    """The best flat grey image under the colour fit: a constant render through
    ``fit_log_linear`` is each channel's mean log level of ``gt`` (one image or a stack)."""
    return fit_log_linear(np.full(gt.shape, 0.5, np.float32), gt, eps)


def to_display(img: np.ndarray) -> np.ndarray:
    """Linear intensity in [0, 1] as display values ``x^(1/DISPLAY_GAMMA)``."""
    return np.clip(img, 0.0, 1.0) ** (1.0 / DISPLAY_GAMMA)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB for images in [0, 1]; ``mask`` ``[H,W]`` restricts it to some pixels."""
    err = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    if mask is not None:
        if not mask.any():
            return float("nan")
        err = err[mask]
    return float(10.0 * np.log10(1.0 / max(float(err.mean()), MSE_FLOOR)))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of two ``[H,W,C]`` images in [0, 1] (11x11 Gaussian window, sigma 1.5)."""
    ta = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))
    tb = torch.from_numpy(np.ascontiguousarray(b.transpose(2, 0, 1), dtype=np.float32))
    return float(ssim_torch(ta, tb, data_range=1.0))


class Lpips:
    """LPIPS (AlexNet) when the ``lpips`` package and all its weights are on this machine."""

    def __init__(self) -> None:
        self.missing = _lpips_missing()
        self.net = None
        if self.missing is None:
            import lpips

            self.net = lpips.LPIPS(net="alex", verbose=False).eval()

    @torch.no_grad()
    def __call__(self, a: np.ndarray, b: np.ndarray) -> float | None:
        if self.net is None:
            return None

        def prep(x: np.ndarray) -> torch.Tensor:
            t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).permute(2, 0, 1)
            if t.shape[0] == 1:
                t = t.expand(3, -1, -1)
            return t[None] * 2 - 1

        return float(self.net(prep(a), prep(b)))


def _lpips_missing() -> str | None:
    """None when LPIPS can run offline, else the reason it is reported missing."""
    if importlib.util.find_spec("lpips") is None:
        return "lpips package not installed"
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    if not any(hub.glob("alexnet-*.pth")):
        return f"AlexNet weights not in {hub} (never downloaded at run time)"
    return None
