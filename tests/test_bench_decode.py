"""`evsplat bench decode` runs end to end on small recordings: every decoder's events match the
generator's (the 'same' column) and every row of its table is printed."""

from __future__ import annotations

import json

import numpy as np

from evsplat.bench.decode import synthetic_chunks
from evsplat.cli import main


def test_bench_decode_prints_every_row_and_every_decoder_agrees(tmp_path, capsys):
    args = ["bench", "decode", "--events=30000", "--repeat=1", f"--dir={tmp_path}", "--json"]
    assert main(args) == 0
    rows = json.loads(capsys.readouterr().out)
    references = {"evt3": "evt3", "evt2": "expelliarmus", "dat": "expelliarmus"}
    references |= {"bag": "rosbags", "bag-lz4": "rosbags", "mcap": "rosbags"}
    references |= {"mcap-zstd": "rosbags", "mcap-split": "rosbags", "mcap-message": "rosbags"}
    references |= {"mcap-file": "rosbags", "db3": "rosbags"}
    references |= {"db3-message": "rosbags", "db3-file": "rosbags", "aedat4": "aedat"}
    for fmt, reference in references.items():
        what = {r["what"]: r for r in rows if r["format"] == fmt}
        for name in ("disk read, O_DIRECT", "disk read, cold", "disk read, warm"):
            assert what[name]["wall_s"] > 0
        for name in ("rust decoder, warm", "rust decoder, cold", f"{reference}, warm"):
            assert what[name]["same"] is True, (fmt, name)
    assert not list(tmp_path.iterdir())  # the recordings are deleted


def test_synthetic_events_are_sorted_row_runs_inside_the_sensor():
    chunks = list(synthetic_chunks(50_000, 10e6, seed=1, size=1 << 14))
    x, y, t, p = (np.concatenate([c[i] for c in chunks]) for i in range(4))
    assert len(t) == 50_000 and np.all(np.diff(t) >= 0)
    assert x.max() < 1280 and y.max() < 720 and set(np.unique(p)) == {0, 1}
    # Neighbouring pixels of one row at one time: most events continue a run.
    run = (np.diff(x.astype(int)) == 1) & (np.diff(y.astype(int)) == 0) & (np.diff(t) == 0)
    assert run.mean() > 0.5
