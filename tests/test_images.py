"""PNG/EXR files: round trips within quantisation, shapes, atomic writes, one-line errors."""

import numpy as np
import pytest

from evsplat.data.images import read_exr, read_png, write_exr, write_png
from evsplat.errors import EvsplatError


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3)])
def test_png_round_trip_is_within_half_a_quantisation_step(tmp_path, bits, shape):
    img = np.random.default_rng(0).uniform(0, 1, shape).astype(np.float32)
    write_png(tmp_path / "a.png", img, bits=bits)
    back = read_png(tmp_path / "a.png")
    assert back.shape == shape and back.dtype == np.float32
    assert np.abs(back - img).max() <= 0.5 / (2**bits - 1) + 1e-6
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_png_values_are_clamped_and_nan_becomes_zero(tmp_path):
    write_png(tmp_path / "a.png", np.array([[-1.0, 2.0, np.nan]], dtype=np.float32))
    assert read_png(tmp_path / "a.png").tolist() == [[0.0, 1.0, 0.0]]


def test_exr_depth_round_trip_is_bit_exact(tmp_path):
    d = np.random.default_rng(1).uniform(0.1, 50, (9, 13)).astype(np.float32)
    write_exr(tmp_path / "d.exr", d)
    back = read_exr(tmp_path / "d.exr")
    assert back.dtype == np.float32 and np.array_equal(back, d)


def test_image_errors_are_one_line(tmp_path):
    with pytest.raises(EvsplatError, match="file not found"):
        read_png(tmp_path / "missing.png")
    with pytest.raises(EvsplatError, match=r"\[H,W\]"):
        write_exr(tmp_path / "d.exr", np.zeros((2, 2, 2), np.float32))
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(EvsplatError, match="bad.png: not a readable image"):
        read_png(tmp_path / "bad.png")
    with pytest.raises(EvsplatError, match="bad.png: not a readable EXR"):
        read_exr(tmp_path / "bad.png")
