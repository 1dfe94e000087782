"""Training that cannot be poisoned: non-finite steps are skipped and counted, parameters never
take a NaN, and a persistently broken loss stops training with a message naming it."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import evsplat.train.loop as loop
from evsplat.config import preset
from evsplat.data.dataset import load_dataset
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError
from evsplat.run_state import RunState
from evsplat.train.loop import Trainer


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("data") / "ball"
    simulate_dataset("ball", out, tiny=True, seed=1, progress=False)
    return out


def _trainer(data_dir: Path, run: Path, iters: int) -> Trainer:
    cfg = preset("tiny")
    cfg.schedule.iterations = iters
    cfg.schedule.checkpoint_every = 5
    return Trainer(load_dataset(data_dir), cfg, run)


def test_injected_nan_loss_is_skipped_counted_and_never_reaches_parameters(
    tiny_data, tmp_path, monkeypatch
):
    real = loop.event_loss
    calls = {"n": 0}

    def sometimes_nan(*args, **kwargs):
        calls["n"] += 1
        value = real(*args, **kwargs)
        return value * float("nan") if calls["n"] % 3 == 0 else value

    monkeypatch.setattr(loop, "event_loss", sometimes_nan)
    trainer = _trainer(tiny_data, tmp_path / "run", 12)
    stats = trainer.run(progress=False)
    assert stats.skipped_nonfinite == 4
    for p in trainer.model.parameters():
        assert torch.isfinite(p).all()


def test_persistent_nan_gradient_stops_with_the_term_and_keeps_the_last_good_checkpoint(
    tiny_data, tmp_path, monkeypatch
):
    real = loop.event_loss
    calls = {"n": 0}

    def nan_gradient_after_six(*args, **kwargs):
        calls["n"] += 1
        value = real(*args, **kwargs)
        if calls["n"] <= 6:
            return value
        # finite value, NaN gradient: sqrt at 0 has an infinite derivative times 0
        return value + 0.0 * torch.sqrt(args[0].sum() * 0.0)

    monkeypatch.setattr(loop, "event_loss", nan_gradient_after_six)
    run = tmp_path / "run"
    trainer = _trainer(tiny_data, run, 40)
    with pytest.raises(EvsplatError, match=r"non-finite gradient of .* in 20 steps") as e:
        trainer.run(progress=False)
    assert "\n" not in str(e.value)
    good = RunState.load(run)
    assert good.iteration == 5
    assert all(torch.isfinite(v).all() for v in good.gaussians.values() if torch.is_tensor(v))


def test_three_views_give_l_e_as_the_mean_over_their_three_windows(
    tiny_data, tmp_path, monkeypatch
):
    real = loop.event_loss
    seen: list[float] = []

    def recording(delta, esi, mask, lam):
        value = real(delta, esi, mask, lam)
        seen.append(float(value.detach()))
        return value

    monkeypatch.setattr(loop, "event_loss", recording)
    trainer = _trainer(tiny_data, tmp_path / "run", 10)
    trainer.cfg.loss.views = 3
    result = trainer.step(0)
    assert result.skipped is None
    assert len(seen) == 3  # windows (t0,t1), (t0,t2), (t1,t2)
    assert result.losses["e"] == pytest.approx(sum(seen) / 3, rel=1e-6)


def test_fewer_than_two_views_is_refused(tiny_data, tmp_path):
    cfg = preset("tiny")
    cfg.loss.views = 1
    with pytest.raises(EvsplatError, match="at least 2"):
        Trainer(load_dataset(tiny_data), cfg, tmp_path / "run")
