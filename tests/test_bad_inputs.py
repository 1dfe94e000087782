"""Bad-input catalogue: malformed inputs across readers, dataset folders, CLI flags, checkpoints
and the Python API. Every row checks a one-line error naming the input and the fix, a non-zero
exit, no partial output and every existing file untouched (the whole work folder is hashed
before and after).

``EVSPLAT_WRITE_ROBUSTNESS_DOC=1 python -m pytest tests/test_bad_inputs.py`` also writes the
table (input, message, exit code) to docs/robustness.md once every row has run.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from evsplat.cli import main
from evsplat.data.simulator import simulate_dataset
from evsplat.errors import EvsplatError
from evsplat.train import train

DOC = Path(__file__).resolve().parents[1] / "docs" / "robustness.md"


@dataclass
class Row:
    """One malformed input: ``setup(work, data, run)`` builds it inside ``work`` (copies of the
    valid tiny dataset ``data`` and run ``run`` are there) and returns the CLI argv, or a
    callable for a Python-API row. ``names`` must all appear in the message; ``code`` is the
    expected exit status (None for API rows, which must raise EvsplatError). Rows with
    ``subprocess`` run the CLI in a fresh interpreter to prove no traceback reaches the user."""

    input: str
    setup: Callable[[Path, Path, Path], list[str] | Callable[[], object]]
    names: tuple[str, ...]
    code: int | None = 2
    patch: Callable[[pytest.MonkeyPatch], None] | None = None
    subprocess: bool = False
    may_create: tuple[str, ...] = ()  # complete JSON files the command may leave (run config)


# ---- builders of malformed inputs ----------------------------------------------------------------


def _h5_events(path: Path, x, y, t, p, width: int, height: int) -> None:
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        for k, v in zip("xytp", (x, y, t, p)):
            g.create_dataset(k, data=np.asarray(v))
        g.attrs["width"], g.attrs["height"] = width, height


def _train_argv(data: Path, work: Path) -> list[str]:
    out = str(work / "new_run")
    return ["train", str(data), "--out", out, "--no-progress", "--preset", "tiny", "--iters", "1"]


def _events(edit: Callable[[Path], None]) -> Callable[[Path, Path, Path], list[str]]:
    """A dataset whose events.h5 is replaced by ``edit``; trained with `evsplat train`."""

    def setup(work: Path, data: Path, run: Path) -> list[str]:
        edit(data / "events.h5")
        return _train_argv(data, work)

    return setup


def _truncate(path: Path) -> None:
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])


def _corrupt(path: Path) -> None:
    raw = bytearray(path.read_bytes())
    raw[:64] = b"\x13" * 64  # the superblock: h5py cannot find the root group
    path.write_bytes(bytes(raw))


def _unsorted(path: Path) -> None:
    _h5_events(path, [1, 2, 3], [1, 1, 1], [10, 30, 20], [1, -1, 1], 96, 96)


def _outside(path: Path) -> None:
    _h5_events(path, [1, 200, 3], [1, 1, 1], [10, 20, 30], [1, -1, 1], 96, 96)


def _empty_file(path: Path) -> None:
    path.write_bytes(b"")


def _directory(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _index(edit: Callable[[np.ndarray], None]) -> Callable[[Path], None]:
    """Rewrites the file's millisecond index by ``edit`` (in place on an int64 copy)."""

    def f(path: Path) -> None:
        with h5py.File(path, "r+") as h5:
            idx = h5["ms_to_idx"][()].astype(np.int64)
            edit(idx)
            del h5["ms_to_idx"]
            h5["ms_to_idx"] = idx.astype(np.uint64)

    return f


def _index_one_early(idx: np.ndarray) -> None:
    """Every inner entry one event early: structurally sound, wrong for any window."""
    idx[1:-1] = np.maximum(idx[1:-1] - 1, idx[0])


def _first_half(path: Path) -> None:
    """The recording cut at 300 ms (of the poses' 600 ms), index and all."""
    from evsplat.data.event_files import read_events
    from evsplat.data.event_writer import write_events_h5

    ev = read_events(path)
    write_events_h5(path, ev.slice(0, int(np.searchsorted(ev.t, 300_000))))


