"""One cell of a sweep: (dataset path, resolved training config, seed) and the key that names
its result, so that a rerun finds what is already done."""

from __future__ import annotations

import functools
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from evsplat import __version__


@dataclass(frozen=True)
class Cell:
    """A training run to make and score. ``config`` is a resolved ``TrainConfig.to_dict()``
    (its own seed is replaced by ``seed``); ``train_args`` are extra `evsplat train` options
    (e.g. ``("--depth-prior", "none")``). ``labels`` (a bench's case and variant) are copied
    into the result row but are not part of the key: two labels for one config share a run."""

    scene: str
    data: Path
    config: dict
    seed: int = 0
    train_args: tuple[str, ...] = ()
    labels: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def config_hash(self) -> str:
        settings = {k: v for k, v in self.config.items() if k != "seed"}
        text = json.dumps({"config": settings, "train_args": list(self.train_args)}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:10]

    def key(self, code: str) -> str:
        """The cell's folder name: scene, config hash, seed and code version (``code``)."""
        scene = re.sub(r"[^A-Za-z0-9._-]+", "_", self.scene).strip("._") or "scene"
        code_hash = hashlib.sha256(code.encode()).hexdigest()[:8]
        return f"{scene}-{self.config_hash}-s{self.seed}-{code_hash}"

    def to_dict(self) -> dict:
        return {
            "scene": self.scene,
            "data": str(self.data),
            "config": {**self.config, "seed": self.seed},
            "seed": self.seed,
            "train_args": list(self.train_args),
            "config_hash": self.config_hash,
        }


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<package version>+<hash of the package's sources and native module>``: a changed line
    of Python, a rebuilt ``_core`` or another release makes every cell's key new."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    files = sorted(p for p in root.rglob("*") if p.suffix in (".py", ".so", ".pyd", ".wgsl"))
    for p in files:
        if "__pycache__" in p.parts:
            continue
        digest.update(p.relative_to(root).as_posix().encode() + b"\0")
        digest.update(p.read_bytes())
    return f"{__version__}+{digest.hexdigest()[:12]}"
