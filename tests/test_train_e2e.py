"""Training end to end on the tiny built-in scene: train, evaluate, render, export, resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from evsplat.checkpoint import list_checkpoints
from evsplat.cli import main
from evsplat.config import preset
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError
from evsplat.eval import evaluate
from evsplat.export import export_ply, gaussian_arrays
from evsplat.raster import rasterize
from evsplat.render import Renderer
from evsplat.run_state import RunState
from evsplat.train import train

ITERS = 40


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("data") / "ball"
    simulate_dataset("ball", out, tiny=True, seed=0, progress=False)
    return out


@pytest.fixture(scope="module")
def tiny_run(tiny_data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "ball"
    train(tiny_data, out, preset_name="tiny", iterations=ITERS, progress=False)
    return out


def test_short_training_run_writes_a_complete_checkpoint_and_log(tiny_run):
    assert RunState.load(tiny_run).iteration == ITERS
    assert (tiny_run / "log.jsonl").is_file()
    assert json.loads((tiny_run / "config.json").read_text())["preset"] == "tiny"
    losses = [json.loads(line) for line in (tiny_run / "log.jsonl").read_text().splitlines()]
    assert all(np.isfinite(e["total"]) for e in losses if "total" in e)


def test_the_tiny_preset_trains_on_one_torch_thread_and_gives_the_callers_back(
    tiny_data, tmp_path, monkeypatch
):
    from evsplat.train.loop import Trainer

    seen = []
    run = Trainer.run

    def run_and_record(self, **kw):
        seen.append(torch.get_num_threads())
        return run(self, **kw)

    monkeypatch.setattr(Trainer, "run", run_and_record)
    callers = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        train(tiny_data, tmp_path / "run", preset_name="tiny", iterations=2, progress=False)
        assert seen == [1]
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(callers)


def test_eval_reports_finite_metrics_for_every_test_frame(tiny_run, tiny_data):
    from evsplat.data.dataset import load_dataset

    renderer, _ = Renderer.from_run(tiny_run)
    data = load_dataset(tiny_data)
    result = evaluate(renderer, data)
    assert len(result["frames"]) == len(data.test_frames) > 0
    assert np.isfinite(result["mean"]["psnr"]) and 0 < result["mean"]["ssim"] <= 1


def test_time_local_opacity_is_trained_checkpointed_and_exported_at_its_time(tiny_data, tmp_path):
    run = tmp_path / "run"
    args = ["train", str(tiny_data), "--out", str(run), "--preset", "tiny", "--iters", "8"]
    # No objects: their opacity outside the time they are in view is not this test's.
    off_objects = ["--set", "mover.enabled=false"]
    assert main([*args, *off_objects, "--temporal-opacity", "--no-progress"]) == 0
    renderer, _ = Renderer.from_run(run)
    model = renderer.model
    assert model.temporal and float(model.t_mean.detach().std()) > 0.1  # random centres in [0, 1]
    t_us = renderer.t_start_us + 0.25 * (renderer.t_end_us - renderer.t_start_us)
    opacity = torch.sigmoid(torch.tensor(gaussian_arrays(renderer, t_us)["opacity_logits"]))
    width = torch.exp(model.t_log_scale.detach())
    want = model.opacities().detach() * torch.exp(
        -0.5 * ((0.25 - model.t_mean.detach()) / width) ** 2
    )
    torch.testing.assert_close(opacity, want.clamp(1e-6, 1 - 1e-6), rtol=1e-4, atol=1e-6)
    # A static baseline never turns it on, whatever the model settings say.
    cfg = preset("tiny")
    cfg.model.temporal_opacity, cfg.deform, cfg.schedule.iterations = True, False, 8
    train(tiny_data, tmp_path / "static", config=cfg, progress=False)
    assert not Renderer.from_run(tmp_path / "static")[0].model.temporal
    # ... and by default it is off.
    off = tmp_path / "off"
    assert main([*args[:2], "--out", str(off), *args[4:], "--no-progress"]) == 0
    assert not Renderer.from_run(off)[0].model.temporal  # off by default


def test_exported_ply_has_standard_fields_and_renders_like_the_model(tiny_run, tmp_path):
    plyfile = pytest.importorskip("plyfile")
    renderer, _ = Renderer.from_run(tiny_run)
    t = 0.5 * (renderer.t_start_us + renderer.t_end_us)
    n = export_ply(tiny_run, t, tmp_path / "g.ply")
    v = plyfile.PlyData.read(str(tmp_path / "g.ply"))["vertex"]
    for name in ("x", "y", "z", "f_dc_0", "opacity", "scale_0", "rot_0"):
        assert name in v.data.dtype.names
    assert len(v.data) == n
    # Rebuild the Gaussians from the PLY fields alone and render them: must match the model.
    d = v.data
    means = torch.tensor(np.stack([d["x"], d["y"], d["z"]], 1))
    quats = torch.tensor(np.stack([d[f"rot_{i}"] for i in range(4)], 1))
    scales = torch.exp(torch.tensor(np.stack([d[f"scale_{i}"] for i in range(3)], 1)))
    opac = torch.sigmoid(torch.tensor(d["opacity"].copy()))
    c0 = 0.28209479177387814  # SH band-0 constant, as in 3DGS
    colors = torch.tensor(np.stack([d[f"f_dc_{i}"] for i in range(3)], 1)) * c0 + 0.5
    channels = renderer.model.colors().shape[1]
    c2w = np.eye(4)
    c2w[:3, 3] = renderer.model.means.detach().mean(0).numpy() - np.array([0, 0, 3.0])
    from evsplat.projection import viewmat

    with torch.no_grad():
        ref = renderer.render(t, c2w).image
        bg = torch.full((channels,), renderer.background)
        img = rasterize(
            means,
            quats,
            scales,
            opac,
            colors[:, :channels].clamp(min=0),
            viewmat(c2w),
            renderer.K,
            renderer.width,
            renderer.height,
            background=bg,
        )[0]
    np.testing.assert_allclose(img.numpy(), ref.clamp(min=0).numpy(), atol=1e-4)


def test_render_command_writes_frames_and_depth(tiny_run, tmp_path):
    assert main(["render", str(tiny_run), "--times", "0:1:0.5", "--out", str(tmp_path)]) == 0
    names = sorted(os.listdir(tmp_path))
    assert "frame_00000.png" in names and "depth_00002.exr" in names


def test_training_into_a_finished_run_without_resume_is_refused(tiny_run, tiny_data):
    with pytest.raises(EvsplatError, match="--resume"):
        train(tiny_data, tiny_run, preset_name="tiny", iterations=ITERS, progress=False)


def test_unknown_preset_is_a_one_line_cli_error(tiny_data, tmp_path, capsys):
    assert main(["train", str(tiny_data), "--out", str(tmp_path / "r"), "--preset", "huge"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown preset 'huge'" in err and "\n" not in err


def test_foreign_checkpoint_in_run_folder_is_a_one_line_error(tiny_data, tmp_path, capsys):
    run = tmp_path / "r"
    (run / "checkpoints").mkdir(parents=True)
    torch.save({"weights": 1}, run / "checkpoints" / "ckpt_0000010.pt")
    code = main(["train", str(tiny_data), "--out", str(run), "--resume", "--no-progress"])
    assert code == 2
    assert "not an evsplat checkpoint" in capsys.readouterr().err


def test_sigkill_mid_training_then_resume_matches_an_uninterrupted_run(tiny_data, tmp_path):
    iters = 60
    full = tmp_path / "full"
    train(tiny_data, full, preset_name="tiny", iterations=iters, progress=False)

    killed = tmp_path / "killed"
    cmd = [sys.executable, "-m", "evsplat.cli", "train", str(tiny_data), "--out", str(killed)]
    cmd += ["--preset", "tiny", "--iters", str(iters), "--checkpoint-every", "10", "--no-progress"]
    proc = subprocess.Popen(cmd)
    deadline = time.time() + 300
    while time.time() < deadline and not list_checkpoints(killed):
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = RunState.load(killed).iteration
    assert 0 < done < iters, "the kill should land mid-training"
    train(tiny_data, killed, preset_name="tiny", resume=True, progress=False)

    from evsplat.data.dataset import load_dataset

    data = load_dataset(tiny_data)
    a = evaluate(Renderer.from_run(full)[0], data)["mean"]["psnr"]
    b = evaluate(Renderer.from_run(killed)[0], data)["mean"]["psnr"]
    assert abs(a - b) <= 0.3, (a, b)
    g_full = gaussian_arrays(Renderer.from_run(full)[0], data.t_start_us)["means"]
    g_res = gaussian_arrays(Renderer.from_run(killed)[0], data.t_start_us)["means"]
    assert g_full.shape == g_res.shape
