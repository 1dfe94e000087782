"""Event files: HDF5 (DSEC-style ``events/{x,y,t,p}`` or flat ``/x,/y,/t,/p``, any
hdf5plugin codec), ``.npz`` and text (``t x y p`` per line), read whole into an
:class:`EventStream` (``evsplat.data.event_store`` reads an HDF5 file by time window instead;
``evsplat.data.event_writer`` writes one).

Sensor size, when neither the file (attributes ``width``/``height``) nor the caller gives it,
is ``max(x) + 1`` by ``max(y) + 1``: the smallest sensor holding every event.
Timestamps: integer files hold microseconds; float timestamps are seconds. Text files are
detected from the first event (a ``.``, ``e`` or ``E`` in t means seconds); ``time_unit``
("s" or "us") overrides the detection for every format.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator
from pathlib import Path

import h5py
import hdf5plugin  # noqa: F401  (registers the Blosc/zstd/LZ4 codecs used by DSEC-style files)
import numpy as np

from evsplat.data import formats
from evsplat.data.events import MAX_SIDE, EventStream, coords_uint16
from evsplat.errors import EvsplatError

#: Events per read when streaming an HDF5 dataset.
READ_CHUNK = 1 << 22
#: Lines per parse when streaming a text file (their strings are the temporary memory).
TEXT_CHUNK = 1 << 20

_H5 = (".h5", ".hdf5")
_TEXT = (".txt", ".csv")


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def read_events(
    path: str | os.PathLike,
    *,
    time_unit: str | None = None,
    width: int | None = None,
    height: int | None = None,
) -> EventStream:
    """Reads an event file chosen by extension (.h5/.hdf5, .npz, .txt/.csv, and the sensor
    recordings of :mod:`evsplat.data.formats`: .aedat4, .raw, .dat, ROS bags) into a validated
    stream. ``width``/``height`` override the file's sensor size; ``time_unit`` ("s"/"us")
    overrides the timestamp unit. Errors are EvsplatErrors naming the file and the fix."""
    path = Path(path)
    src = str(path)
    if time_unit not in (None, "s", "us"):
        raise EvsplatError(f"{src}: time_unit {time_unit!r} is unknown; use 's' or 'us'")
    if formats.is_sensor_format(path):
        # Sensor recordings carry their own time unit (µs) and sensor size.
        return formats.read_source(formats.open_source(path))
    if not path.is_file():
        raise EvsplatError(f"{src}: no such file; check the path")
    if path.stat().st_size == 0:
        raise EvsplatError(f"{src}: file is empty; expected events (x, y, t, p)")
    suffix = path.suffix.lower()
    size: dict = {}
    if suffix in _H5:
        x, y, t, p, size = _read_h5(path)
    elif suffix == ".npz":
        x, y, t, p, size = _read_npz(path)
    elif suffix in _TEXT:
        x, y, t, p, detected = _read_text(path)
        time_unit = time_unit or detected
    else:
        raise EvsplatError(
            f"{src}: unknown event file type '{suffix}'; use .h5/.hdf5, .npz, .txt, .csv or "
            f"a recording ({', '.join(formats.KNOWN_SUFFIXES)})"
        )
    t = _to_microseconds(t, time_unit)
    w = width if width is not None else size.get("width")
    h = height if height is not None else size.get("height")
    if w is None or h is None:
        # Sensor size from the events themselves: cast first (checked), then max + 1.
        x = coords_uint16(x, "x", MAX_SIDE, src)
        y = coords_uint16(y, "y", MAX_SIDE, src)
        if len(x) == 0:
            raise EvsplatError(f"{src}: no events and no sensor size; pass width and height")
        w = int(x.max()) + 1 if w is None else w
        h = int(y.max()) + 1 if h is None else h
    return EventStream.from_arrays(x, y, t, p, w, h, source=src)


def _to_microseconds(t: np.ndarray, time_unit: str | None) -> np.ndarray:
    """Seconds (time_unit "s", or float timestamps when it is None) become whole µs; µs pass
    through (whole-numbered floats are cast, with checks, by EventStream.from_arrays)."""
    seconds = time_unit == "s" or (time_unit is None and t.dtype.kind == "f")
    if not seconds:
        return t
    with np.errstate(invalid="ignore"):
        # NaN stays NaN here and is reported, with its index, by the cast in from_arrays.
        return np.rint(np.asarray(t, np.float64) * 1e6)


def h5_events_group(f: h5py.File, src: str) -> h5py.Group:
    """The group holding the x, y, t, p datasets: ``events`` (DSEC layout) or the root."""
    group = f["events"] if isinstance(f.get("events"), h5py.Group) else f
    missing = [k for k in "xytp" if not isinstance(group.get(k), h5py.Dataset)]
    if missing:
        where = ", ".join(f"{group.name.rstrip('/')}/{k}" for k in missing)
        raise EvsplatError(
            f"{src}: missing dataset {where}; expected events/{{x,y,t,p}} (DSEC "
            "layout) or /x, /y, /t, /p"
        )
    return group


def h5_t_offset(f: h5py.File) -> int:
    """DSEC's ``t_offset`` (µs): the stored t are relative to it; 0 when absent."""
    return int(f["t_offset"][()]) if "t_offset" in f else 0


