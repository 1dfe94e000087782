"""The GPU benchmark's phase timer (evsplat.bench.gpu): exclusive times, against sleeps."""

from __future__ import annotations

import time

import torch

from evsplat.bench.gpu import PHASES, PhaseTimer, phases_timed


def test_a_phase_inside_another_is_taken_out_of_it():
    timer = PhaseTimer(torch.device("cpu"))
    inner = timer.wrap("inner", lambda: time.sleep(0.05))

    def outer_body():
        time.sleep(0.03)
        inner()
        inner()

    timer.wrap("outer", outer_body)()
    assert 0.1 <= timer.seconds["inner"] < 0.2
    assert 0.03 <= timer.seconds["outer"] < 0.08  # its own 30 ms, not the inner 100


def test_the_timed_functions_are_put_back():
    import importlib

    def current():
        found = []
        for _, module, attr in PHASES:
            owner = importlib.import_module(module)
            for part in attr.split("."):
                owner = getattr(owner, part)
            found.append(owner)
        return found

    before = current()
    with phases_timed(PhaseTimer(torch.device("cpu"))):
        assert all(a is not b for a, b in zip(before, current()))
    assert all(a is b for a, b in zip(before, current()))
