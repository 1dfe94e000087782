"""Recordings from other tools: the readers on real files that registry packages ship (only
`aedat`'s sdist has any; docs/results.md, issue 24), compared event by event with an
independent decoder (dv-processing, iniVation's C++ library) and with the digests the `aedat`
package's own tests assert for its decoder. tests/data/README.md says where each file comes
from and how it was cut down."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from evsplat.cli import main
from evsplat.data.event_files import read_events
from evsplat.data.formats import open_source
from evsplat.errors import EvsplatError

DATA = Path(__file__).resolve().parent / "data"
#: The DAVIS346 recording of aedat 2.3.0's tests, events and triggers only (695 KB).
DAVIS346 = DATA / "aedat_davis346_events.aedat4"
#: The whole original, frames included (6 MB): scripts/fetch_samples.sh puts it here.
DAVIS346_FULL = Path(os.environ.get("EVSPLAT_AEDAT_SAMPLE", DATA / "external" / "test_data.aedat4"))
#: SHA3-224 of the event columns (t u64, x u16, y u16, on bool; little-endian), as the aedat
#: package's tests/assets.py asserts them for its decoder on test_data.aedat4.
AEDAT_DIGESTS = {
    "t": "f1e093cad5afb6ecb971dfa2ef7646ab4ae0f467f73a48804e40bb68",
    "x": "1d8ea97b0febadfde24dd0b9e608682fc6934fc88656823b15f0e7a7",
    "y": "18f89da35f8f10b24c3407b03aa7f82bdd7c8e6ab5369e2c30f8bad0",
    "on": "6f99cf01187da8a05e1a032f3782de51b87e51bdc31356669bdd7cb9",
}
N_EVENTS = 78_830


def _dv_processing_events(path: Path) -> np.ndarray:
    """Every event of the file as dv-processing's reader gives them (timestamp, x, y,
    polarity)."""
    dv = pytest.importorskip("dv_processing")
    reader = dv.io.MonoCameraRecording(str(path))
    parts = []
    while reader.isRunning():
        batch = reader.getNextEventBatch()
        if batch is not None and len(batch):
            parts.append(batch.numpy())
    return np.concatenate(parts)


def _ours(path: Path):
    source = open_source(path)
    chunks = list(source.chunks)
    x, y, t, p = (np.concatenate([c[i] for c in chunks]) for i in range(4))
    return source, x, y, t, p


def _assert_matches_dv_processing_and_aedat_digests(path: Path) -> None:
    source, x, y, t, p = _ours(path)
    assert (source.width, source.height) == (346, 260)
    assert len(t) == N_EVENTS
    columns = {"t": t.astype("<u8"), "x": x.astype("<u2"), "y": y.astype("<u2"), "on": p > 0}
    for name, column in columns.items():
        digest = hashlib.sha3_224(column.tobytes()).hexdigest()
        assert digest == AEDAT_DIGESTS[name], name
    ref = _dv_processing_events(path)  # skips here when dv-processing is not installed
    np.testing.assert_array_equal(x, ref["x"])
    np.testing.assert_array_equal(y, ref["y"])
    np.testing.assert_array_equal(t, ref["timestamp"])
    np.testing.assert_array_equal(np.asarray(p) > 0, ref["polarity"] > 0)


def test_davis346_recording_from_aedat_matches_dv_processing_and_aedats_digests():
    _assert_matches_dv_processing_and_aedat_digests(DAVIS346)


def test_davis346_recording_converts_and_validates(tmp_path, capsys):
    out = tmp_path / "davis.h5"
    assert main(["convert", str(DAVIS346), str(out)]) == 0
    assert f"wrote {N_EVENTS} events" in capsys.readouterr().out
    ev = read_events(DAVIS346)
    with h5py.File(out) as f:
        assert (f.attrs["width"], f.attrs["height"]) == (346, 260)
        np.testing.assert_array_equal(f["events/t"][:] + f["t_offset"][()], ev.t)
        np.testing.assert_array_equal(f["events/p"][:], ev.p)


@pytest.mark.skipif(
    not DAVIS346_FULL.is_file(),
    reason=f"{DAVIS346_FULL} is absent (6 MB, not vendored): run scripts/fetch_samples.sh "
    "or set EVSPLAT_AEDAT_SAMPLE to aedat 2.3.0's tests/data/test_data.aedat4",
)
def test_whole_davis346_recording_with_frames_matches_dv_processing_and_aedats_digests():
    _assert_matches_dv_processing_and_aedat_digests(DAVIS346_FULL)


def test_frame_only_recording_from_aedat_fails_with_one_line_naming_the_file():
    path = DATA / "aedat_gray16_frame.aedat4"
    with pytest.raises(EvsplatError, match="no event stream \\(streams: frame\\)") as err:
        open_source(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
