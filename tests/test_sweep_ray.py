"""The sweep runner on a local Ray cluster (2 CPUs, loopback only): the same rows as the local
runner, a worker SIGKILLed mid-cell is retried with nothing lost or counted twice, and bad
addresses or cells are one-line errors."""

from __future__ import annotations

import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest

from evsplat.cli import main
from evsplat.config import preset
from evsplat.sweep import Cell, SweepOptions, code_version, run_sweep, store
from evsplat.sweep.backends import LOCAL_CLUSTER, import_ray, start_local_cluster

ON_RAY = SweepOptions(ray=LOCAL_CLUSTER, max_retries=2, progress=False)
# Fields that depend on where and when a cell ran, not on what it computed.
WHERE_AND_WHEN = ("host", "wall_seconds", "iterations_per_second", "peak_rss_mib")
SCORES = ("psnr", "ssim", "psnr_moving")


@pytest.fixture(scope="module")
def cluster():
    """One local cluster for the module (its start costs ~20 s on 2 busy cores); a sweep
    given ``--ray`` joins it instead of starting its own. Its workers and the local runner's
    cells inherit one lavapipe thread: with several, the backward's float atomics add in an
    order that varies with the load, and a loaded CI machine saw two runs of one cell differ
    by 6e-5 in PSNR."""
    with pytest.MonkeyPatch.context() as env:
        env.setenv("LP_NUM_THREADS", "1")
        ray = import_ray(LOCAL_CLUSTER)  # loopback only, usage reporting off
        start_local_cluster(ray, cpus=2)
        yield
        ray.shutdown()


def config(iterations: int, checkpoint_every: int = 500, static: bool = True) -> dict:
    cfg = preset("tiny")
    cfg.schedule.iterations = iterations
    cfg.schedule.checkpoint_every = checkpoint_every
    cfg.mover.enabled = False  # its seeding alone would outlast these few iterations many times
    cfg.skips.static = static
    return cfg.to_dict()


def test_ray_rows_equal_the_local_runners_for_the_same_seeds(cluster, tiny_scene, tmp_path):
    data = tiny_scene("ball")
    cells = [
        Cell("ball", data, config(6, static=static), seed=seed, labels={"static": static})
        for static in (True, False)
        for seed in (0, 1)
    ]
    local = run_sweep(cells, tmp_path / "local", SweepOptions(progress=False))
    on_ray = run_sweep(cells, tmp_path / "ray", ON_RAY)
    assert local.exit_code == on_ray.exit_code == 0
    assert len(local.rows) == len(on_ray.rows) == 4
    assert len({r["key"] for r in on_ray.rows}) == 4

    for a, b in zip(on_ray.rows, local.rows):
        assert {k: v for k, v in a.items() if k not in WHERE_AND_WHEN + SCORES} == {
            k: v for k, v in b.items() if k not in WHERE_AND_WHEN + SCORES
        }
        # One lavapipe thread makes the float atomics' order fixed (see `cluster`); the bound
        # leaves room for the last bits of torch's reductions.
        for k in SCORES:
            assert a[k] == pytest.approx(b[k], rel=1e-6), k


def _attempt_pid(out: Path, key: str, deadline: float) -> int:
    """The pid of the worker running ``key``, once its training has written a checkpoint."""
    log = store.log_path(out, key)
    while time.time() < deadline:
        ckpts = list(store.cells_dir(out).glob(f"{store.TMP_PREFIX}{key}@*/run/checkpoints/*.pt"))
        if ckpts and log.is_file():
            header = [x for x in log.read_text().splitlines() if x.startswith("== attempt")][-1]
            return int(header.split(" pid ")[1].split()[0])
        time.sleep(0.2)
    raise AssertionError(f"{key} never reached its first checkpoint")


def _processes_mentioning(text: str) -> list[int]:
    found = []
    for p in Path("/proc").iterdir():
        try:
            if p.name.isdigit() and text in (p / "cmdline").read_text():
                found.append(int(p.name))
        except OSError:
            continue
    return found


def test_a_worker_killed_mid_cell_is_retried_and_nothing_is_lost_or_counted_twice(
    cluster, tiny_scene, tmp_path
):
    data, out = tiny_scene("ball"), tmp_path / "sweep"
    long = Cell("ball", data, config(60, checkpoint_every=10), seed=0)
    short = Cell("ball", data, config(6), seed=1)
    key = long.key(code_version())
    killed: list[int] = []

    def kill_mid_cell() -> None:
        pid = _attempt_pid(out, key, time.time() + 600)
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    killer = threading.Thread(target=kill_mid_cell, daemon=True)
    killer.start()
    result = run_sweep([long, short], out, ON_RAY)
    killer.join(timeout=5)
    assert killed, "the test never killed the worker"
    assert result.exit_code == 0 and result.executed == 2
    assert sorted(r["key"] for r in result.rows) == sorted([key, short.key(code_version())])
    log = store.log_path(out, key).read_text().splitlines()
    attempts = [x for x in log if x.startswith("== attempt")]
    assert len(attempts) == 2 and f"pid {killed[0]}" in attempts[0]
    assert log.count("finished") == 1
    assert result.rows[0]["iterations"] == 60
    # The killed attempt's folder is gone, and so is its training process (it dies with its
    # worker rather than train on beside the retry).
    assert sorted(p.name for p in store.cells_dir(out).iterdir()) == sorted(
        [key, short.key(code_version())]
    )
    assert _processes_mentioning(f"@{os.uname().nodename}-{killed[0]}") == []
    rerun = run_sweep([long, short], out, ON_RAY)
    assert rerun.executed == 0 and rerun.reused == 2 and rerun.rows == result.rows


def test_bad_cells_on_ray_fail_alone_with_one_line_each(cluster, tiny_scene, tmp_path):
    data = tiny_scene("ball")
    broken = tmp_path / "broken"
    shutil.copytree(data, broken)
    (broken / "events.h5").write_bytes(b"not hdf5")
    cells = [
        Cell("gone", tmp_path / "elsewhere" / "ball", config(3)),
        Cell("broken", broken, config(3)),
        Cell("ball", data, config(3)),
    ]
    result = run_sweep(cells, tmp_path / "sweep", ON_RAY)
    assert result.exit_code == 1 and [r["scene"] for r in result.rows] == ["ball"]
    errors = {c.scene: e for c, e in result.failures}
    assert f"dataset {tmp_path / 'elsewhere' / 'ball'} not found on worker" in errors["gone"]
    assert "events.h5" in errors["broken"] and "training failed" in errors["broken"]
    assert all("\n" not in e for e in errors.values())


def test_an_unreachable_address_is_a_one_line_error_at_once(tiny_scene, tmp_path, capsys):
    start = time.perf_counter()
    # Loopback, a port where nothing listens: no traffic leaves the machine.
    args = ["train-many", str(tiny_scene("ball")), "--out", str(tmp_path / "r"), "--iters", "2"]
    code = main([*args, "--ray", "127.0.0.1:1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert "--ray 127.0.0.1:1: no Ray cluster reachable there" in err and "ray start" in err
    assert time.perf_counter() - start < 30
    assert not (tmp_path / "r" / "cells").exists()
