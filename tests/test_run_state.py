"""RunState is the checkpoint: a saved state loads back equal, versions 1 and 2 are upgraded,
unknown versions are refused in one line, and a trainer restored from a checkpoint is the trainer
that saved it (every iteration seeds its own generators, so it then continues identically)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from evsplat.config import preset
from evsplat.data.dataset import load_dataset
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError
from evsplat.model.deform import DeformationMLP
from evsplat.model.gaussians import GaussianModel, clamped_to_softplus
from evsplat.model.motion import ObjectMotion
from evsplat.render import Renderer
from evsplat.run_state import VERSION, Camera, Poses, RunState
from evsplat.train.loop import Trainer
from evsplat.train.snapshot import snapshot
from evsplat.train.stages import Stage


def _objects() -> dict:
    """Two objects' rigid paths over 3 knots and each of the 6 Gaussians' object."""
    motion = ObjectMotion(
        torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 3.0]]),
        torch.tensor([0.2, 0.3]),
        torch.linspace(0.0, 1.0, 18).reshape(2, 3, 3),
        torch.linspace(-0.5, 0.5, 18).reshape(2, 3, 3),
    )
    return {"motion": motion.state(), "object_id": torch.tensor([-1, 0, 0, 1, -1, 1])}


def _state(mlp_active: bool = True, objects: bool = False) -> RunState:
    """A small state with every field set (optimizer moments after one Adam step); with two
    objects' motion when ``objects``."""
    cfg = preset("tiny")
    cfg.model.mlp_width, cfg.model.mlp_depth, cfg.model.mlp_skip = 8, 3, 1
    torch.manual_seed(0)
    model, mlp = GaussianModel(6, 3), DeformationMLP(cfg.model)
    with torch.no_grad():
        model.means.normal_()
    optimizer = torch.optim.Adam(model.parameters())
    mlp_optimizer = torch.optim.Adam(mlp.parameters())
    loss = model.means.square().sum() + sum(p.square().sum() for p in mlp.parameters())
    loss.backward()
    optimizer.step()
    mlp_optimizer.step()
    return RunState(
        iteration=12,
        config=cfg,
        camera=Camera(np.diag([50.0, 50.0, 1.0]), 32, 24, 1_000, 91_000, 3, "RGGB"),
        poses=Poses(np.array([1_000, 91_000]), np.stack([np.eye(4), np.eye(4)])),
        dataset="/data/ball",
        gaussians=model.state_for_checkpoint(),
        mlp=mlp.state_dict(),
        mlp_active=mlp_active,
        optimizer=optimizer.state_dict(),
        mlp_optimizer=mlp_optimizer.state_dict(),
        densifier={"grad_accum": torch.rand(6), "denom": torch.ones(6), "max_radii": torch.ones(6)},
        static_mask=torch.tensor([True, False] * 3),
        static_scene=False,
        objects=_objects() if objects else None,
        early_stop={"best": 0.5, "since_best": 2, "stopped_at": None},
        skipped_nonfinite=1,
        skipped_empty=2,
        seconds=3.5,
        history=[{"iteration": 0, "stage": "warm-up", "e": 0.7}],
    )


def _assert_same(a: object, b: object, where: str = "state") -> None:
    """Equal values, tensors and arrays exactly, through dicts, lists and dataclasses."""
    if hasattr(a, "__dataclass_fields__"):
        assert type(a) is type(b), where
        for name in a.__dataclass_fields__:
            _assert_same(getattr(a, name), getattr(b, name), f"{where}.{name}")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            _assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b), where
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


def _as_version_2(s: RunState) -> dict:
    """``s`` as version 2 saved it (its fields at the top level)."""
    fields = {f: getattr(s, f) for f in s.__dataclass_fields__ if f != "objects"}
    return {
        "format": "evsplat-checkpoint",
        "version": 2,
        **fields,
        "mover_track": None,
        "config": s.config.to_dict(),
        "camera": vars(s.camera),
        "poses": vars(s.poses),
    }