def _text(name: str, edit: Callable[[str], str]) -> Callable[[Path, Path, Path], list[str]]:
    """A dataset whose text file ``name`` is rewritten by ``edit``."""

    def setup(work: Path, data: Path, run: Path) -> list[str]:
        (data / name).write_text(edit((data / name).read_text()))
        return _train_argv(data, work)

    return setup


def _pose_lines(edit: Callable[[list[str]], list[str]]) -> Callable[[str], str]:
    def f(text: str) -> str:
        lines = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
        return "\n".join(edit(lines)) + "\n"

    return f


def _dup_pose(lines: list[str]) -> list[str]:
    return lines[:3] + [lines[2]] + lines[3:]


def _swap_pose(lines: list[str]) -> list[str]:
    return lines[:2] + [lines[3], lines[2]] + lines[4:]


def _nan_pose(lines: list[str]) -> list[str]:
    parts = lines[4].split()
    parts[1] = "nan"
    return lines[:4] + [" ".join(parts)] + lines[5:]


def _json_edit(key: str, value: object) -> Callable[[str], str]:
    def f(text: str) -> str:
        d = json.loads(text)
        d[key] = value
        return json.dumps(d)

    return f


def _k_edit(i: int, j: int, value: float) -> Callable[[str], str]:
    def f(text: str) -> str:
        d = json.loads(text)
        d["K"][i][j] = value
        return json.dumps(d)

    return f


def _checkpoint(edit: Callable[[Path], None]) -> Callable[[Path, Path, Path], list[str]]:
    """The trained run with its newest checkpoint replaced by ``edit``; exported to PLY."""

    def setup(work: Path, data: Path, run: Path) -> list[str]:
        ckpt = sorted((run / "checkpoints").glob("ckpt_*.pt"))[-1]
        edit(ckpt)
        return ["export", str(run), "--ply", str(work / "out.ply")]

    return setup


def _future_version(path: Path) -> None:
    state = torch.load(path, weights_only=False)
    state["version"] += 1
    torch.save(state, path)


def _foreign(path: Path) -> None:
    torch.save({"state_dict": {"w": torch.zeros(2)}}, path)


def _no_checkpoints(path: Path) -> None:
    for p in path.parent.iterdir():
        p.unlink()


def _export_over_existing(work: Path, data: Path, run: Path) -> list[str]:
    """An export whose target already holds an older PLY, which must survive the failure."""
    (work / "old.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nend_header\n")
    return ["export", str(run), "--ply", str(work / "old.ply")]


