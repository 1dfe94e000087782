"""`evsplat bench seeding` scores each true object by the seeded objects drawn nearest its path:
checked on paths whose distances are known, and end to end on a built-in scene against its true
objects."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evsplat.bench.seeding import (
    Score,
    follow_score,
    nearest,
    partly_in_view,
    summary,
    turn_error,
)
from evsplat.cli import main


def _truth(times: int = 20) -> np.ndarray:
    t = np.linspace(0.0, 1.0, times)
    return np.stack([10.0 + 60.0 * t, 40.0 + 20.0 * np.sin(3.0 * t)], 1)


def test_the_nearest_drawn_object_follows_and_its_steady_offset_is_taken_out():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    seen[:4] = False  # out of the image: not scored
    near = truth + np.array([3.0, 4.0])  # 5 px off, steadily
    near[:4] += 100.0
    far = truth + np.array([30.0, 0.0])
    drawn = np.ones((2, len(truth)), dtype=bool)
    followed, median, steady, p90, missed = follow_score(
        *nearest(np.stack([far, near]), drawn, truth), seen
    )
    assert followed == [1]
    assert median == pytest.approx(5.0)
    assert steady == pytest.approx(0.0, abs=1e-9)
    assert p90 == pytest.approx(5.0)
    assert missed == 0.0


def test_an_object_hidden_outside_its_span_hands_over_or_is_missed():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    first, second = truth + np.array([1.0, 0.0]), truth + np.array([0.0, 2.0])
    drawn = np.zeros((2, len(truth)), dtype=bool)
    drawn[0, :8] = True  # the first track ends, the second starts later
    drawn[1, 10:] = True
    followed, median, _, _, missed = follow_score(
        *nearest(np.stack([first, second]), drawn, truth), seen
    )
    assert followed == [1, 0]  # 10 times the second, 8 the first
    assert median == pytest.approx(2.0)  # 8 at 1 px, 10 at 2 px
    assert missed == pytest.approx(2 / 20)


def test_an_offset_that_changes_is_not_taken_out():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    jitter = np.zeros_like(truth)
    jitter[:, 0] = np.where(np.arange(len(truth)) % 2 == 0, 2.0, -2.0)  # 2 px right, then left
    drawn = np.ones((1, len(truth)), dtype=bool)
    _, median, steady, _, _ = follow_score(*nearest(jitter[None] + truth, drawn, truth), seen)
    assert median == pytest.approx(2.0)
    assert steady == pytest.approx(2.0)  # the median offset is none


def test_nothing_seeded_or_never_seen_scores_none():
    truth = _truth()
    seen = np.ones(len(truth), dtype=bool)
    empty = nearest(np.zeros((0, len(truth), 2)), np.zeros((0, len(truth)), bool), truth)
    assert follow_score(*empty, seen) == ([], None, None, None, 1.0)
    drawn = np.ones((1, len(truth)), dtype=bool)
    unseen = np.zeros(len(truth), dtype=bool)
    assert follow_score(*nearest(truth[None], drawn, truth), unseen)[:4] == ([], None, None, None)


def _score(scene: str, setting: str, name: str, by: list[int], median: float | None) -> Score:
    return Score(scene, setting, 2, name, by, median, median, median, 0.0, None, None, 1.0)


def test_the_summary_counts_each_setting_over_all_scenes():
    scores = [
        # scene a: both true objects followed most by seeded object 0 (drawn as one)
        _score("a", "defaults", "box", [0], 1.0),
        _score("a", "defaults", "ball", [0, 1], 2.5),
        # scene b: object 0 again, but of another scene; one true object never followed
        _score("b", "defaults", "card", [0], 1.5),
        _score("b", "defaults", "sphere", [], None),
        _score("a", "mover.gate=2", "box", [0], 4.0),
        _score("a", "mover.gate=2", "ball", [1], 0.5),
    ]
    header, rule, *rows = summary(scores)
    assert header.startswith("| setting | true objects | within 1.5 px | within 3 px |")
    assert rule.count("|") == header.count("|")
    cells = [[c.strip() for c in row.strip("|").split("|")] for row in rows]
    # setting, objects, <=1.5, <=3, by two or more, drawn as one, by none, median of medians
    assert cells[0] == ["defaults", "4", "2", "3", "1", "2", "1", "2.0"]
    assert cells[1] == ["mover.gate=2", "2", "1", "1", "0", "0", "0", "2.2"]
    none_seen = summary([_score("c", "defaults", "box", [], None)])[2]
    assert none_seen.strip("|").split("|")[-1].strip() == "-"


def test_an_object_is_partly_in_view_where_its_centre_is_out_and_its_disc_over_the_image():
    # A 96 x 64 image; discs of 10 px: inside, 6 px beyond the right border (its left edge in
    # view), 12 px beyond it (out of view), 5 px beyond a corner on each axis (7.1 px from it: in
    # view), and 10 px beyond the top with no radius known.
    centres = np.array([[50.0, 30.0], [102.0, 30.0], [108.0, 30.0], [-5.0, -5.0], [40.0, -10.0]])
    radii = np.array([10.0, 10.0, 10.0, 10.0, 0.0])
    inside, partly = partly_in_view(centres, radii, 96, 64)
    assert inside.tolist() == [True, False, False, False, False]
    assert partly.tolist() == [False, True, False, True, False]


def test_turn_error_is_the_angle_between_the_seeded_and_the_true_turn_from_the_reference():
    t = np.linspace(0.0, 0.6, 31)
    start = Rotation.from_rotvec([0.3, -1.0, 2.0])  # the true object's orientation at t = 0
    true = (Rotation.from_rotvec(t[:, None] * [0.0, 5.0, 0.0]) * start).as_matrix()
    seen = np.ones(len(t), dtype=bool)
    exact = Rotation.from_rotvec((t[:, None] - 0.2) * [0.0, 5.0, 0.0]).as_quat()  # ref 0.2 s
    assert turn_error(np.roll(exact, 1, axis=1), true, seen) == pytest.approx(0.0, abs=1e-6)
    none = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))  # not turned: off by 5 rad/s x |t - 0|
    want = np.degrees(np.median(5.0 * t))
    assert turn_error(none, true, seen) == pytest.approx(want, rel=1e-6)
    # Placed at 0.2 s (its seeded shift is zero there): its missing turn counts from there.
    shift = np.abs(t - 0.2)
    want = np.degrees(np.median(5.0 * np.abs(t - 0.2)))
    assert turn_error(none, true, seen, shift) == pytest.approx(want, rel=1e-6)
    assert turn_error(np.roll(exact, 1, axis=1), true, seen, shift) == pytest.approx(0, abs=1e-6)
    assert turn_error(none, true, np.zeros(len(t), dtype=bool)) is None


def test_an_unknown_scene_is_a_one_line_error(capsys, tmp_path):
    assert main(["bench", "seeding", "--scenes", "nope", "--out", str(tmp_path)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]
    assert not list(tmp_path.iterdir())  # nothing simulated


def test_every_true_object_of_a_scene_gets_a_row_and_a_kept_warm_up_seeds_the_same(
    capsys, tmp_path
):
    args = ["bench", "seeding", "--scenes", "enter_leave", "--out", str(tmp_path)]
    kept = ["--warm-ups", str(tmp_path / "kept")]
    assert main(args + kept) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| enter_leave |")]
    assert [p.name for p in (tmp_path / "kept").iterdir()] == ["enter_leave-seed0-iters2000.pt"]
    assert main(args + kept) == 0  # from the kept warm-up: the same objects and distances
    again = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| enter_leave |")]
    assert [r.split("|")[:-2] for r in again] == [r.split("|")[:-2] for r in rows]
    names = sorted({r.split("|")[4].strip() for r in rows})
    assert names == ["box", "sphere"]
    for row in rows[-2:]:  # the closing table's
        cells = [c.strip() for c in row.split("|")[1:-1]]
        assert int(cells[2]) >= 1  # objects seeded
        assert float(cells[5]) >= 0.0  # a median distance, in px
        assert 0.0 <= float(cells[9]) <= 180.0  # the turn's error, degrees


def test_an_unreadable_kept_warm_up_is_a_one_line_error(capsys, tmp_path):
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "enter_leave-seed0-iters2000.pt").write_text("not torch\n")
    args = ["--scenes", "enter_leave", "--out", str(tmp_path), "--warm-ups", str(tmp_path / "kept")]
    assert main(["bench", "seeding", *args]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "enter_leave-seed0-iters2000.pt" in err[0] and "delete" in err[0]
