"""Checkpoints and atomic writes: complete files only, clear errors for damaged or foreign ones."""

import os

import pytest
import torch

from evsplat.checkpoint import (
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    load_run,
    save_checkpoint,
)
from evsplat.data.atomic import write_atomic, write_text_atomic
from evsplat.errors import EvsplatError


def test_checkpoint_round_trip_keeps_tensors_and_iteration(tmp_path):
    state = {"weights": torch.arange(5.0), "note": "x"}
    path = save_checkpoint(tmp_path, 7, state)
    loaded = load_checkpoint(path)
    assert loaded["iteration"] == 7
    assert torch.equal(loaded["weights"], state["weights"])
    assert load_run(tmp_path)["iteration"] == 7


def test_only_the_newest_checkpoints_are_kept(tmp_path):
    for it in (10, 20, 30, 40):
        save_checkpoint(tmp_path, it, {}, keep=2)
    assert [p.name for p in list_checkpoints(tmp_path)] == ["ckpt_0000030.pt", "ckpt_0000040.pt"]
    assert latest_checkpoint(tmp_path).name == "ckpt_0000040.pt"


def test_leftover_temporary_file_is_never_taken_as_a_checkpoint(tmp_path):
    save_checkpoint(tmp_path, 5, {})
    (tmp_path / "checkpoints" / ".ckpt_0000009.pt.abc.tmp").write_bytes(b"partial")
    assert latest_checkpoint(tmp_path).name == "ckpt_0000005.pt"


def test_truncated_checkpoint_is_a_one_line_error(tmp_path):
    path = save_checkpoint(tmp_path, 1, {"w": torch.zeros(1000)})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(EvsplatError, match="not a readable checkpoint") as e:
        load_checkpoint(path)
    assert "\n" not in str(e.value)


def test_foreign_and_future_checkpoints_are_rejected(tmp_path):
    foreign = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(EvsplatError, match="not an evsplat checkpoint"):
        load_checkpoint(foreign)
    future = tmp_path / "future.pt"
    torch.save({"format": "evsplat-checkpoint", "version": 999}, future)
    with pytest.raises(EvsplatError, match="version 999"):
        load_checkpoint(future)


def test_missing_run_folder_and_empty_run_folder_are_errors(tmp_path):
    with pytest.raises(EvsplatError, match="no such run folder"):
        load_run(tmp_path / "nope")
    with pytest.raises(EvsplatError, match="no checkpoint"):
        load_run(tmp_path)


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
