"""Scoring event prediction without frames (evsplat.event_prediction) and observed-ness
(evsplat.observed), against numpy's correlation and hand-built event images."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from evsplat.data.dataset import load_dataset
from evsplat.event_prediction import fallback_windows, pearson, predict_events
from evsplat.intensity import LOG_EPS
from evsplat.observed import GROW, masked, observed_map
from evsplat.render import RenderOut


def test_pearson_equals_numpys_corrcoef_and_is_undefined_for_a_constant() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(12, 17))
    b = 0.3 * a + rng.normal(size=(12, 17))
    assert pearson(a, b) == pytest.approx(np.corrcoef(a.ravel(), b.ravel())[0, 1], abs=1e-12)
    assert pearson(a, -2.0 * a + 5.0) == pytest.approx(-1.0, abs=1e-12)
    assert pearson(np.full((3, 3), 0.7), a[:3, :3]) is None


class ChangeOfEvents:
    """A stand-in renderer whose log image at t is ``gain`` times the ESI from the start to t
    (plus 1): its log change over any window is exactly gain x the window's ESI. With
    the MLP or the objects' motion off (None, as the static model is drawn) it draws a constant
    image."""

    def __init__(self, data, gain: float):
        self.data, self.gain = data, gain
        self.mlp, self.motion = object(), object()
        self.K = torch.from_numpy(data.K.astype(np.float32))  # the device Views reads it on

    def render(self, t_us: float, c2w: np.ndarray) -> RenderOut:
        store = self.data.events
        if self.mlp is None or self.motion is None:
            esi = np.zeros((self.data.height, self.data.width), np.float32)
        else:
            window = store.window(self.data.t_start_us, int(t_us))
            esi = store.accumulate(*window, self.data.c_pos, self.data.c_neg)[0]
        # The sensor sees log(I + LOG_EPS): that minus LOG_EPS makes it exactly gain x ESI + 1.
        log_image = self.gain * esi.astype(np.float64) + 1.0
        image = torch.from_numpy(np.exp(log_image) - LOG_EPS).float()
        image = image[..., None].expand(-1, -1, 3)  # grey: every Bayer channel sees it
        return RenderOut(image, image[..., 0], image[..., 0], {}, torch.zeros(0, 3))


@pytest.fixture(scope="module")
def ball(tiny_scene):
    return load_dataset(tiny_scene("ball"))


def test_a_render_whose_log_change_is_a_multiple_of_the_events_correlates_1(ball) -> None:
    windows = fallback_windows(ball.t_start_us, ball.t_end_us)
    renderer = ChangeOfEvents(ball, gain=0.6)
    result = predict_events(renderer, ball, [], lambda_ssim=0.2)
    assert result["windows_source"].startswith("the run held no windows out")
    assert [(w["t0_us"], w["t1_us"]) for w in result["windows"]] == windows
    scored = [w for w in result["windows"] if w["events"] > 0]
    assert len(scored) >= 12
    for w in scored:
        assert w["model"]["correlation"] == pytest.approx(1.0, abs=1e-5)
        # The static stand-in and the flat image predict no change: correlation 0.
        assert w["static"]["correlation"] == 0.0 and w["flat"]["correlation"] == 0.0
        assert w["static"]["l_e"] == pytest.approx(w["flat"]["l_e"])
    assert result["mean"]["model"]["correlation"] == pytest.approx(1.0, abs=1e-5)
    assert renderer.mlp is not None  # given back as found


def test_held_out_windows_are_the_ones_scored_and_must_lie_in_the_data(ball) -> None:
    held = [(ball.t_start_us + 10_000, ball.t_start_us + 40_000)]
    result = predict_events(ChangeOfEvents(ball, 1.0), ball, held, lambda_ssim=0.2)
    assert result["windows_source"].startswith("held out")
    assert [(w["t0_us"], w["t1_us"]) for w in result["windows"]] == held
    with pytest.raises(Exception, match="outside the dataset's time range"):
        predict_events(ChangeOfEvents(ball, 1.0), ball, [(0, ball.t_end_us + 1)], 0.2)


def test_observed_map_marks_the_pixels_with_events_outside_the_held_out_windows() -> None:
    # Events at three pixels at 100, 300 and 500 µs; the one at 300 µs lies in a held-out window.
    t = np.array([100, 300, 500], np.int64)
    ev = SimpleNamespace(x=np.array([1, 5, 9]), y=np.array([2, 4, 6]), t=t)

    class Store:
        width, height = 12, 8

        def window(self, t0, t1):
            return int(np.searchsorted(ev.t, t0)), int(np.searchsorted(ev.t, t1))

        def accumulate(self, i0, i1, c_pos, c_neg):
            mask = np.zeros((8, 12), bool)
            mask[ev.y[i0:i1], ev.x[i0:i1]] = True
            return None, mask, i1 - i0

    seen = observed_map(Store(), 0, 1000, [(250, 350)])
    want = np.zeros((8, 12), bool)
    for x, y in ((1, 2), (9, 6)):
        want[y - GROW : y + GROW + 1, x - GROW : x + GROW + 1] = True
    np.testing.assert_array_equal(seen, want)
    image = np.full((8, 12, 1), 0.9, np.float32)
    out = masked(image, seen, 0.5)
    assert np.all(out[seen] == 0.9) and np.all(out[~seen] == 0.5)
