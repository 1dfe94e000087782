"""Where cells run: on this machine (one after another in this process by default, or several
at a time in a process pool; no Ray needed), or as Ray tasks on a local or existing cluster.
All run ``execute_cell``; the runner sees only ``submit`` and ``poll``."""

from __future__ import annotations

import logging
import os
import pickle
import socket
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from multiprocessing import get_context
from pathlib import Path

from evsplat.errors import EvsplatError
from evsplat.sweep import store
from evsplat.sweep.cell import Cell
from evsplat.sweep.execute import Outcome, execute_cell

LOCAL_CLUSTER = "local"  # `--ray` without an address: start a cluster on this machine
CONNECT_TIMEOUT_S = 5.0
RAY_EXTRA = "--ray needs Ray: pip install 'evsplat[ray]' (or pip install ray)"


class LocalBackend:
    """Cells in order, in this process (each trains in its own child process)."""

    description = "local (one cell at a time)"

    def __init__(self) -> None:
        self._queue: list[tuple[Cell, Path, str]] = []

    def submit(self, cells: list[Cell], out: Path, code: str) -> None:
        self._queue += [(c, out, code) for c in cells]

    def poll(self, timeout: float) -> list[Outcome]:
        return [execute_cell(*self._queue.pop(0))] if self._queue else []

    def running(self, out: Path, waiting: set[str]) -> int:
        return min(1, len(waiting))  # the next poll runs one

    def object_store_bytes(self) -> int:
        return 0

    def close(self) -> None:
        self._queue.clear()


class PoolBackend:
    """Cells ``jobs`` at a time on this machine, each in a worker process of a pool (and
    trained in its own child process there)."""

    def __init__(self, jobs: int) -> None:
        self.description = f"local ({jobs} cells at a time)"
        # spawn, not fork: a forked copy of a process holding a GPU device is not safe.
        self._pool = ProcessPoolExecutor(jobs, mp_context=get_context("spawn"))
        self._pending: dict[Future, tuple[Cell, Path, str]] = {}

    def submit(self, cells: list[Cell], out: Path, code: str) -> None:
        for c in cells:
            self._pending[self._pool.submit(execute_cell, c, out, code)] = (c, out, code)

    def poll(self, timeout: float) -> list[Outcome]:
        if not self._pending:
            return []
        ready, _ = wait(list(self._pending), timeout=timeout, return_when=FIRST_COMPLETED)
        outcomes = []
        for fut in ready:
            cell, out, code = self._pending.pop(fut)
            try:
                outcomes.append(fut.result())
            except Exception as e:  # the worker process died (killed, out of memory)
                key = cell.key(code)
                outcomes.append(
                    Outcome(
                        key,
                        None,
                        f"{type(e).__name__}: the local worker running it died "
                        f"(log: {store.log_path(out, key)})",
                    )
                )
        return outcomes

    def running(self, out: Path, waiting: set[str]) -> int:
        """Cells with an attempt folder: started in a worker."""
        return store.running(out, waiting)

    def object_store_bytes(self) -> int:
        return 0

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pending.clear()