def _clamp_colours_upgraded(s: RunState) -> RunState:
    """``s`` after the upgrade to version 3: its band-0 SH rewritten for the softplus."""
    sh = s.gaussians["sh"].clone()
    sh[:, 0] = clamped_to_softplus(sh[:, 0])
    return dataclasses.replace(s, gaussians=s.gaussians | {"sh": sh})


def _as_version_1(s: RunState) -> dict:
    """``s`` in the layout that version 1's ``Trainer.state`` wrote."""
    return {
        "format": "evsplat-checkpoint",
        "version": 1,
        "iteration": s.iteration,
        "config": s.config.to_dict(),
        "gaussians": s.gaussians,
        "mlp": s.mlp if s.mlp_active else None,
        "mlp_full": s.mlp,
        "optimizer": s.optimizer,
        "mlp_optimizer": s.mlp_optimizer,
        "densifier": s.densifier,
        "static_mask": s.static_mask,
        "static_scene": s.static_scene,
        "mover_track": None,  # version 1-3's one mover's track prior
        "early_stop": s.early_stop,
        "camera": {**vars(s.camera), "K": s.camera.K.tolist()},
        "trajectory": {"times_us": s.poses.times_us, "c2w": s.poses.c2w},
        "dataset": s.dataset,
        "stats": {
            "skipped_nonfinite": s.skipped_nonfinite,
            "skipped_empty": s.skipped_empty,
            "seconds": s.seconds,
        },
        "history": s.history,
    }


@pytest.mark.parametrize("objects", [False, True])
def test_run_state_saves_and_loads_back_equal(tmp_path, objects):
    state = _state(objects=objects)
    path = state.save(tmp_path, keep=2)
    assert path.name == "ckpt_0000012.pt" and VERSION == 4
    _assert_same(RunState.load(path), state)
    _assert_same(RunState.load(tmp_path), state)  # a run folder: its newest checkpoint


def test_a_run_with_objects_renders_them_where_their_paths_carry_them(tmp_path):
    state = _state(objects=True)
    state.save(tmp_path, keep=2)
    renderer = Renderer.from_state(RunState.load(tmp_path))
    motion = ObjectMotion.from_state(state.objects["motion"])
    ids = state.objects["object_id"]
    model = GaussianModel.from_checkpoint(state.gaussians)
    want = motion.apply(model.means, model.rotations(), ids, 0.25)[0]
    renderer.mlp = None
    got = renderer.gaussians_at(
        renderer.t_start_us + 0.25 * (renderer.t_end_us - renderer.t_start_us)
    )[0]
    assert torch.allclose(got, want) and not torch.allclose(got[ids >= 0], model.means[ids >= 0])
    assert torch.equal(got[ids < 0], model.means[ids < 0])


@pytest.mark.parametrize("mlp_active", [True, False])
def test_version_1_checkpoint_is_upgraded_to_the_same_state(tmp_path, mlp_active):
    state = _state(mlp_active)
    torch.save(_as_version_1(state), tmp_path / "v1.pt")
    loaded = RunState.load(tmp_path / "v1.pt")
    _assert_same(loaded, _clamp_colours_upgraded(state))
    assert (Renderer.from_state(loaded).mlp is None) is not mlp_active


def test_version_2_checkpoint_renders_the_colours_its_clamp_gave(tmp_path):
    # Version 2 drew max(C0 dc + 0.5, 0) (3DGS); upgraded, the softplus gives those colours.
    state = _state()
    dc = torch.linspace(-4.0, 4.0, 18, dtype=torch.float32).reshape(6, 3)
    state.gaussians["sh"][:, 0] = dc
    torch.save(_as_version_2(state), tmp_path / "v2.pt")
    loaded = RunState.load(tmp_path / "v2.pt")
    colours = GaussianModel.from_checkpoint(loaded.gaussians).colors().detach().numpy()
    clamp = np.maximum(0.28209479177387814 * dc.numpy() + 0.5, 0.0)
    np.testing.assert_allclose(colours, clamp, atol=2e-6)
    _assert_same(loaded, _clamp_colours_upgraded(state))


