"""Writes the fuzzers' seed corpus, crates/formats/fuzz/seeds/<encoding>/*.bin: valid event
words (no header) from evsplat.data.formats.prophesee_writer. Run from the repository root:
`python scripts/fuzz_seeds.py`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evsplat.data.formats.prophesee_writer import Encoder

SEEDS = Path(__file__).resolve().parent.parent / "crates/formats/fuzz/seeds"


def events(seed: int, n: int, t0: int, span: int, width: int = 1280, height: int = 720):
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, span, n))
    return rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n)


def main() -> None:
    cases = {
        "sparse": events(1, 200, 1_000_000, 2_000_000),  # new time words for most events
        "dense": events(2, 300, 5_000, 300),  # several events per µs and row
        "wrap": events(3, 200, (1 << 24) - 20_000, 60_000),  # EVT 3.0's 24-bit time wraps
    }
    for encoding in ("evt2", "evt3", "dat"):
        folder = SEEDS / encoding
        folder.mkdir(parents=True, exist_ok=True)
        for name, (x, y, t, p) in cases.items():
            (folder / f"{name}.bin").write_bytes(Encoder(encoding).encode(x, y, t, p))


if __name__ == "__main__":
    main()
