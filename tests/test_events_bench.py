"""`evsplat bench events` runs end to end on a small stream: it cross-checks the core against
its numpy baselines (asserting agreement) and prints every row of its table."""

from __future__ import annotations

import numpy as np

from evsplat.bench.events import esi_mask_add_at, esi_mask_bincount, patches_numpy
from evsplat.cli import main
from evsplat.data.events import EventStream


def test_bench_events_prints_core_and_numpy_rows(capsys):
    args = ["bench", "events", "--events=20000", "--width=64", "--height=48", "--repeat=1"]
    assert main([*args, "--centres=50", "--no-single-thread"]) == 0
    out = capsys.readouterr().out
    for impl in ("numpy np.add.at", "numpy np.bincount", "rust (one pass)", "numpy (vectorised)"):
        assert impl in out
    assert "x np.add.at" in out


def test_numpy_baselines_agree_with_each_other_and_the_core():
    rng = np.random.default_rng(3)
    n, w, h = 5000, 31, 17
    ev = EventStream.from_arrays(
        rng.integers(0, w, n), rng.integers(0, h, n), np.arange(n), rng.choice([-1, 1], n), w, h
    )
    a_esi, a_mask = esi_mask_add_at(ev.x, ev.y, ev.p, w, h)
    b_esi, b_mask = esi_mask_bincount(ev.x, ev.y, ev.p, w, h)
    np.testing.assert_allclose(a_esi, b_esi, atol=1e-4)
    np.testing.assert_array_equal(a_mask, b_mask)
    np.testing.assert_allclose(ev.esi(0, n, 0.2, 0.3), b_esi, atol=1e-4)
    centres = rng.uniform(-2, 33, (40, 2)).astype(np.float32)
    bounds = ev.split_equal_count(0, n, 3)
    want = patches_numpy(ev, centres, bounds, 5)
    np.testing.assert_allclose(ev.patches(centres, bounds, 5, 0.2, 0.3)[0], want, atol=1e-4)
