"""The README's real-data walkthrough starts from a bag that docs/make_bag.py writes from a
simulated dataset: the bag must convert back to the dataset's own events and poses."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from evsplat.cli import main
from evsplat.data.event_files import read_events
from evsplat.data.poses import read_tum

MAKE_BAG = Path(__file__).resolve().parents[1] / "docs" / "make_bag.py"


def test_make_bag_converts_back_to_the_simulated_events_and_poses(tiny_scene, tmp_path):
    sim = tiny_scene("ball")
    bag = tmp_path / "recording.bag"
    subprocess.run([sys.executable, str(MAKE_BAG), str(sim), str(bag)], check=True)
    out = tmp_path / "data"
    out.mkdir()
    argv = ["convert", str(bag), str(out / "events.h5"), "--poses", str(out / "poses.txt")]
    assert main(argv) == 0

    want, got = read_events(sim / "events.h5"), read_events(out / "events.h5")
    assert len(got) == len(want) > 0
    for k in "xyt":
        np.testing.assert_array_equal(getattr(got, k), getattr(want, k))
    np.testing.assert_array_equal(got.p > 0, want.p > 0)
    t_want, m_want = read_tum(sim / "poses.txt")
    t_got, m_got = read_tum(out / "poses.txt")
    np.testing.assert_array_equal(t_got, t_want)
    np.testing.assert_allclose(m_got, m_want, atol=1e-6)
