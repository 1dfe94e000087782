"""Fast subset of `evsplat bench stress`: the same case generators with fewer cases, two SIGKILL
trials, and regression tests for the bugs the stress suite found."""

from __future__ import annotations

import errno

import numpy as np
import pytest
import torch

from evsplat.errors import EvsplatError
from tests.stress.harness import Case, Tally, check_case
from tests.stress.kill import check_ply_output, kill_trials
from tests.stress.suite import COMPONENTS, format_tallies, run_stress

# Cases per component in the default run (the full bench runs >= 10,000 in all).
FAST_CASES = {
    "events": 300,
    "spline": 120,
    "losses": 100,
    "colour_fit": 40,
    "model": 120,
    "raster": 26,
}


@pytest.mark.parametrize("component", list(COMPONENTS))
def test_finite_inputs_give_finite_outputs_and_gradients_or_a_clear_error(component):
    tally = run_stress(FAST_CASES[component], seed=1, components=[component])[component]
    assert tally.cases == FAST_CASES[component]
    assert tally.nonfinite == 0 and not tally.failures, tally.failures[:5]
    assert tally.finite > 0 and tally.refused > 0 or component in ("colour_fit", "model")


def test_fast_subset_runs_a_few_hundred_cases():
    assert sum(FAST_CASES.values()) == 706


def test_harness_counts_nan_output_and_unclear_errors_as_failures():
    tally = Tally()
    check_case(Case("x", "nan", lambda: [torch.tensor([float("nan")])]), tally)
    check_case(Case("x", "crash", lambda: 1 / 0), tally)
    check_case(Case("x", "accepted", lambda: [], expect="error"), tally)
    check_case(
        Case("x", "two lines", lambda: (_ for _ in ()).throw(ValueError("a\nb")), "error"), tally
    )
    check_case(
        Case("x", "refused", lambda: (_ for _ in ()).throw(EvsplatError("f: bad; fix")), "error"),
        tally,
    )
    assert (tally.cases, tally.nonfinite, tally.failed, tally.refused) == (5, 1, 4, 1)
    assert "total | 5 | 0 | 1 | 1 | 4" in format_tallies({"x": tally})


def test_ply_check_tells_complete_files_from_truncated_ones(tmp_path):
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\n"
    header += b"property float x\nproperty float y\nend_header\n"
    good = tmp_path / "good.ply"
    good.write_bytes(header + np.zeros(4, "<f4").tobytes())
    assert check_ply_output(good, None) == []
    cut = tmp_path / "cut.ply"
    cut.write_bytes(header + np.zeros(3, "<f4").tobytes())
    assert check_ply_output(cut, None) and check_ply_output(tmp_path / "gone.ply", b"old")


def test_sigkill_during_simulate_and_export_leaves_only_complete_files(tmp_path):
    # SIGKILL during `train` + `--resume` is covered by tests/test_train_e2e.py and the bench.
    report = kill_trials(2, tmp_path, seed=3, kinds=("simulate", "export"))
    assert report.trials == {"train": 0, "simulate": 1, "export": 1}
    assert report.corrupt == []


def test_cli_runs_the_harness_from_the_checkout(capsys):
    from evsplat.cli import main

    assert main(["bench", "stress", "--cases", "8", "--components", "events"]) == 0
    assert "events | 8 |" in capsys.readouterr().out


def test_cli_without_a_checkout_says_where_the_harness_lives(tmp_path, monkeypatch, capsys):
    from evsplat.bench import stress
    from evsplat.cli import main

    monkeypatch.setattr(stress, "CHECKOUT", tmp_path)
    assert main(["bench", "stress", "--cases", "8"]) == 2
    assert "no source checkout with tests/stress/" in capsys.readouterr().err


# ---- regressions found by the stress suite ---------------------------------------------------


def test_huge_quaternions_normalise_to_unit_length_with_finite_gradients():
    from evsplat.model.gaussians import normalize_quats

    q = torch.tensor([[3e30, -4e30, 0.0, 0.0], [0.0, 0.0, 2e20, 0.0]], requires_grad=True)
    r = normalize_quats(q)
    torch.testing.assert_close(r.detach(), torch.tensor([[0.6, -0.8, 0, 0], [0, 0, 1.0, 0]]))
    r[:, 0].sum().backward()
    assert torch.isfinite(q.grad).all()


def test_failing_atomic_write_is_a_one_line_error_and_leaves_the_old_file(tmp_path):
    from evsplat.data.atomic import write_atomic

    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def disk_full(tmp):
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(EvsplatError, match="out.bin: cannot write .*free space") as e:
        write_atomic(target, disk_full)
    assert "\n" not in str(e.value)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == [
        "out.bin"
    ]


def test_cli_subcommand_with_a_positional_named_run_dispatches(tmp_path, capsys):
    from evsplat.cli import main

    # `export RUN`: the positional used to overwrite the dispatch function.
    assert main(["export", str(tmp_path / "missing"), "--ply", str(tmp_path / "o.ply")]) == 2
    assert "no such run folder" in capsys.readouterr().err
