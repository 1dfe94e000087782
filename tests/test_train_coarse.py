"""Coarse-to-fine: 2x2 event binning against a per-pixel loop, the half-resolution camera
against projection geometry, and coarse training steps end to end."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsplat.config import SkipConfig, preset
from evsplat.data.dataset import load_dataset
from evsplat.data.events import bayer_channel_map
from evsplat.data.simulator import simulate_dataset
from evsplat.model.gaussians import GaussianModel
from evsplat.render import Renderer
from evsplat.train.coarse import bin_events, coarse_due, half_renderer
from evsplat.train.loop import Trainer
from evsplat.train.stages import stage_at


def loop_binning(esi: np.ndarray, mask: np.ndarray, cmap: np.ndarray | None):
    """The oracle: one 2x2 block at a time, one pixel at a time."""
    h, w = esi.shape[0] // 2, esi.shape[1] // 2
    out = np.zeros((h, w) if cmap is None else (3, h, w))
    has = np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            pix = [(2 * i + a, 2 * j + b) for a in (0, 1) for b in (0, 1)]
            has[i, j] = any(mask[p] for p in pix)
            if cmap is None:
                out[i, j] = np.mean([esi[p] for p in pix])
                continue
            for c in range(3):
                vals = [esi[p] for p in pix if cmap[p] == c]
                out[c, i, j] = np.mean(vals)
    return out, has


@pytest.mark.parametrize("pattern", ["mono", "RGGB", "GBRG"])
def test_binning_matches_a_per_pixel_loop_and_drops_odd_edges(pattern):
    rng = np.random.default_rng(1)
    h, w = 9, 12  # odd height: the last row has no block
    esi = rng.normal(size=(h, w)).astype(np.float32)
    mask = rng.random((h, w)) < 0.3
    cmap = None if pattern == "mono" else bayer_channel_map(pattern, w, h).astype(np.int64)
    got, has = bin_events(
        torch.from_numpy(esi),
        torch.from_numpy(mask),
        None if cmap is None else torch.from_numpy(cmap),
    )
    want, want_has = loop_binning(esi, mask, cmap)
    assert got.shape == want.shape
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-6, atol=1e-6)
    assert np.array_equal(has.numpy(), want_has)


def test_half_renderer_puts_a_gaussian_at_half_its_pixel_position():
    model = GaussianModel(1, 1)
    with torch.no_grad():
        model.means.copy_(torch.tensor([[0.3, -0.2, 4.0]]))
        model.log_scales.fill_(np.log(0.08))
        model.opacity_logits.fill_(4.0)
        model.sh.fill_(2.0)
    K = torch.tensor([[90.0, 0, 40.0], [0, 90.0, 32.0], [0, 0, 1]])
    full = Renderer(model, None, K, 80, 64, 0, 1, background=0.0)
    half = half_renderer(full)
    assert (half.width, half.height) == (40, 32)
    pose = np.eye(4)

    def centroid(r: Renderer) -> np.ndarray:
        a = r.render(0, pose).alpha.detach().numpy()
        ys, xs = np.mgrid[: a.shape[0], : a.shape[1]] + 0.5
        return np.array([(a * xs).sum(), (a * ys).sum()]) / a.sum()

    # Projection: u = fx x / z + cx = 90*0.3/4 + 40 = 46.75, v = 90*(-0.2)/4 + 32 = 27.5.
    np.testing.assert_allclose(centroid(full), [46.75, 27.5], atol=0.05)
    np.testing.assert_allclose(centroid(half), [46.75 / 2, 27.5 / 2], atol=0.05)


def test_coarse_iterations_are_the_configured_fraction_outside_refinement():
    cfg = preset("tiny")
    cfg.skips.coarse_fraction = 0.8
    due = [coarse_due(cfg, i, stage_at(i, cfg.schedule)) for i in range(cfg.schedule.iterations)]
    # 0.8 of the run, cut at the refinement start (2/3 of the run).
    assert sum(due) == cfg.schedule.refine_start and not any(due[cfg.schedule.refine_start :])
    cfg.skips.coarse_fraction = 0.0
    assert not any(coarse_due(cfg, i, stage_at(i, cfg.schedule)) for i in range(100))


@pytest.mark.parametrize("color", [True, False])
def test_coarse_steps_train_every_loss_at_half_resolution(tmp_path, color):
    data_dir = tmp_path / "ball"
    simulate_dataset("ball", data_dir, tiny=True, seed=0, color=color, progress=False)
    data = load_dataset(data_dir)
    cfg = preset("tiny")
    cfg.num_gaussians = 300
    cfg.schedule.iterations = 12
    cfg.schedule.warmup_fraction = 0.25  # motion losses (L_ef, L_m) from iteration 3
    cfg.schedule.refine_fraction = 0.99
    cfg.skips = SkipConfig(static=False, early_stop=False, coarse_fraction=1.0)
    trainer = Trainer(data, cfg, tmp_path / "run")
    before = trainer.model.sh.detach().clone()
    seen = set()
    for it in range(cfg.schedule.iterations):
        r = trainer.step(it)
        assert r.skipped is None and all(np.isfinite(v) for v in r.losses.values())
        seen |= set(r.losses)
    assert {"e", "ef", "m"} <= seen
    assert not torch.equal(before, trainer.model.sh.detach())
