"""The sweep runner, locally: a cell's row is the direct training run's score, reruns execute
nothing, half-written attempts are never results, and bad cells fail alone with one line."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import sys
from pathlib import Path

import pytest

from evsplat.cli import main
from evsplat.config import preset
from evsplat.errors import EvsplatError
from evsplat.sweep import Cell, SweepOptions, SweepResult, code_version, run_sweep, store

ITERS = 6


def tiny_config(iterations: int = ITERS, **skips) -> dict:
    cfg = preset("tiny")
    cfg.schedule.iterations = iterations
    cfg.mover.enabled = False  # its seeding alone would outlast these few iterations many times
    for k, v in skips.items():
        setattr(cfg.skips, k, v)
    return cfg.to_dict()


def quiet() -> SweepOptions:
    return SweepOptions(progress=False)


@pytest.fixture(scope="module")
def serial(tiny_scene, tmp_path_factory) -> tuple[list[Cell], Path, SweepResult, str]:
    """Three cells (seeds 0-2) run one at a time with the progress bar on: the cells, their
    output folder, the result and what the bar wrote. One sweep for the two tests that compare
    it with a direct run and with cells run at once: a cell is a training process (~15 s)."""
    data = tiny_scene("ball")
    cells = [Cell("ball", data, tiny_config(), seed=s, labels={"seed_label": s}) for s in (0, 1, 2)]
    out = tmp_path_factory.mktemp("serial") / "sweep"
    with contextlib.redirect_stderr(io.StringIO()) as err:
        result = run_sweep(cells, out, SweepOptions())
    return cells, out, result, err.getvalue()


def test_the_key_names_scene_config_seed_and_code_but_not_the_labels():
    cell = Cell("ball", Path("/d/ball"), tiny_config(), seed=1, labels={"variant": "a"})
    key = cell.key("v1")
    assert key.startswith(f"ball-{cell.config_hash}-s1-")
    assert Cell("ball", Path("/d/ball"), tiny_config(), seed=1, labels={"x": 2}).key("v1") == key
    assert Cell("ball", Path("/d/ball"), tiny_config(), seed=2).key("v1") != key
    assert Cell("ball", Path("/d/ball"), tiny_config(7), seed=1).key("v1") != key
    no_prior = ("--depth-prior", "none")
    assert Cell("ball", Path("/d/ball"), tiny_config(), 1, no_prior).key("v1") != key
    assert cell.key("v2") != key
    # The config's own seed is the cell's: it does not change the config hash.
    assert Cell("ball", Path("/d"), {**tiny_config(), "seed": 9}).config_hash == cell.config_hash
    assert code_version().startswith("0.")


def test_local_sweep_scores_like_a_direct_run_and_a_rerun_executes_nothing(serial, tmp_path):
    from evsplat.config import TrainConfig
    from evsplat.data.dataset import load_dataset
    from evsplat.eval import evaluate
    from evsplat.render import Renderer
    from evsplat.train import train

    cells, out, first, err = serial
    data = cells[0].data
    assert first.exit_code == 0 and first.executed == 3 and first.reused == 0
    assert "3/3" in err and "done 3 running 0 failed 0" in err  # the progress bar's last state
    # Oracle: the same config and seed trained directly, outside the sweep.
    cfg = TrainConfig.from_dict({**tiny_config(), "seed": 1})
    train(data, tmp_path / "direct", config=cfg, progress=False)
    direct = evaluate(Renderer.from_run(tmp_path / "direct")[0], load_dataset(data))["mean"]
    row = first.rows[1]
    assert row["seed_label"] == 1 and row["seed"] == 1 and row["iterations"] == ITERS
    assert row["psnr"] == pytest.approx(direct["psnr"], abs=0.05)
    assert (out / row["run"] / "eval.json").is_file()
    rerun = run_sweep(cells, out, quiet())
    assert rerun.executed == 0 and rerun.reused == 3 and rerun.rows == first.rows
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executed"] == 0 and summary["datasets"] == [str(data)]


def test_cells_run_at_once_in_worker_processes_score_as_one_at_a_time(serial, tmp_path):
    cells, _, one_at_a_time, _ = serial
    pooled = run_sweep(cells, tmp_path / "pooled", SweepOptions(jobs=2, progress=False))
    assert pooled.exit_code == 0 and pooled.executed == 3
    # Oracle: the same cells run one at a time in this process.
    for a, b in zip(one_at_a_time.rows, pooled.rows):
        assert (a["seed"], a["key"]) == (b["seed"], b["key"])
        # Not to the last digit: the backward's float atomics add in the order the threads
        # reach them, so two runs of one cell differ by ~1e-3 dB (seeds by ~0.1 dB, Table 3).
        assert b["psnr"] == pytest.approx(a["psnr"], abs=0.02)
    from evsplat.gpu import adapter_label

    assert all(r["adapter"] == adapter_label() for r in pooled.rows)  # the workers' adapter
    hosts = json.loads((tmp_path / "pooled" / "summary.json").read_text())["backend"]
    assert hosts == "local (2 cells at a time)"
    assert not list(store.cells_dir(tmp_path / "pooled").glob(store.TMP_PREFIX + "*"))
    with pytest.raises(EvsplatError, match="--jobs 0"):
        run_sweep(cells, tmp_path / "x", SweepOptions(jobs=0, progress=False))
    with pytest.raises(EvsplatError, match="--cpus-per-cell"):
        run_sweep(cells, tmp_path / "x", SweepOptions(jobs=2, ray="local", progress=False))


def test_a_half_written_attempt_or_cell_folder_is_never_taken_as_finished(tiny_scene, tmp_path):
    data = tiny_scene("ball")
    out = tmp_path / "sweep"
    cell = Cell("ball", data, tiny_config(), seed=0)
    key = cell.key(code_version())
    # A worker killed mid-cell leaves its attempt folder (even with a result.json in it: the
    # folder is renamed only once complete) ...
    stale = store.cells_dir(out) / f"{store.TMP_PREFIX}{key}@deadhost-123"
    (stale / "run").mkdir(parents=True)
    (stale / "result.json").write_text(json.dumps({"psnr": 99.0}))
    # ... and a folder named like the key but holding no result.json is no result either.
    twin = Cell("ball", data, tiny_config(), seed=1)
    (store.cells_dir(out) / twin.key(code_version()) / "run").mkdir(parents=True)
    result = run_sweep([cell, twin], out, quiet())
    assert result.executed == 2 and result.exit_code == 0
    assert all(r["psnr"] < 50 for r in result.rows)
    assert sorted(p.name for p in store.cells_dir(out).iterdir()) == sorted(
        c.key(code_version()) for c in (cell, twin)
    )


def test_a_missing_dataset_and_a_failing_cell_are_one_line_each_and_the_rest_finish(
    tiny_scene, tmp_path, capsys
):
    data = tiny_scene("ball")
    broken = tmp_path / "broken"
    shutil.copytree(data, broken)
    (broken / "meta.json").write_text("{ not json")
    cells = [
        Cell("gone", tmp_path / "no-such-dataset", tiny_config()),
        Cell("broken", broken, tiny_config()),
        Cell("ball", data, tiny_config()),
    ]
    result = run_sweep(cells, tmp_path / "sweep", quiet())
    assert result.exit_code == 1 and [r["scene"] for r in result.rows] == ["ball"]
    errors = dict((c.scene, e) for c, e in result.failures)
    assert "no-such-dataset not found on worker" in errors["gone"]
    assert "shared filesystem" in errors["gone"]
    assert "meta.json" in errors["broken"] and "log: " in errors["broken"]
    out = capsys.readouterr().out
    failed = [x for x in out.splitlines() if x.startswith("  failed: ")]
    assert len(failed) == 2 and all("\n" not in e for e in errors.values())
    # Nothing half-written for the failures: no cell folder, no attempt folder.
    assert [p.name for p in store.cells_dir(tmp_path / "sweep").iterdir()] == [
        cells[2].key(code_version())
    ]


def test_train_many_trains_every_matched_folder_and_reports_bad_globs(tiny_scene, tmp_path, capsys):
    root = tmp_path / "recordings"
    for name in ("a", "b"):
        shutil.copytree(tiny_scene("ball"), root / name)
    runs = tmp_path / "runs"
    args = ["train-many", str(root / "*"), "--out", str(runs), "--preset", "tiny"]
    assert main([*args, "--iters", "3", "--no-progress"]) == 0
    rows = json.loads((runs / "results.json").read_text())["rows"]
    assert sorted(r["scene"] for r in rows) == ["a", "b"]
    assert all((runs / r["run"] / "stats.json").is_file() for r in rows)
    assert "results.csv" in capsys.readouterr().out
    assert main(["train-many", str(tmp_path / "nothing-*"), "--out", str(runs)]) == 2
    err = capsys.readouterr().err.strip()
    assert "matches no folder" in err and "\n" not in err


def test_ray_without_the_extra_is_a_one_line_error_naming_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(EvsplatError, match=r"evsplat\[ray\]"):
        run_sweep([], tmp_path, SweepOptions(ray="local", progress=False))
    code = main(["train-many", str(tmp_path), "--out", str(tmp_path / "r"), "--ray"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "pip install 'evsplat[ray]'" in err and "\n" not in err
