"""TUM and transforms.json pose files: exact times, round trips, one-line errors."""

import json

import numpy as np
import pytest

from evsplat.data.poses import (
    matrix_to_quat,
    quat_to_matrix,
    read_transforms_json,
    read_tum,
    write_transforms_json,
    write_tum,
)
from evsplat.errors import EvsplatError


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = quat_to_matrix(q)
    m[:, :3, 3] = rng.normal(size=(n, 3))
    return m


def test_quaternion_conversion_round_trips_including_near_180_degrees():
    q = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [1e-9, 0, 0.6, 0.8], [0.5, 0.5, -0.5, 0.5]])
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    back = matrix_to_quat(quat_to_matrix(q))
    assert np.allclose(np.abs(np.sum(back * q, axis=1)), 1, atol=1e-12)
    r = quat_to_matrix(back)
    assert np.allclose(np.einsum("nji,njk->nik", r, r), np.eye(3), atol=1e-12)


def test_tum_round_trip_keeps_times_exact_and_poses_to_1e_12(tmp_path):
    t = np.array([0, 1, 999_999, 1_700_000_000_123_456, 1_700_000_000_123_457], dtype=np.int64)
    m = random_poses(5)
    write_tum(tmp_path / "p.txt", t, m)
    t2, m2 = read_tum(tmp_path / "p.txt")
    assert t2.dtype == np.int64 and np.array_equal(t2, t)
    assert np.abs(m2 - m).max() < 1e-12
    assert [p.name for p in tmp_path.iterdir()] == ["p.txt"]  # no temporary left


def test_tum_seconds_are_parsed_exactly_and_comments_skipped(tmp_path):
    (tmp_path / "p.txt").write_text(
        "# t tx ty tz qx qy qz qw\n\n"
        "1700000000.123456 1 2 3 0 0 0 1\n"
        "1700000000.1234575 0 0 0 0 0 0 1\n"
    )
    t, m = read_tum(tmp_path / "p.txt")
    assert t.tolist() == [1_700_000_000_123_456, 1_700_000_000_123_458]  # half-µs rounds to even
    assert np.allclose(m[0, :3, 3], [1, 2, 3]) and np.allclose(m[0, :3, :3], np.eye(3))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "0.0 0 0 0 0 0 0 1\n0.0 0 0 0 0 0 0 1\n",
            r"p\.txt: pose times not strictly increasing at index 1",
        ),
        ("0.0 0 0 0 0 0 0 1\n0.1 0 0 0 nan 0 0 1\n", r"p\.txt:2: NaN"),
        ("0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0\n", r"p\.txt:2: expected 8 values"),
        ("0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 2\n", r"p\.txt:2: quaternion norm"),
        ("0.0 0 0 0 0 0 0 1\n0.1 a 0 0 0 0 0 1\n", r"p\.txt:2: not a number"),
        ("# only a comment\n", r"p\.txt: no poses"),
    ],
    ids=[
        "non_monotonic",
        "nan_quaternion",
        "short_line",
        "non_unit_quaternion",
        "garbage",
        "empty",
    ],
)
def test_bad_tum_files_give_one_line_errors(tmp_path, text, match):
    (tmp_path / "p.txt").write_text(text)
    with pytest.raises(EvsplatError, match=match) as e:
        read_tum(tmp_path / "p.txt")
    assert "\n" not in str(e.value)


def test_missing_pose_file_is_a_one_line_error(tmp_path):
    with pytest.raises(EvsplatError, match="cannot read pose file"):
        read_tum(tmp_path / "nope.txt")


def test_write_tum_with_bad_poses_leaves_nothing_behind(tmp_path):
    m = random_poses(3)
    m[1, 0, 0] = np.nan
    with pytest.raises(EvsplatError, match="NaN"):
        write_tum(tmp_path / "p.txt", np.array([0, 1, 2]), m)
    assert list(tmp_path.iterdir()) == []


def test_transforms_json_round_trip_with_intrinsics(tmp_path):
    t = np.array([10, 20, 35], dtype=np.int64)
    m = random_poses(3, seed=3)
    K = np.array([[100.0, 0, 48], [0, 100, 48], [0, 0, 1]])
    write_transforms_json(tmp_path / "transforms.json", t, m, K=K, width=96, height=96)
    t2, m2 = read_transforms_json(tmp_path / "transforms.json")
    assert np.array_equal(t2, t) and np.array_equal(m2, m)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    assert doc["w"] == 96 and doc["fl_x"] == 100.0


def test_transforms_json_errors_name_the_frame(tmp_path):
    (tmp_path / "t.json").write_text(json.dumps({"frames": [{"time_us": 1}]}))
    with pytest.raises(EvsplatError, match="frame 0 needs"):
        read_transforms_json(tmp_path / "t.json")
    (tmp_path / "t.json").write_text("{")
    with pytest.raises(EvsplatError, match="not valid JSON"):
        read_transforms_json(tmp_path / "t.json")
