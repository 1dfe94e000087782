"""Checkpoint files and atomic writes: complete files only, clear errors for damaged, foreign or
unknown-version ones, older versions upgraded one at a time."""

import os

import pytest
import torch

from evsplat.checkpoint import (
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    run_checkpoint,
    save_checkpoint,
)
from evsplat.data.atomic import write_atomic, write_text_atomic
from evsplat.errors import EvsplatError


def test_checkpoint_round_trip_keeps_tensors_and_iteration(tmp_path):
    state = {"weights": torch.arange(5.0), "note": "x"}
    path = save_checkpoint(tmp_path, 7, state, version=1)
    loaded = load_checkpoint(path, 1, {})
    assert loaded["iteration"] == 7 and loaded["version"] == 1
    assert torch.equal(loaded["weights"], state["weights"])
    assert run_checkpoint(tmp_path) == path and run_checkpoint(path) == path


def test_only_the_newest_checkpoints_are_kept(tmp_path):
    for it in (10, 20, 30, 40):
        save_checkpoint(tmp_path, it, {}, version=1, keep=2)
    assert [p.name for p in list_checkpoints(tmp_path)] == ["ckpt_0000030.pt", "ckpt_0000040.pt"]
    assert latest_checkpoint(tmp_path).name == "ckpt_0000040.pt"


def test_leftover_temporary_file_is_never_taken_as_a_checkpoint(tmp_path):
    save_checkpoint(tmp_path, 5, {}, version=1)
    (tmp_path / "checkpoints" / ".ckpt_0000009.pt.abc.tmp").write_bytes(b"partial")
    assert latest_checkpoint(tmp_path).name == "ckpt_0000005.pt"


def test_truncated_checkpoint_is_a_one_line_error(tmp_path):
    path = save_checkpoint(tmp_path, 1, {"w": torch.zeros(1000)}, version=1)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(EvsplatError, match="not a readable checkpoint") as e:
        load_checkpoint(path, 1, {})
    assert "\n" not in str(e.value)


def test_foreign_future_and_unknown_old_checkpoints_are_rejected_in_one_line(tmp_path):
    foreign = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(EvsplatError, match="not an evsplat checkpoint"):
        load_checkpoint(foreign, 2, {})
    for version in (999, 0):
        path = tmp_path / f"v{version}.pt"
        torch.save({"format": "evsplat-checkpoint", "version": version}, path)
        with pytest.raises(EvsplatError, match=f"version {version} but .* version 1, 2;") as e:
            load_checkpoint(path, 2, {1: dict})
        assert "\n" not in str(e.value)


def test_older_versions_are_upgraded_one_version_at_a_time(tmp_path):
    path = save_checkpoint(tmp_path, 3, {"steps": []}, version=1)
    upgrades = {
        1: lambda s: s | {"steps": [*s["steps"], s["version"]]},
        2: lambda s: s | {"steps": [*s["steps"], s["version"]]},
    }
    loaded = load_checkpoint(path, 3, upgrades)
    assert loaded["version"] == 3 and loaded["steps"] == [1, 2] and loaded["iteration"] == 3
    assert load_checkpoint(save_checkpoint(tmp_path, 4, {}, version=3), 3, upgrades)["version"] == 3


def test_missing_run_folder_and_empty_run_folder_are_errors(tmp_path):
    with pytest.raises(EvsplatError, match="no such run folder"):
        run_checkpoint(tmp_path / "nope")
    with pytest.raises(EvsplatError, match="no checkpoint"):
        run_checkpoint(tmp_path)


def test_atomic_write_failure_leaves_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.txt"
    write_text_atomic(target, "old")

    def half_then_fail(tmp):
        tmp.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_atomic(target, half_then_fail)
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]
