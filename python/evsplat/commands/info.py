"""`evsplat info`: the GPU adapter in use, its limits, the device torch trains on, and package
versions."""

from __future__ import annotations

import argparse
import json
import platform

HELP = (
    "print the GPU adapter, its limits, float-atomic and subgroup support, the training device "
    "and package versions"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def versions() -> dict[str, str]:
    import numpy
    import torch

    from evsplat import __version__, _core

    return {
        "evsplat": __version__,
        "evsplat._core": _core.__version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "torch": torch.__version__,
    }


def run(args: argparse.Namespace) -> int:
    from evsplat.gpu import adapter_info
    from evsplat.train.device import describe_device

    info = {
        "adapter": adapter_info(),
        "training_device": describe_device("auto"),
        "versions": versions(),
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    a = info["adapter"]
    print(f"adapter      {a['name']} ({a['device_type']}, {a['backend']})")
    print(f"driver       {a['driver']} {a['driver_info']}".rstrip())
    print(f"f32 atomics  {'yes' if a['float32_atomics'] else 'no'} (using {a['atomic_mode']})")
    sums = "summed across subgroups" if a["subgroup_reduce"] else "one atomic per invocation"
    print(f"subgroups    {'yes' if a['subgroups'] else 'no'} (gradients {sums})")
    print(f"training     torch on {info['training_device']}")
    for key in (
        "max_storage_buffer_binding_size",
        "max_buffer_size",
        "max_compute_workgroup_storage_size",
        "max_compute_invocations_per_workgroup",
        "max_compute_workgroups_per_dimension",
    ):
        print(f"{key:<40} {a[key]}")
    for name, version in info["versions"].items():
        print(f"{name:<14} {version}")
    return 0
