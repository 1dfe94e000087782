"""The event core against the independent numpy reference (tests/reference/events_ref.py):
ESI, counts, masks, Bayer split, windows, sub-windows, patches and voxel grids on random
streams, sensor borders, empty windows, 2^40 µs offsets and a 10 M-event single-pixel flood."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evsplat.data.events import EventStream, bayer_channel_map
from evsplat.errors import EvsplatError
from tests.reference import events_ref as ref

PATTERNS = ["RGGB", "BGGR", "GRBG", "GBRG", "mono"]
SETTINGS = settings(max_examples=40, deadline=None)


@st.composite
def streams(draw, max_events: int = 300, max_side: int = 20) -> EventStream:
    """Random streams with repeated timestamps and extra weight on the sensor borders."""
    w = draw(st.integers(1, max_side))
    h = draw(st.integers(1, max_side))
    n = draw(st.integers(0, max_events))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    x = rng.integers(0, w, n)
    y = rng.integers(0, h, n)
    border = rng.random(n) < 0.3
    x[border] = rng.choice([0, w - 1], border.sum())
    y[border] = rng.choice([0, h - 1], border.sum())
    t = np.sort(rng.integers(0, 50, n)) + draw(st.sampled_from([0, 2**40]))
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return EventStream.from_arrays(x.astype(np.uint16), y.astype(np.uint16), t, p, w, h)


@st.composite
def stream_and_window(draw):
    ev = draw(streams())
    i0 = draw(st.integers(0, len(ev)))
    i1 = draw(st.integers(i0, len(ev)))
    return ev, i0, i1


def contrast(ev: EventStream, per_pixel: bool, seed: int, base: float):
    if not per_pixel:
        return base
    return np.random.default_rng(seed).uniform(0.05, 1.0, ev.shape).astype(np.float32)


def window_arrays(ev: EventStream, i0: int, i1: int):
    return ev.x[i0:i1], ev.y[i0:i1], ev.p[i0:i1]


def assert_float32_sums(got: np.ndarray, want: np.ndarray, counts: np.ndarray, step) -> None:
    """``got`` (float32 per-pixel sums of signed steps) equals the float64 reference ``want``
    to float32's rounding: summing n steps of at most ``step`` is off by at most n x step x eps
    (a pixel with 227 events of 0.3 read 0.0999988 for 0.1)."""
    bound = 1e-7 + counts * np.max(step) * np.finfo(np.float32).eps
    assert (np.abs(got.astype(np.float64) - want) <= bound).all(), np.abs(got - want).max()


@SETTINGS
@given(stream_and_window(), st.booleans(), st.integers(0, 1000))
def test_esi_count_and_mask_match_numpy_reference(case, per_pixel, seed):
    ev, i0, i1 = case
    cp, cn = contrast(ev, per_pixel, seed, 0.2), contrast(ev, per_pixel, seed + 1, 0.35)
    x, y, p = window_arrays(ev, i0, i1)
    want = ref.esi(x, y, p, ev.width, ev.height, cp, cn)
    got = ev.esi(i0, i1, cp, cn)
    assert got.dtype == np.float32 and got.shape == ev.shape
    counts = ref.count(x, y, ev.width, ev.height)
    assert_float32_sums(got, want, counts, [np.max(cp), np.max(cn)])
    assert ev.event_count(i0, i1).dtype == np.uint32
    np.testing.assert_array_equal(ev.event_count(i0, i1), counts)
    np.testing.assert_array_equal(ev.event_mask(i0, i1), counts > 0)
    esi2, mask2 = ev.esi_and_mask(i0, i1, cp, cn)
    np.testing.assert_array_equal(esi2, got)
    np.testing.assert_array_equal(mask2, counts > 0)


@SETTINGS
@given(stream_and_window(), st.sampled_from(PATTERNS), st.booleans())
def test_esi_by_channel_matches_reference_for_bayer_sensor(case, pattern, per_pixel):
    ev, i0, i1 = case
    cp, cn = contrast(ev, per_pixel, 3, 0.25), 0.3
    x, y, p = window_arrays(ev, i0, i1)
    want = ref.esi_by_channel(x, y, p, ev.width, ev.height, cp, cn, pattern)
    got = ev.esi_by_channel(i0, i1, cp, cn, pattern)
    assert got.shape == want.shape and got.dtype == np.float32
    counts = ref.count(x, y, ev.width, ev.height)
    assert_float32_sums(got, want, counts, [np.max(cp), cn])


@pytest.mark.parametrize("pattern", PATTERNS)
def test_bayer_channel_map_matches_reference(pattern):
    np.testing.assert_array_equal(bayer_channel_map(pattern, 7, 5), ref.bayer_map(pattern, 7, 5))
    assert bayer_channel_map(pattern, 7, 5).dtype == np.uint8


def test_unknown_bayer_pattern_is_a_one_line_error():
    ev = EventStream.from_arrays([0], [0], [0], [1], 2, 2)
    with pytest.raises(EvsplatError, match="unknown Bayer pattern 'RGB'"):
        ev.esi_by_channel(0, 1, 0.2, 0.2, "RGB")


@SETTINGS
@given(streams(), st.integers(-5, 60), st.integers(-5, 60))
def test_window_by_time_matches_searchsorted(ev, a, b):
    t0, t1 = (int(ev.t[0]) if len(ev) else 0) + a, (int(ev.t[0]) if len(ev) else 0) + b
    i0, i1 = ev.window(t0, t1)
    want0 = int(np.searchsorted(ev.t, t0, "left"))
    want1 = max(want0, int(np.searchsorted(ev.t, t1, "left")))
    assert (i0, i1) == (want0, want1)
    assert np.all((ev.t[i0:i1] >= t0) & (ev.t[i0:i1] < t1))


def test_window_by_count_clips_to_the_stream():
    ev = EventStream.from_arrays(np.zeros(10), np.zeros(10), np.arange(10), np.ones(10), 1, 1)
    assert ev.window_by_count(3, 4) == (3, 7)
    assert ev.window_by_count(8, 5) == (8, 10)
    assert ev.window_by_count(12, 5) == (10, 10)
    assert ev.window_by_count(-3, 2) == (0, 2)


@SETTINGS
@given(st.integers(0, 10_000), st.integers(0, 10_000), st.integers(1, 50))
def test_split_equal_count_matches_reference_and_balances_counts(a, n, m):
    ev = EventStream.from_arrays(
        np.zeros(a + n), np.zeros(a + n), np.zeros(a + n), np.ones(a + n), 1, 1
    )
    b = ev.split_equal_count(a, a + n, m)
    assert b.dtype == np.int64 and len(b) == m + 1
    np.testing.assert_array_equal(b, ref.split_bounds(a, a + n, m))
    sizes = np.diff(b)
    assert sizes.sum() == n and sizes.max() - sizes.min() <= 1


@SETTINGS
@given(
    stream_and_window(),
    st.integers(1, 4),
    st.integers(1, 5),
    st.sampled_from(["bilinear", "nearest"]),
    st.booleans(),
    st.integers(0, 2**32 - 1),
)
def test_patches_match_reference_including_borders(case, m, side, mode, moving, seed):
    ev, i0, i1 = case
    rng = np.random.default_rng(seed)
    n = 3
    shape = (n, m, 2) if moving else (n, 2)
    # Centres from well outside to well inside the sensor, some on exact pixel centres.
    centres = rng.uniform(-2.0, 2.0, shape)
    centres[..., 0] += rng.uniform(0, ev.width, shape[:-1])
    centres[..., 1] += rng.uniform(0, ev.height, shape[:-1])
    centres[0] = np.floor(centres[0]) + 0.5
    centres = centres.astype(np.float32)
    bounds = ev.split_equal_count(i0, i1, m)
    cp = contrast(ev, True, seed % 1000, 0.2)
    got, ok = ev.patches(centres, bounds, side, cp, 0.3, mode)
    want, want_ok = ref.patches(
        ev.x, ev.y, ev.p, ev.width, ev.height, centres, bounds, side, cp, 0.3, mode
    )
    assert got.shape == (n, m, side, side) and got.dtype == np.float32 and ok.dtype == bool
    np.testing.assert_array_equal(ok, want_ok)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    assert np.all(got[~ok] == 0)


def test_patch_of_a_single_event_is_centred_and_border_samples_are_invalid():
    ev = EventStream.from_arrays([0], [0], [0], [1], 4, 4)
    vals, ok = ev.patches(np.array([[0.5, 0.5]], np.float32), np.array([0, 1]), 3, 1.0, 1.0)
    # Sample (a, b) sits at centre + (b - 1, a - 1): row/column 0 of the patch is off-sensor.
    assert not ok[0, 0, 0].any() and not ok[0, 0, :, 0].any() and ok[0, 0, 1:, 1:].all()
    assert vals[0, 0, 1, 1] == 1.0 and vals[0, 0, 1, 2] == 0.0


@SETTINGS
@given(stream_and_window(), st.integers(1, 6))
def test_voxel_grid_matches_reference(case, bins):
    ev, i0, i1 = case
    want = ref.voxel_grid(
        ev.x[i0:i1], ev.y[i0:i1], ev.t[i0:i1], ev.p[i0:i1], ev.width, ev.height, bins
    )
    got = ev.voxel_grid(i0, i1, bins)
    assert got.shape == (bins, ev.height, ev.width) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_empty_window_gives_zero_images():
    ev = EventStream.from_arrays([1, 2], [0, 1], [5, 9], [1, -1], 3, 2)
    i0, i1 = ev.window(6, 6)
    assert i0 == i1
    assert not ev.esi(i0, i1, 0.2, 0.2).any() and not ev.event_mask(i0, i1).any()
    assert not ev.voxel_grid(i0, i1, 3).any()
    vals, ok = ev.patches(np.array([[1.0, 1.0]], np.float32), np.array([i0, i1]), 3, 0.2, 0.2)
    assert not vals.any() and ok.any()


def test_results_are_bit_identical_under_a_2_pow_40_microsecond_offset():
    rng = np.random.default_rng(7)
    n, w, h = 5000, 33, 17
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    t = np.sort(rng.integers(0, 200_000, n))
    p = rng.choice([-1, 1], n)
    base = EventStream.from_arrays(x, y, t, p, w, h)
    off = EventStream.from_arrays(x, y, t + 2**40, p, w, h)
    i0, i1 = base.window(50_000, 150_000)
    assert off.window(50_000 + 2**40, 150_000 + 2**40) == (i0, i1)
    bounds = base.split_equal_count(i0, i1, 4)
    np.testing.assert_array_equal(off.split_equal_count(i0, i1, 4), bounds)
    centres = rng.uniform(0, 17, (20, 2)).astype(np.float32)
    for f in (
        lambda e: e.esi(i0, i1, 0.2, 0.3),
        lambda e: e.esi_by_channel(i0, i1, 0.2, 0.3, "RGGB"),
        lambda e: e.voxel_grid(i0, i1, 5),
        lambda e: e.patches(centres, bounds, 5, 0.2, 0.3)[0],
    ):
        assert np.array_equal(f(base), f(off))


def test_single_pixel_flood_of_ten_million_events_is_exact():
    n, w, h = 10_000_000, 64, 48
    p = np.ones(n, np.int8)
    p[::3] = -1
    ev = EventStream.from_arrays(
        np.full(n, w - 1, np.uint16), np.full(n, h - 1, np.uint16), np.arange(n) + 2**40, p, w, h
    )
    npos, nneg = int(np.count_nonzero(p > 0)), int(np.count_nonzero(p < 0))
    # Thresholds are float32; the sum is exact, so only the final rounding to float32 remains.
    cp, cn = float(np.float32(0.2)), float(np.float32(0.3))
    esi = ev.esi(0, n, 0.2, 0.3)
    assert esi[h - 1, w - 1] == np.float32(cp * npos - cn * nneg)
    assert np.count_nonzero(esi) == 1
    assert ev.event_count(0, n)[h - 1, w - 1] == n
    assert ev.event_mask(0, n).sum() == 1
    vox = ev.voxel_grid(0, n, 4)
    assert np.isfinite(vox).all()
    # Each event's bilinear time weights sum to 1, so the bins sum to n+ - n-.
    np.testing.assert_allclose(vox[:, h - 1, w - 1].sum(), npos - nneg, rtol=1e-6)
    centre = np.array([[w - 0.5, h - 0.5]], np.float32)
    vals, _ = ev.patches(centre, ev.split_equal_count(0, n, 2), 1, 0.2, 0.3, "nearest")
    assert np.isclose(vals.sum(), 0.2 * npos - 0.3 * nneg, rtol=1e-6)


def test_from_arrays_keeps_canonical_arrays_without_copy_and_slices_are_views():
    x = np.array([0, 1, 2], np.uint16)
    t = np.array([1, 2, 3], np.int64)
    p = np.array([1, -1, 1], np.int8)
    ev = EventStream.from_arrays(x, x, t, p, 3, 3)
    assert ev.x is x and ev.t is t and ev.p is p
    s = ev.slice(1, 3)
    assert len(s) == 2 and np.shares_memory(s.t, t) and np.shares_memory(s.x, x)
    with pytest.raises(EvsplatError, match="outside the stream"):
        ev.slice(2, 5)


def test_from_arrays_casts_other_dtypes_without_loss():
    ev = EventStream.from_arrays(
        np.array([0.0, 3.0]),
        np.array([1, 2], np.int64),
        [10.0, 20.0],
        np.array([0, 1], np.uint8),
        4,
        3,
    )
    assert ev.x.dtype == np.uint16 and ev.t.dtype == np.int64 and ev.p.dtype == np.int8
    np.testing.assert_array_equal(ev.x, [0, 3])
    np.testing.assert_array_equal(ev.p, [-1, 1])
    np.testing.assert_array_equal(ev.t, [10, 20])


@pytest.mark.parametrize(
    ("arrays", "size", "message"),
    [
        (([0, 1], [0, 0], [5, 4], [1, 1]), (2, 2), r"timestamps not sorted at index 1 \(t=4 < 5\)"),
        (
            ([0, 2], [0, 0], [1, 2], [1, 1]),
            (2, 2),
            r"x outside the sensor at index 1 \(x=2 >= width 2\)",
        ),
        (([0, 0], [0, -1], [1, 2], [1, 1]), (2, 2), r"y negative at index 1 \(y=-1\)"),
        (([0, 0], [0, 0], [1, 2], [1, 3]), (2, 2), r"polarity 3 at index 1"),
        (([0, 0], [0], [1, 2], [1, 1]), (2, 2), r"different lengths \(x: 2, y: 1, t: 2, p: 2\)"),
        (([0.5], [0], [1], [1]), (2, 2), r"x is not an integer at index 0"),
        (([0], [0], [np.nan], [1]), (2, 2), r"t is not finite at index 0"),
        (([0, 0], [0, 0], [1, 2], [0, -1]), (2, 2), r"mixes the 0/1 and -1/\+1"),
        (([0], [0], [1], [1]), (0, 2), r"sensor width 0 is invalid"),
    ],
)
def test_malformed_arrays_give_one_line_errors_naming_the_source(arrays, size, message):
    with pytest.raises(EvsplatError, match=message) as err:
        EventStream.from_arrays(*arrays, *size, source="cam0.h5")
    assert str(err.value).startswith("cam0.h5: ") and "\n" not in str(err.value)


def test_contrast_map_of_wrong_shape_is_rejected():
    ev = EventStream.from_arrays([0], [0], [0], [1], 3, 2)
    with pytest.raises(EvsplatError, match=r"c_pos map has shape \(3, 2\)"):
        ev.esi(0, 1, np.ones((3, 2), np.float32), 0.2)
    with pytest.raises(EvsplatError, match="c_neg is not finite"):
        ev.esi(0, 1, 0.2, np.inf)


def test_large_window_counted_in_parallel_matches_reference():
    """Above the parallel threshold the window is split across threads and reduced."""
    rng = np.random.default_rng(11)
    n, w, h = 400_000, 640, 480
    ev = EventStream.from_arrays(
        rng.integers(0, w, n), rng.integers(0, h, n), np.arange(n), rng.choice([-1, 1], n), w, h
    )
    x, y, p = window_arrays(ev, 5, n)
    np.testing.assert_allclose(ev.esi(5, n, 0.2, 0.3), ref.esi(x, y, p, w, h, 0.2, 0.3), atol=1e-5)
    np.testing.assert_array_equal(ev.event_count(5, n), ref.count(x, y, w, h))


def test_stream_constructor_rejects_non_canonical_arrays():
    x = np.zeros(4, np.uint16)
    with pytest.raises(EvsplatError, match="contiguous 1-D uint16"):
        EventStream(x[::2], x[:2], np.zeros(2, np.int64), np.ones(2, np.int8), 1, 1)