class RayBackend:
    """Each cell a Ray task asking for ``cpus`` CPUs and, where the cluster has GPUs, one GPU;
    a task whose worker dies is retried up to ``max_retries`` times. An exception inside a
    cell is its result (an Outcome with an error), so only lost workers are retried."""

    def __init__(self, address: str, max_retries: int, cpus: float) -> None:
        if address != LOCAL_CLUSTER:
            _check_reachable(address)
        self.ray = import_ray(address)  # a missing extra is an error before any work
        self.address, self.max_retries, self.cpus = address, max_retries, cpus
        self.gpus = 0
        self.description = "ray (not started: nothing to run)"
        self._started = False
        self._remote = None
        self._pending: dict = {}
        self._sent = 0

    def _connect(self) -> None:
        ray = self.ray
        if not ray.is_initialized():
            _connect(ray, self.address)
            self._started = True
        resources = ray.cluster_resources()
        self.gpus = 1 if resources.get("GPU", 0) >= 1 else 0
        nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
        where = "local cluster" if self.address == LOCAL_CLUSTER else f"cluster at {self.address}"
        per_cell = f"{self.cpus:g} CPU{'s' if self.cpus != 1 else ''}"
        self.description = (
            f"ray {where}: {nodes} node(s), {resources.get('CPU', 0):g} CPUs, "
            f"{resources.get('GPU', 0):g} GPUs; {per_cell}{' + 1 GPU' if self.gpus else ''} "
            f"per cell, max {self.max_retries} retries"
        )
        self._remote = ray.remote(execute_cell)

    def submit(self, cells: list[Cell], out: Path, code: str) -> None:
        if not cells:
            return
        if self._remote is None:
            self._connect()
        for cell in cells:
            task = self._remote.options(
                num_cpus=self.cpus,
                num_gpus=self.gpus,
                max_retries=self.max_retries,
                retry_exceptions=False,
                name=f"evsplat cell {cell.key(code)}",
            )
            self._pending[task.remote(cell, out, code)] = (cell, out, code)
            self._sent += len(pickle.dumps((cell, out, code)))

    def running(self, out: Path, waiting: set[str]) -> int:
        """Cells with an attempt folder: started on a worker (or killed, awaiting retry)."""
        return store.running(out, waiting)

    def poll(self, timeout: float) -> list[Outcome]:
        if not self._pending:
            return []
        ready, _ = self.ray.wait(list(self._pending), num_returns=1, timeout=timeout)
        outcomes = []
        for ref in ready:
            cell, out, code = self._pending.pop(ref)
            try:
                outcome = self.ray.get(ref)
            except self.ray.exceptions.RayError as e:  # the worker died on every try
                key = cell.key(code)
                why = str(e).strip().splitlines()[0] if str(e).strip() else ""
                outcome = Outcome(
                    key,
                    None,
                    f"{type(e).__name__}: the worker running it died {self.max_retries + 1} "
                    f"times (--max-retries {self.max_retries}): {why} "
                    f"(log: {store.log_path(out, key)})",
                )
            else:
                self._sent += len(pickle.dumps(outcome))
            outcomes.append(outcome)
        return outcomes

    def object_store_bytes(self) -> int:
        """Bytes this sweep sent through Ray: cell specs out, result rows back."""
        return self._sent

    def close(self) -> None:
        for ref in self._pending:
            self.ray.cancel(ref, force=True)
        self._pending.clear()
        if self._started:
            self.ray.shutdown()


def import_ray(address: str):
    """Ray, imported with its usage reporting off and, for a cluster on this machine, bound
    to the loopback address (Ray's single-machine mode) so nothing leaves the host."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address == LOCAL_CLUSTER:
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    try:
        import ray
    except ImportError:
        raise EvsplatError(RAY_EXTRA) from None
    return ray


def start_local_cluster(ray, cpus: int | None = None, tries: int = 3) -> None:
    """A Ray head on this machine with ``cpus`` CPUs (default: all), no dashboard, quiet.
    Ray gives its raylet a fixed 30 s to register, which a busy machine can miss: try again."""
    for attempt in range(1, tries + 1):
        try:
            ray.init(
                num_cpus=cpus or os.cpu_count(),
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,
            )
            return
        except Exception as e:  # Ray raises a bare Exception for the time-out
            ray.shutdown()
            if attempt == tries:
                first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
                raise EvsplatError(
                    f"--ray: a local Ray cluster did not start in {tries} tries ({first}); "
                    "run `ray start --head` and pass --ray auto"
                ) from None


def _connect(ray, address: str) -> None:
    if address == LOCAL_CLUSTER:
        start_local_cluster(ray)
        return
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    except Exception as e:  # Ray raises ConnectionError, RuntimeError, ValueError, ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise EvsplatError(f"--ray {address}: cannot join the cluster ({first})") from None


def _check_reachable(address: str) -> None:
    """A one-line error at once for an address where nothing listens (Ray itself retries for
    a minute); ``auto`` (the cluster `ray start` left on this machine) is Ray's to find."""
    if address == "auto":
        return
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise EvsplatError(
            f"--ray {address}: expected HOST:PORT (the head's GCS port, 6379 by default), "
            "ray://HOST:10001 or auto"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise EvsplatError(
            f"--ray {address}: no Ray cluster reachable there ({e.strerror or e}); start one "
            "with `ray start --head` on that machine or check the address (docs/scale-out.md)"
        ) from None
