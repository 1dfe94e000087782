"""A recording's events on the training device, accumulated there: the ESI and event mask of an
index range by scatter-add (``torch.bincount``) instead of the Rust core's host loop, so a CUDA
run sends no event image across the bus.

Each event is held as one int32 count slot ``2 * (y * width + x) + (p < 0)``, as
crates/events/src/accumulate.rs counts them; the ESI is ``C+ n+ - C- n-`` per pixel in float64
with the thresholds rounded to float32 (the core's types), rounded once to float32, and the mask
is "any event". Integer counts make the result exact and independent of event order.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch
from torch import Tensor

from evsplat.data.event_files import READ_CHUNK
from evsplat.data.event_store import EventStore
from evsplat.errors import EvsplatError

#: Device memory the events may take (documented choice: 1 GiB, 268 M events at 4 bytes each;
#: a 16 GiB GPU keeps most of its memory for the model). A recording that fits is sent once;
#: a longer one is read through the EventStore a window at a time.
BUDGET_BYTES = 1 << 30
SLOT_BYTES = 4


class DeviceEvents:
    """The events of ``store`` on ``device``; ``accumulate`` is ``EventStore.accumulate`` there.

    The whole recording is held when it fits ``budget_bytes``, else the last window read (in
    pieces of at most the budget), reused while later windows fall inside it."""

    def __init__(
        self,
        store: EventStore,
        c_pos: float,
        c_neg: float,
        device: torch.device | str,
        budget_bytes: int = BUDGET_BYTES,
    ):
        if store.transforms:
            raise EvsplatError(
                f"{store.source}: events rectified as read are accumulated by the Rust core; "
                "device events need an undistorted recording"
            )
        self.store = store
        self.device = torch.device(device)
        self.width, self.height = store.width, store.height
        # The core takes the thresholds as float32: the same values here.
        self.c_pos, self.c_neg = float(np.float32(c_pos)), float(np.float32(c_neg))
        self.capacity = max(int(budget_bytes) // SLOT_BYTES, 1)
        self.whole = store.count <= self.capacity
        self._base = 0
        self._slots = self._load(0, store.count if self.whole else 0)

    def _load(self, i0: int, i1: int) -> Tensor:
        """Count slots of events [i0, i1), read in slices of READ_CHUNK and sent to the device."""
        parts = [torch.zeros(0, dtype=torch.int32, device=self.device)]
        for s in range(i0, i1, READ_CHUNK):
            ev = self.store.events(s, min(s + READ_CHUNK, i1))
            pixel = ev.y.astype(np.int32) * self.width + ev.x
            slots = 2 * pixel + (ev.p < 0)
            parts.append(torch.from_numpy(slots.astype(np.int32)).to(self.device))
        return torch.cat(parts)

    def _pieces(self, i0: int, i1: int) -> Iterator[Tensor]:
        """The slots of events [i0, i1) on the device, in pieces of at most ``capacity``."""
        if self.whole:
            yield self._slots[i0:i1]
            return
        for a in range(i0, i1, self.capacity):
            b = min(a + self.capacity, i1)
            if not self._base <= a <= b <= self._base + len(self._slots):
                self._slots = self._slots[:0]  # the old piece is freed before the new one
                self._base, self._slots = a, self._load(a, b)
            yield self._slots[a - self._base : b - self._base]

    def accumulate(self, i0: int, i1: int) -> tuple[Tensor, Tensor, int]:
        """(ESI float32 [H,W], event mask bool [H,W], event count) of events [i0, i1) on the
        device, as ``EventStore.accumulate`` gives them on the host."""
        pixels = self.width * self.height
        counts = torch.zeros(2 * pixels, dtype=torch.int64, device=self.device)
        for slots in self._pieces(int(i0), int(i1)):
            counts += torch.bincount(slots, minlength=2 * pixels)
        n = counts.view(pixels, 2)
        esi = self.c_pos * n[:, 0].double() - self.c_neg * n[:, 1].double()
        mask = (n[:, 0] + n[:, 1]) > 0
        shape = (self.height, self.width)
        return esi.float().view(shape), mask.view(shape), int(n.sum())