def h5_sensor_size(f: h5py.File, group: h5py.Group) -> dict:
    """``width``/``height`` attributes of the events group or the file, those present."""
    size = {}
    for k in ("width", "height"):
        for attrs in (group.attrs, f.attrs):
            if k in attrs:
                size[k] = int(np.asarray(attrs[k]).reshape(-1)[0])
                break
    return size


def h5_read_error(src: str, e: OSError) -> EvsplatError:
    return EvsplatError(
        f"{src}: cannot read HDF5 ({_one_line(e)}); the file is truncated, corrupt or not "
        "HDF5: re-export or re-download it"
    )


def _read_h5(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    src = str(path)
    try:
        with h5py.File(path, "r") as f:
            group = h5_events_group(f, src)
            x, y, t, p = (_read_dataset(group[k]) for k in "xytp")
            if "t_offset" in f:
                t = t + np.int64(h5_t_offset(f))
            return x, y, t, p, h5_sensor_size(f, group)
    except OSError as e:
        raise h5_read_error(src, e) from None


def _read_dataset(ds: h5py.Dataset) -> np.ndarray:
    """Reads a 1-D dataset chunk by chunk straight into one array (no second copy)."""
    if ds.ndim != 1:
        raise EvsplatError(
            f"{ds.file.filename}: dataset {ds.name} has shape {ds.shape}; expected one value "
            "per event (1-D)"
        )
    out = np.empty(ds.shape, ds.dtype)
    for s in range(0, len(out), READ_CHUNK):
        sel = np.s_[s : min(s + READ_CHUNK, len(out))]
        ds.read_direct(out, sel, sel)
    return out


def _read_npz(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    src = str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in "xytp" if k not in z.files]
            if missing:
                raise EvsplatError(
                    f"{src}: missing array {', '.join(missing)}; an event .npz holds x, y, t, p "
                    "(and optionally width, height)"
                )
            x, y, t, p = (z[k] for k in "xytp")
            size = {k: int(z[k]) for k in ("width", "height") if k in z.files}
            return x, y, t, p, size
    except (OSError, ValueError) as e:
        raise EvsplatError(
            f"{src}: cannot read .npz ({_one_line(e)}); the file is truncated or not a numpy "
            "archive"
        ) from None


def _data_lines(f: Iterator[str]) -> Iterator[str]:
    return (ln for ln in f if ln.strip() and not ln.lstrip().startswith("#"))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_text(
    path: Path,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, str]:
    """Parses ``t x y p`` lines (whitespace, or commas for .csv; '#' comments and a csv
    header line skipped) in chunks of TEXT_CHUNK lines with numpy's C parser. Also returns
    the detected time unit."""
    src = str(path)
    delimiter = "," if path.suffix.lower() == ".csv" else None
    blocks = []
    with open(path, encoding="utf-8", errors="replace") as f:
        lines = _data_lines(f)
        first = next(lines, None)
        if first is None:
            raise EvsplatError(f"{src}: no events (only comments or blank lines)")
        t_token = first.replace(",", " ").split()[0]
        if not _is_number(t_token):
            first = next(lines, None)  # a header line such as "t,x,y,p"
            if first is None:
                raise EvsplatError(f"{src}: no events after the header line")
            t_token = first.replace(",", " ").split()[0]
        float_time = any(c in t_token for c in ".eE")
        lines = itertools.chain([first], lines)
        while chunk := list(itertools.islice(lines, TEXT_CHUNK)):
            try:
                block = np.loadtxt(chunk, dtype=np.float64, delimiter=delimiter, ndmin=2)
            except ValueError as e:
                raise EvsplatError(
                    f"{src}: cannot parse events ({_one_line(e)}); expected 't x y p' per line"
                ) from None
            if block.shape[1] != 4:
                raise EvsplatError(
                    f"{src}: lines have {block.shape[1]} columns; expected 4 ('t x y p')"
                )
            blocks.append(block)
    cols = np.concatenate(blocks)
    unit = "s" if float_time else "us"
    return cols[:, 1], cols[:, 2], cols[:, 0], cols[:, 3], unit
