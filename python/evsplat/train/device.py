"""Where training's tensors live: the one device setting (``TrainConfig.device``). Gaussians,
MLP, losses, both optimizers and the event windows sit on it; the rasterizer (wgpu, its own
adapter) and the numpy parts (seeding, evaluation, export) take tensors at their edges."""

from __future__ import annotations

import argparse

import torch

from evsplat.errors import EvsplatError

DEVICES = ("auto", "cpu", "cuda")


def training_device(name: str) -> torch.device:
    """The torch device that ``name`` (auto | cpu | cuda) trains on: ``auto`` takes CUDA when
    torch sees a GPU. On CUDA the MLP's matmuls run in TF32 where the GPU has it (Ampere and
    later; torch leaves it off by default)."""
    if name not in DEVICES:
        raise EvsplatError(f"device {name!r}: choose one of {', '.join(DEVICES)}")
    if name == "cuda" and not torch.cuda.is_available():
        fix = (
            "check the driver and CUDA_VISIBLE_DEVICES"
            if torch.version.cuda
            else ("install a CUDA build of torch")
        )
        raise EvsplatError(
            f"--device cuda: torch {torch.__version__} sees no CUDA GPU; pass --device cpu or "
            f"auto, or {fix}"
        )
    if name == "cpu" or not torch.cuda.is_available():
        return torch.device("cpu")
    torch.backends.cuda.matmul.allow_tf32 = True
    return torch.device("cuda")


def describe_device(name: str = "auto") -> str:
    """One line for `evsplat info`: the device ``name`` trains on, and why."""
    device = training_device(name)
    if device.type == "cpu":
        why = "torch sees no CUDA GPU" if name == "auto" else "asked for"
        return f"cpu ({why}; torch {torch.__version__})"
    major, minor = torch.cuda.get_device_capability(device)
    tf32 = "TF32 matmuls" if major >= 8 else "no TF32 (before Ampere)"
    gpu = torch.cuda.get_device_name(device)
    return f"cuda ({gpu}, compute {major}.{minor}, {tf32}; torch {torch.__version__})"


def add_device_argument(parser: argparse.ArgumentParser, default: str | None) -> None:
    """--device: where torch trains (shared with the training benchmarks)."""
    shown = default or "the config's (auto)"
    parser.add_argument(
        "--device",
        choices=DEVICES,
        default=default,
        help=f"where torch trains: auto (CUDA when torch sees a GPU), cpu or cuda; default {shown}",
    )
