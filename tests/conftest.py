"""Shared pytest set-up: the GPU adapter is required (lavapipe in CI), never skipped."""

import os
from collections.abc import Callable
from pathlib import Path

import pytest

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
os.environ.setdefault("EVSPLAT_QUIET", "1")


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory) -> Callable[[str], Path]:
    """``tiny_scene(name)``: the dataset folder of the built-in scene's tiny variant (seed 0),
    simulated once per test session. Tests read it and write their runs elsewhere."""
    from evsplat.data.simulator import simulate_dataset

    made: dict[str, Path] = {}

    def get(name: str) -> Path:
        if name not in made:
            root = tmp_path_factory.mktemp("tiny") / name
            simulate_dataset(name, root, tiny=True, seed=0, progress=False)
            made[name] = root
        return made[name]

    return get
