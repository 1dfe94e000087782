"""`evsplat bench seeding` scores each true object by the seeded object nearest its path: checked
on paths whose distances are known, and end to end on a built-in scene against its true objects."""

from __future__ import annotations

import numpy as np
import pytest

from evsplat.bench.seeding import match_score
from evsplat.cli import main


def _truth(times: int = 20) -> np.ndarray:
    t = np.linspace(0.0, 1.0, times)
    return np.stack([10.0 + 60.0 * t, 40.0 + 20.0 * np.sin(3.0 * t)], 1)


def test_the_nearest_seeded_object_is_matched_and_its_steady_offset_taken_out():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    seen[:4] = False  # out of the image: not scored
    near = truth + np.array([3.0, 4.0])  # 5 px off, steadily
    near[:4] += 100.0
    far = truth + np.array([30.0, 0.0])
    k, median, steady, p90 = match_score(np.stack([far, near]), truth, seen)
    assert k == 1
    assert median == pytest.approx(5.0)
    assert steady == pytest.approx(0.0, abs=1e-9)
    assert p90 == pytest.approx(5.0)


def test_an_offset_that_changes_is_not_taken_out():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    jitter = np.zeros_like(truth)
    jitter[:, 0] = np.where(np.arange(len(truth)) % 2 == 0, 2.0, -2.0)  # 2 px right, then left
    k, median, steady, _ = match_score(jitter[None] + truth, truth, seen)
    assert k == 0
    assert median == pytest.approx(2.0)
    assert steady == pytest.approx(2.0)  # the median offset is none


def test_nothing_seeded_or_never_seen_scores_none():
    truth = _truth()
    assert (
        match_score(np.zeros((0, len(truth), 2)), truth, np.ones(len(truth), bool)) == (None,) * 4
    )
    assert match_score(truth[None], truth, np.zeros(len(truth), bool)) == (None,) * 4


def test_an_unknown_scene_is_a_one_line_error(capsys, tmp_path):
    assert main(["bench", "seeding", "--scenes", "nope", "--out", str(tmp_path)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]
    assert not list(tmp_path.iterdir())  # nothing simulated


def test_every_true_object_of_a_scene_gets_a_row(capsys, tmp_path):
    assert main(["bench", "seeding", "--scenes", "enter_leave", "--out", str(tmp_path)]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| enter_leave |")]
    names = sorted({r.split("|")[4].strip() for r in rows})
    assert names == ["box", "sphere"]
    for row in rows[-2:]:  # the closing table's
        cells = [c.strip() for c in row.split("|")[1:-1]]
        assert int(cells[2]) >= 1  # objects seeded
        assert float(cells[5]) >= 0.0  # a median distance, in px
