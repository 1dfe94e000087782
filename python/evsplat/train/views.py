"""What training compares: the dataset's event windows and the model's renders, in the
sensor's channels (one, or each pixel's Bayer channel of a colour render)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from evsplat.config import LossConfig
from evsplat.data.dataset import Dataset
from evsplat.data.events import bayer_channel_map
from evsplat.data.hot_pixels import hot_pixel_map
from evsplat.losses.event import bayer_select, log_render
from evsplat.losses.flow import linearized_brightness_change
from evsplat.render import Renderer, RenderOut
from evsplat.train.coarse import bin_events
from evsplat.train.device_events import DeviceEvents
from evsplat.train.heldout import Interval, free_spans, overlaps

#: Draws of a step's windows before one that overlaps the held-out intervals is shortened to
#: fit between them (``Views.draw_times``).
DRAW_TRIES = 16


@dataclass
class Views:
    """Event windows of ``data`` and log renders of ``renderer`` (the full-resolution one; a
    coarse renderer is passed as ``view`` where a method takes one), on the renderer's device."""

    data: Dataset
    renderer: Renderer
    channel_map: torch.Tensor | None  # [h,w] Bayer channel per pixel; None for a mono sensor
    # The events accumulated on the device (``train.device_events``); None: by the Rust core.
    device_events: DeviceEvents | None = None
    heldout: list[Interval] = field(default_factory=list)  # never read (``train.heldout``)
    # [h,w] bool where the windows are accumulated: the sensor's hot pixels
    # (``data.hot_pixels``), whose events no window holds; None where there are none.
    hot: torch.Tensor | None = None

    @classmethod
    def of(cls, data: Dataset, renderer: Renderer, heldout: list[Interval] | None = None) -> Views:
        """The views of ``data``'s sensor: one channel, or each pixel's Bayer channel; the
        ``heldout`` intervals are kept out of every window training reads, and so are the hot
        pixels' events. Off the CPU the event windows are accumulated on the device (rectified
        recordings excepted)."""
        device = renderer.K.device
        channel_map = None
        if data.bayer != "mono":
            cmap = bayer_channel_map(data.bayer, data.width, data.height)
            channel_map = torch.from_numpy(cmap.astype(np.int64)).to(device)
        events = None
        if device.type != "cpu" and not data.events.transforms:
            events = DeviceEvents(data.events, data.c_pos, data.c_neg, device)
        heldout = list(heldout or [])
        spans = free_spans(heldout, data.t_start_us, data.t_end_us)
        hot = hot_pixel_map(data.events, spans)
        at = events.device if events is not None else torch.device("cpu")
        held = torch.from_numpy(hot).to(at) if hot.any() else None
        return cls(data, renderer, channel_map, events, heldout, held)

    def allowed(self, t0: int, t1: int) -> bool:
        """Whether training may read the events of [t0, t1): it overlaps no held-out interval."""
        return not overlaps(self.heldout, t0, t1)

    def draw_times(
        self, rng: np.random.Generator, lc: LossConfig, moving: bool
    ) -> tuple[list[int], int] | None:
        """One iteration's ``lc.views`` render times t_0 < ... < t_last, consecutive gaps of
        random length, and the short flow window of L_ef after t_last (0 without motion); None
        when the gaps are longer than the sequence.

        The windows are placed as if the sequence went on past its ends, then pushed back
        inside it: a window placed wholly within would render the first and last instants only
        from one side, half as often as the middle, and the model's ends came out blurred
        (docs/experiments/training.md, "The MLP rate settles, and the windows reach the
        sequence's ends"). Everything the step reads, [t_0, t_last + the motion
        losses' reach), stays off the held-out intervals: a draw that overlaps one is drawn
        again, up to ``DRAW_TRIES`` times, then shortened to fit between them
        (``_between_heldout``); so with held-out windows the long L_e windows become rarer."""
        start, end = self.data.t_start_us, self.data.t_end_us
        reach = 0
        if moving:  # L_ef's window and L_m's (``objective.motion_events``) follow t_last
            reach = max(int(lc.flow_window * (end - start)), 1)
            if lc.w_motion > 0:
                reach = max(reach, int(lc.motion_window * (end - start)))
        for _ in range(DRAW_TRIES if self.heldout else 1):
            draw = [rng.uniform(lc.window_min, lc.window_max) for _ in range(lc.views - 1)]
            gaps = [int(g * (end - start)) for g in draw]
            drawn = self._placed(rng, gaps, moving, lc)
            if drawn is None:
                return None
            if self.allowed(drawn[0][0], min(drawn[0][-1] + reach, end)):
                return drawn
        return self._between_heldout(rng, gaps, drawn[1], reach)

    def _placed(
        self, rng: np.random.Generator, gaps: list[int], moving: bool, lc: LossConfig
    ) -> tuple[list[int], int] | None:
        """Render times with consecutive ``gaps``, placed as ``draw_times`` says."""
        start, end = self.data.t_start_us, self.data.t_end_us
        dtau = max(int(lc.flow_window * (end - start)), 1) if moving else 0
        span = sum(gaps)
        if span > end - start - dtau:
            return None
        t1 = int(rng.integers(start, end - dtau + span + 1))
        t1 = min(max(t1, start + span), end - dtau)
        return [t1 - sum(gaps[k:]) for k in range(len(gaps))] + [t1], dtau

    def _between_heldout(
        self, rng: np.random.Generator, gaps: list[int], dtau: int, reach: int
    ) -> tuple[list[int], int] | None:
        """Render times with ``gaps`` scaled down to fit, with ``reach`` after them, inside
        one of the spans between held-out intervals (drawn in proportion to their length);
        None when none is long enough."""
        data = self.data
        spans = [
            (a, b)
            for a, b in free_spans(self.heldout, data.t_start_us, data.t_end_us)
            if b - a > reach + len(gaps)
        ]
        if not spans:
            return None
        room = np.array([b - a - reach for a, b in spans], dtype=np.float64)
        a, b = spans[int(rng.choice(len(spans), p=room / room.sum()))]
        # Each gap keeps at least 1 µs, and all of them fit: b - a - reach > len(gaps).
        scale = min(1.0, (b - a - reach - len(gaps)) / max(sum(gaps), 1))
        gaps = [int(g * scale) + 1 for g in gaps]
        t0 = int(rng.integers(a, b - reach - sum(gaps) + 1))
        return [t0 + sum(gaps[:k]) for k in range(len(gaps) + 1)], dtau

    def log_image(self, out: RenderOut, coarse: bool = False) -> torch.Tensor:
        """Log intensity each pixel's sensor sees: its own Bayer channel, or the one channel.
        A coarse colour render keeps all three channels ``[3,h,w]``, as its binned events do."""
        img = out.image
        if self.channel_map is None:
            return log_render(img[..., 0])
        if coarse:
            return log_render(img).permute(2, 0, 1)
        return log_render(bayer_select(img, self.channel_map))

    def linearized_change(self, out: RenderOut, flow: torch.Tensor, coarse: bool) -> torch.Tensor:
        """-∇L·F (eq. 13) in the sensor's channels. A colour render is differentiated per
        channel before each pixel keeps its Bayer channel: differences across a mosaic mix
        colours, and drove the MLP's motion backwards in the oracle test
        (docs/experiments/motion.md)."""
        if self.channel_map is None:
            return linearized_brightness_change(log_render(out.image[..., 0]), flow)
        change = linearized_brightness_change(log_render(out.image).permute(2, 0, 1), flow)
        if coarse:
            return change
        return bayer_select(change.permute(1, 2, 0), self.channel_map)

    def accumulate(self, i0: int, i1: int) -> tuple[torch.Tensor, torch.Tensor, int]:
        """(ESI, event mask, event count) of the events [i0, i1) by index, the hot pixels'
        left out of the ESI and the mask: on the device, or streamed through the Rust core
        (L_e's windows span up to 30% of the recording)."""
        if self.device_events is not None:
            esi, mask, count = self.device_events.accumulate(i0, i1)
        else:
            data = self.data
            got = data.events.accumulate(i0, i1, data.c_pos, data.c_neg)
            esi, mask, count = torch.from_numpy(got[0]), torch.from_numpy(got[1]), got[2]
        if self.hot is not None:
            esi, mask = esi.masked_fill(self.hot, 0.0), mask & ~self.hot
        return esi, mask, count

    def esi(self, t0: int, t1: int, coarse: bool = False) -> tuple[torch.Tensor, torch.Tensor, int]:
        """(ESI, event mask, event count) of [t0, t1), 2x2-binned for a coarse render."""
        esi, mask, count = self.accumulate(*self.data.events.window(t0, t1))
        if coarse:
            esi, mask = bin_events(esi, mask, self.channel_map)
        return esi, mask, count

    def has_events(self, t0: int, t1: int) -> bool:
        """Whether the recording holds events in [t0, t1) (found by index, none read)."""
        i0, i1 = self.data.events.window(t0, t1)
        return i1 > i0

    def pose(self, t_us: float) -> np.ndarray:
        return self.data.trajectory.pose(float(t_us))

    def log_image_at(self, t_us: int, view: Renderer | None = None) -> torch.Tensor:
        """Render at ``t_us`` with ``view`` (default the full-resolution renderer) and log it."""
        view = view or self.renderer
        return self.log_image(view.render(t_us, self.pose(t_us)), view is not self.renderer)
