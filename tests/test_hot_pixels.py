"""Hot pixels (evsplat.data.hot_pixels): found among a scene's edges, a colour mosaic and
background noise where they were put, and none elsewhere; their events left out of every window
training reads (evsplat.train.views.Views) and listed by `evsplat check`."""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from evsplat.cli import main
from evsplat.data.dataset import load_dataset
from evsplat.data.event_writer import write_events_h5
from evsplat.data.events import EventStream
from evsplat.data.hot_pixels import HOT_RATIO, hot_pixel_map, hot_pixels
from evsplat.train.views import Views


def _scene_counts(rng: np.random.Generator) -> np.ndarray:
    """[64,64] events per pixel of a scene with no hot pixel: background noise everywhere, a
    moving edge's band (each pixel crossed fires about as its neighbours do), and a colour edge
    that one channel of a Bayer mosaic sees (every other pixel of every other row)."""
    yy, xx = np.mgrid[:64, :64]
    counts = rng.poisson(2.0, (64, 64))
    band = np.abs(xx - 0.5 * yy - 10) < 3
    counts += np.where(band, rng.poisson(40.0, (64, 64)), 0)
    mosaic = (np.abs(yy - 40) < 3) & (xx % 2 == 0) & (yy % 2 == 0)
    counts += np.where(mosaic, rng.poisson(60.0, (64, 64)), 0)
    return counts


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_hot_pixels_put_in_a_scene_are_found_and_nothing_else(seed) -> None:
    """One hot pixel alone and two side by side (each other's busiest neighbour), on the
    background, on the moving edge's band and on the mosaic's edge: exactly those."""
    rng = np.random.default_rng(seed)
    counts = _scene_counts(rng)
    assert not hot_pixels(counts).any()
    put = [(5, 50), (20, 30), (20, 31), (30, 40), (40, 22)]  # (y, x); (30, 40) on the band
    for y, x in put:
        counts[y, x] += 1500
    found = set(zip(*np.nonzero(hot_pixels(counts))))
    assert found == set(put)


def test_a_few_noise_events_among_silent_pixels_are_not_a_hot_pixel() -> None:
    """Where no pixel near it fired, a pixel is hot only past ``HOT_RATIO`` events: one more
    than the silent neighbours' count keeps a pixel of a few noise events from counting."""
    counts = np.zeros((16, 16), np.int64)
    counts[8, 8] = int(HOT_RATIO)
    assert not hot_pixels(counts).any()
    counts[8, 8] += 1
    assert hot_pixels(counts)[8, 8]


def _with_hot_pixel(src: Path, dst: Path, at: tuple[int, int], rate_hz: float) -> int:
    """``src``'s dataset copied to ``dst`` with a hot pixel at ``at`` (x, y) firing at
    ``rate_hz`` (alternating polarity) over the whole recording; the events added."""
    shutil.copytree(src, dst)
    data = load_dataset(src)
    ev = data.events.events(0, data.events.count)
    n = int(rate_hz * (data.t_end_us - data.t_start_us) * 1e-6)
    t = np.linspace(data.t_start_us, data.t_end_us - 1, n).astype(np.int64)
    x = np.concatenate([ev.x, np.full(n, at[0])])
    y = np.concatenate([ev.y, np.full(n, at[1])])
    p = np.concatenate([ev.p, np.where(np.arange(n) % 2 == 0, 1, -1)])
    order = np.argsort(np.concatenate([ev.t, t]), kind="stable")
    tt = np.concatenate([ev.t, t])
    stream = EventStream.from_arrays(
        x[order], y[order], tt[order], p[order], data.width, data.height
    )
    (dst / "events.h5").unlink()
    write_events_h5(dst / "events.h5", stream)
    return n


def test_training_windows_leave_a_hot_pixels_events_out(tiny_scene, tmp_path) -> None:
    """On the still camera's scene with a 2 kHz hot pixel added: the pixel is the one found, a
    window's ESI and event mask are zero there and, elsewhere, the scene's own to the bit (its
    store's window without the added pixel), and `evsplat check` lists it."""
    src = tiny_scene("watch")
    at = (17, 61)
    _with_hot_pixel(src, tmp_path / "hot", at, 2000.0)
    clean, data = load_dataset(src), load_dataset(tmp_path / "hot")
    spans = [(data.t_start_us, data.t_end_us)]
    assert not hot_pixel_map(clean.events, spans).any()
    renderer = SimpleNamespace(K=torch.zeros(3, 3))
    views = Views.of(data, renderer)
    assert views.hot is not None and list(zip(*np.nonzero(views.hot.numpy()))) == [at[::-1]]
    t0, t1 = 100_000, 160_000
    esi, mask, _ = views.esi(t0, t1)
    want_esi, want_mask, _ = clean.events.accumulate(
        *clean.events.window(t0, t1), clean.c_pos, clean.c_neg
    )
    want_esi[at[1], at[0]], want_mask[at[1], at[0]] = 0.0, False
    np.testing.assert_array_equal(esi.numpy(), want_esi)
    np.testing.assert_array_equal(mask.numpy(), want_mask)
    assert Views.of(clean, renderer).hot is None


def test_check_lists_the_hot_pixels(tiny_scene, tmp_path, capsys) -> None:
    _with_hot_pixel(tiny_scene("watch"), tmp_path / "hot", (17, 61), 2000.0)
    assert main(["check", str(tmp_path / "hot")]) == 0
    out = capsys.readouterr().out
    assert "hot pixels: 1 at (x, y) (17, 61); training leaves their events out" in out
    assert main(["check", str(tiny_scene("watch"))]) == 0
    assert "hot pixels: none" in capsys.readouterr().out