def test_version_1_checkpoint_from_before_the_skips_gets_their_starting_values(tmp_path):
    old = _as_version_1(_state())
    for key in ("static_mask", "static_scene", "mover_track", "early_stop"):
        del old[key]
    torch.save(old, tmp_path / "v1.pt")
    loaded = RunState.load(tmp_path / "v1.pt")
    assert loaded.static_mask is None and loaded.static_scene is False
    assert loaded.objects is None
    assert loaded.early_stop == {"best": math.inf, "since_best": 0, "stopped_at": None}


@pytest.mark.parametrize("version", [0, VERSION + 1])
def test_checkpoint_of_an_unknown_version_is_refused_in_one_line(tmp_path, version):
    path = _state().save(tmp_path, keep=2)
    payload = torch.load(path, weights_only=False)
    torch.save(payload | {"version": version}, path)
    with pytest.raises(EvsplatError, match=f"format version {version} but") as e:
        RunState.load(tmp_path)
    assert "\n" not in str(e.value) and path.name in str(e.value)


def test_checkpoint_without_a_field_is_a_one_line_error(tmp_path):
    path = _state().save(tmp_path, keep=2)
    payload = torch.load(path, weights_only=False)
    del payload["densifier"]
    torch.save(payload, path)
    with pytest.raises(EvsplatError, match="lacks densifier") as e:
        RunState.load(path)
    assert "\n" not in str(e.value)


def test_damaged_version_1_checkpoint_is_a_one_line_error(tmp_path):
    old = _as_version_1(_state())
    del old["mlp_full"]
    torch.save(old, tmp_path / "v1.pt")
    with pytest.raises(EvsplatError, match="version 1 checkpoint lacks 'mlp_full'") as e:
        RunState.load(tmp_path / "v1.pt")
    assert "\n" not in str(e.value)


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("data") / "ball"
    simulate_dataset("ball", out, tiny=True, seed=0, progress=False)
    return out


def test_a_restored_trainer_is_the_one_that_saved_and_steps_on_alike(tiny_data, tmp_path):
    cfg = preset("tiny")
    cfg.num_gaussians = 300
    cfg.schedule.iterations = 12  # warm-up ends at 1; refinement from 8
    cfg.schedule.grad_norms_every = 3
    cfg.densify.start_fraction, cfg.densify.interval = 0.0, 3
    cfg.mover.enabled = False  # the seeding's cost; its track is a field like the others
    cfg.skips.static_start_fraction, cfg.skips.static_every = 0.5, 2
    data = load_dataset(tiny_data)
    saved = Trainer(data, cfg, tmp_path / "run")
    for it in range(10):
        saved.progress.log(it, saved.step(it), stop=False)
    saved.progress.plateaued(0.5, 10, Stage.REFINE)
    assert saved.renderer.static_mask is not None, "the static classification ran"
    saved.save(10)
    resumed = Trainer(data, cfg, tmp_path / "run")
    assert resumed.resume() and resumed.start_iteration == 10
    _assert_same(snapshot(resumed, 10), snapshot(saved, 10))
    # The step's losses come before its update: the same windows and renders, equal values.
    assert resumed.step(10).losses == saved.step(10).losses


def test_held_out_windows_are_saved_and_a_version_3_checkpoint_has_none(tmp_path):
    state = dataclasses.replace(_state(), heldout=[(20_000, 25_000), (60_000, 65_000)])
    _assert_same(RunState.load(state.save(tmp_path / "run", keep=2)), state)
    v3 = _as_version_2(state) | {"version": 3}
    del v3["heldout"]
    torch.save(v3, tmp_path / "v3.pt")
    _assert_same(RunState.load(tmp_path / "v3.pt"), dataclasses.replace(state, heldout=[]))
