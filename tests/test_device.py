"""The device setting (evsplat.train.device) and the device-dependent training paths, run on the
CPU: a few training steps with the events accumulated by torch (the path a CUDA run takes)
against the Rust core's."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch

from evsplat.config import SkipConfig, TrainConfig, load_config, preset
from evsplat.data.dataset import load_dataset
from evsplat.errors import EvsplatError
from evsplat.train.device import training_device
from evsplat.train.device_events import DeviceEvents
from evsplat.train.loop import Trainer
from evsplat.train.snapshot import restore, snapshot

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="torch sees a CUDA GPU here")


def test_auto_and_cpu_train_on_the_cpu_without_a_gpu_and_bad_names_are_one_line_errors():
    assert training_device("cpu") == torch.device("cpu")
    want = "cuda" if torch.cuda.is_available() else "cpu"
    assert training_device("auto").type == want
    with pytest.raises(EvsplatError, match="device 'gpu': choose one of auto, cpu, cuda"):
        training_device("gpu")


@no_cuda
def test_asking_for_cuda_without_a_gpu_is_a_one_line_error_and_writes_nothing(
    tiny_scene, tmp_path, capsys
):
    from evsplat.cli import main

    run = tmp_path / "run"
    assert main(["train", str(tiny_scene("ball")), "--out", str(run), "--device", "cuda"]) != 0
    err = capsys.readouterr().err.strip()
    assert "sees no CUDA GPU; pass --device cpu" in err and len(err.splitlines()) == 1
    assert not run.exists()
    with pytest.raises(EvsplatError, match="--device cuda: torch .* sees no CUDA GPU"):
        training_device("cuda")


def test_the_device_is_saved_with_the_config_and_older_configs_train_on_auto(tmp_path):
    cfg = preset("tiny")
    assert cfg.device == "auto"
    cfg.device = "cpu"
    assert TrainConfig.from_dict(cfg.to_dict()).device == "cpu"
    old = cfg.to_dict()
    del old["device"]
    path = tmp_path / "config.json"
    path.write_text(json.dumps(old))
    assert load_config(path).device == "auto"


def test_training_steps_on_torch_accumulated_events_equal_the_cores(tiny_scene, tmp_path):
    """Each step of every stage taken twice from the same state, its windows (L_e's, L_ef's,
    L_m's sub-windows) from the Rust core and from torch: every loss the same bit for bit
    (exact counts, the same rounding). Steps are compared from one state because training is
    not bit-reproducible across steps: the rasterizer's backward adds with float atomics."""
    cfg = preset("tiny")
    cfg.device = "cpu"
    cfg.num_gaussians = 300
    cfg.schedule.iterations = 12
    cfg.schedule.warmup_fraction = 0.25  # L_ef and L_m from iteration 3
    cfg.schedule.refine_fraction = 0.75  # L_ne and L_sp (and L_d) from 9
    cfg.skips = SkipConfig(static=False, early_stop=False)
    cfg.mover.enabled = False  # the seeding reads its windows through the same Views.esi
    trainer = Trainer(load_dataset(tiny_scene("ball")), cfg, tmp_path / "run")
    assert trainer.views.device_events is None  # a CPU run keeps the Rust path
    data = trainer.data
    on_device = DeviceEvents(data.events, data.c_pos, data.c_neg, "cpu")
    seen = set()
    for it in range(cfg.schedule.iterations):
        before = copy.deepcopy(snapshot(trainer, it))
        trainer.views.device_events = None
        host = trainer.step(it)
        restore(trainer, before, tmp_path)
        trainer.views.device_events = on_device
        device = trainer.step(it)
        assert host.skipped == device.skipped is None
        assert host.losses == device.losses, f"iteration {it}"
        seen |= set(host.losses)
    assert {"e", "ef", "m", "ne", "sp"} <= seen
    assert all(np.isfinite(v) for v in device.losses.values())