def _fail_writes(exc: BaseException) -> Callable[[pytest.MonkeyPatch], None]:
    """Writers fail after writing half of their bytes (disk full, Ctrl-C, read-only folder)."""

    def patch(mp: pytest.MonkeyPatch) -> None:
        real = Path.write_bytes

        def half_then_fail(self: Path, data: bytes) -> int:
            real(self, data[: len(data) // 2])
            raise exc

        mp.setattr(Path, "write_bytes", half_then_fail)
        mp.setattr(torch, "save", lambda obj, f, *a, **k: (Path(f).write_bytes(b"PK\x03"), exc))

    return patch


def _fail_checkpoint_save(exc: BaseException) -> Callable[[pytest.MonkeyPatch], None]:
    """torch.save writes a few bytes of the checkpoint, then fails."""

    def patch(mp: pytest.MonkeyPatch) -> None:
        def partial_save(obj: object, f: object, *a: object, **k: object) -> None:
            Path(f).write_bytes(b"PK\x03\x04partial")
            raise exc

        mp.setattr(torch, "save", partial_save)

    return patch


def _api(
    fn: Callable[[Path], Callable[[], object]],
) -> Callable[[Path, Path, Path], Callable[[], object]]:
    """A Python-API row: ``fn(work)`` writes its input files and returns the failing call."""
    return lambda work, data, run: fn(work)


def _api_unsorted_text(work: Path) -> Callable[[], object]:
    from evsplat.data.event_files import read_events

    (work / "ev.txt").write_text("0.001 1 1 1\n0.0005 2 2 0\n")
    return lambda: read_events(work / "ev.txt")


def _api_empty_text(work: Path) -> Callable[[], object]:
    from evsplat.data.event_files import read_events

    (work / "ev.csv").write_text("")
    return lambda: read_events(work / "ev.csv")


def _api_polarity(work: Path) -> Callable[[], object]:
    from evsplat.data.events import EventStream

    return lambda: EventStream.from_arrays([0, 1], [0, 0], [0, 1], [1, 2], 4, 4, source="cam0")


def _api_repeated_pose_time(work: Path) -> Callable[[], object]:
    from evsplat.data.trajectory import Trajectory

    return lambda: Trajectory.fit(
        np.array([0, 5, 5]), np.tile(np.eye(4), (3, 1, 1)), source="rig.txt"
    )


def _api_nan_means(work: Path) -> Callable[[], object]:
    from evsplat.raster import rasterize

    means = torch.tensor([[0.0, float("nan"), 2.0]])
    one = torch.ones(1, 1)
    return lambda: rasterize(means, torch.ones(1, 4), torch.ones(1, 3), torch.ones(1), one,
                     torch.eye(4), torch.eye(3), 8, 8)  # fmt: skip


def _api_inf_translation(work: Path) -> Callable[[], object]:
    from evsplat.data.trajectory import Trajectory

    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[1, 0, 3] = np.inf
    return lambda: Trajectory.fit(np.array([0, 5, 9]), c2w, source="poses.txt")


ROWS: list[Row] = [
    # readers, through a dataset folder given to `evsplat train`
    Row("truncated HDF5 events.h5", _events(_truncate), ("events.h5", "truncated")),
    Row(
        "corrupt HDF5 superblock in events.h5",
        _events(_corrupt),
        ("events.h5", "re-export"),
        subprocess=True,
    ),  # fmt: skip
    Row("unsorted event timestamps", _events(_unsorted), ("events.h5", "sort")),
    Row("events outside the sensor", _events(_outside), ("events.h5", "x")),
    Row("empty event file (0 bytes)", _events(_empty_file), ("events.h5", "empty")),
    Row(
        "a directory where events.h5 is expected", _events(_directory), ("events.h5", "is a folder")
    ),
    Row(
        "duplicated pose timestamp",
        _text("poses.txt", _pose_lines(_dup_pose)),
        ("poses.txt", "drop duplicates"),
    ),  # fmt: skip
    Row(
        "unsorted pose timestamps",
        _text("poses.txt", _pose_lines(_swap_pose)),
        ("poses.txt", "sort"),
    ),  # fmt: skip
    Row(
        "NaN in a pose",
        _text("poses.txt", _pose_lines(_nan_pose)),
        ("poses.txt", "NaN", "remove that line"),
        subprocess=True,
    ),  # fmt: skip
    Row(
        "Inf focal length in intrinsics.json",
        _text("intrinsics.json", _k_edit(0, 0, 1e999)),
        ("intrinsics.json", "finite"),
    ),  # fmt: skip
    Row(
        "NaN principal point in intrinsics.json",
        _text("intrinsics.json", _k_edit(0, 2, float("nan"))),
        ("intrinsics.json", "finite"),
    ),
    Row(
        "sensor size in meta.json differs from intrinsics.json",
        _text("meta.json", _json_edit("width", 97)),
        ("meta.json", "intrinsics.json"),
    ),
    Row(
        "meta.json is not JSON",
        _text("meta.json", lambda s: s[: len(s) // 2]),
        ("meta.json", "regenerate"),
    ),
    Row(
        "dataset folder is a file",
        lambda w, d, r: _train_argv(d / "meta.json", w),
        ("meta.json", "dataset folder"),
    ),  # fmt: skip
    Row(
        "ms index that disagrees with the timestamps",
        _events(_index(_index_one_early)),
        ("events.h5", "disagrees with the timestamps", "re-convert"),
    ),
    Row(
        "ms index pointing past the last event",
        _events(_index(lambda idx: idx.__setitem__(-1, idx[-1] + 10**6))),
        ("events.h5", "outside the file's", "re-convert"),
    ),
    Row(
        "recording shorter than the poses",
        _events(_first_half),
        ("events.h5", "shorter than the data's time range", "meta.json"),
    ),
    # CLI flags
    Row("--iters 0", lambda w, d, r: [*_train_argv(d, w)[:-1], "0"], ("--iters", "at least 1")),
    Row(
        "--time-range outside the recording",
        lambda w, d, r: [*_train_argv(d, w), "--time-range", "0.5:0.9"],
        ("--time-range", "not inside the recording", "0 <= START < END <= 0.6"),
    ),
    Row(
        "--preset that does not exist",
        lambda w, d, r: [*_train_argv(d, w)[:-3], "huge"],
        ("huge", "choose one of"),
    ),  # fmt: skip
    Row(
        "--config file missing",
        lambda w, d, r: [*_train_argv(d, w), "--config", str(w / "c.json")],
        ("c.json", "not found"),
    ),  # fmt: skip
    Row(
        "export --time outside [0, 1]",
        lambda w, d, r: ["export", str(r), "--time", "2", "--ply", str(w / "o.ply")],
        ("--time", "[0, 1]"),
    ),  # fmt: skip
    Row(
        "simulate --scene unknown",
        lambda w, d, r: ["simulate", "--scene", "nosuch", "--tiny", "--out", str(w / "ds")],
        ("nosuch",),
    ),  # fmt: skip
    Row(
        "simulate --out is an existing non-empty folder",
        lambda w, d, r: ["simulate", "--scene", "ball", "--tiny", "--out", str(d)],
        (d_name := "data", "remove it"),
    ),  # fmt: skip
    Row(
        "render --out is an existing file",
        lambda w, d, r: ["render", str(r), "--times", "0:1:0.5", "--out", str(d / "meta.json")],
        ("meta.json", "folder"),
    ),  # fmt: skip
    Row(
        "export --ply is an existing directory",
        lambda w, d, r: ["export", str(r), "--ply", str(d)],
        ("data", "not a folder"),
    ),  # fmt: skip
    # checkpoints
    Row(
        "checkpoint from a newer evsplat version",
        _checkpoint(_future_version),
        ("ckpt_", "retrain"),
        subprocess=True,
    ),  # fmt: skip
    Row("truncated checkpoint", _checkpoint(_truncate), ("ckpt_", "resume from an earlier")),
    Row(
        "foreign checkpoint (another program's .pt)",
        _checkpoint(_foreign),
        ("ckpt_", "not an evsplat checkpoint"),
    ),  # fmt: skip
    Row("run folder without checkpoints", _checkpoint(_no_checkpoints), ("run", "train it first")),
    # output that cannot be written: nothing partial, the older file untouched
    Row(
        "disk full while exporting (failing writer)",
        _export_over_existing,
        ("old.ply", "free space"),
        patch=_fail_writes(OSError(errno.ENOSPC, "No space left")),
    ),
    Row(
        "read-only output folder (writer refused)",
        _export_over_existing,
        ("old.ply", "permission"),
        patch=_fail_writes(PermissionError(errno.EACCES, "denied")),
    ),
    Row(
        "Ctrl-C while exporting (KeyboardInterrupt inside the writer)",
        _export_over_existing,
        ("interrupted",),
        code=130,
        patch=_fail_writes(KeyboardInterrupt()),
    ),
    Row(
        "disk full while writing a training checkpoint",
        lambda w, d, r: _train_argv(d, w),
        ("ckpt_", "free space"),
        patch=_fail_checkpoint_save(OSError(errno.ENOSPC, "No space left")),
        may_create=("new_run", "new_run/config.json", "new_run/checkpoints"),
    ),
    # Python API
    Row("read_events: unsorted text events", _api(_api_unsorted_text), ("ev.txt", "sort"), None),
    Row("read_events: empty CSV file", _api(_api_empty_text), ("ev.csv", "empty"), None),
    Row("EventStream.from_arrays: polarity 2", _api(_api_polarity), ("cam0", "polarit"), None),
    Row(
        "Trajectory.fit: repeated timestamps",
        _api(_api_repeated_pose_time),
        ("rig.txt", "drop duplicates"),
        None,
    ),  # fmt: skip
    Row("Trajectory.fit: Inf translation", _api(_api_inf_translation), ("poses.txt", "inf"), None),
    Row("rasterize: NaN means", _api(_api_nan_means), ("means", "finite"), None),
]
del d_name


# ---- the harness ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> tuple[Path, Path]:
    """A valid tiny dataset and a 2-iteration run trained on it (copied for each row)."""
    base = tmp_path_factory.mktemp("valid")
    simulate_dataset("ball", base / "data", tiny=True, seed=0, progress=False)
    train(base / "data", base / "run", preset_name="tiny", iterations=2, progress=False)
    return base / "data", base / "run"


def _snapshot(root: Path) -> dict[str, str]:
    """Every file and folder under ``root`` with a hash of its bytes."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for d in dirs:
            out[os.path.relpath(os.path.join(dirpath, d), root)] = "dir"
        for f in files:
            p = os.path.join(dirpath, f)
            out[os.path.relpath(p, root)] = hashlib.sha1(Path(p).read_bytes()).hexdigest()
    return out


RESULTS: dict[str, tuple[str, str]] = {}


@pytest.fixture(scope="module", autouse=True)
def robustness_doc():
    """Writes docs/robustness.md from the rows' results when EVSPLAT_WRITE_ROBUSTNESS_DOC=1."""
    yield
    if os.environ.get("EVSPLAT_WRITE_ROBUSTNESS_DOC") != "1" or len(RESULTS) != len(ROWS):
        return
    lines = [
        "# Robustness: what evsplat does with bad input",
        "",
        "Generated by `EVSPLAT_WRITE_ROBUSTNESS_DOC=1 python -m pytest tests/test_bad_inputs.py`",
        "from the table in that test; do not edit by hand. Every row is checked for: a one-line",
        "message naming the input and the fix, the exit code shown, no traceback, no partial",
        "output and every existing file untouched. Paths are shortened to `…/`. The numeric",
        "stress suite is `evsplat bench stress` (cases per component, NaN/Inf found, SIGKILL",
        "trials with `--kill-trials N`), which runs the harness in tests/stress/ of a source",
        "checkout.",
        "",
        f"{len(ROWS)} malformed inputs:",
        "",
        "| # | input | message | exit code |",
        "|---|---|---|---|",
    ]
    for i, row in enumerate(ROWS, 1):
        msg, code = RESULTS[row.input]
        msg = msg.replace("|", "\\|")
        lines.append(f"| {i} | {row.input} | `{msg}` | {code} |")
    DOC.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _shorten(msg: str, work: Path) -> str:
    return msg.replace(str(work) + "/", "…/").replace(str(work), "…")


@pytest.mark.parametrize("row", ROWS, ids=[r.input for r in ROWS])
def test_bad_input_gives_one_line_error_and_leaves_files_untouched(
    row: Row, valid, tmp_path, monkeypatch, capsys
):
    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(valid[0], data)
    shutil.copytree(valid[1], run)
    target = row.setup(tmp_path, data, run)
    before = _snapshot(tmp_path)
    if callable(target):
        with pytest.raises(EvsplatError) as e:
            target()
        msg, code = str(e.value), "EvsplatError (API)"
    elif row.subprocess:
        env = {**os.environ, "EVSPLAT_QUIET": "1"}
        p = subprocess.run([sys.executable, "-m", "evsplat.cli", *target], capture_output=True,
                           text=True, env=env)  # fmt: skip
        assert p.returncode == row.code and "Traceback" not in p.stderr, p.stderr
        msg, code = p.stderr.strip(), p.returncode
    else:
        if row.patch is not None:
            row.patch(monkeypatch)
        code = main(target)
        monkeypatch.undo()
        msg = capsys.readouterr().err.strip()
        assert code == row.code, msg
    assert msg and "\n" not in msg, f"not one line: {msg!r}"
    for name in row.names:
        assert name.lower() in msg.lower(), f"{name!r} not in {msg!r}"
    after = _snapshot(tmp_path)
    for rel in row.may_create:
        if after.get(rel) not in (None, "dir"):
            json.loads((tmp_path / rel).read_text())  # complete, not half-written
        after.pop(rel, None)
    assert after == before, "files were added, removed or changed"
    RESULTS[row.input] = (_shorten(msg, tmp_path), str(code))


def test_catalogue_has_at_least_25_rows():
    assert len(ROWS) >= 25
