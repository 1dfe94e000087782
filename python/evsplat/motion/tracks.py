"""Moving regions chained across windows into one track per object, their number found, not
given (docs/motion.md, step 2): Hungarian assignment, hidden tracks, pieces and returns joined."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from evsplat.config import MoverConfig
from evsplat.motion.border import borders, in_image, touches_border, uncut
from evsplat.motion.segment import Blob, union

UNASSIGNED = 1e9  # cost of a pair outside the gate
#: A step over twice the track's median is not its own motion (docs/motion.md, "Tuning numbers").
JUMP = 2.0
#: Pieces whose offset holds within half their size move as one (docs/motion.md, "Tuning numbers").
RIGID = 0.5
#: A region cut under half its area is a sliver, centre unsure (docs/motion.md, "Tuning numbers").
SLIVER = 0.5


def filled(at: np.ndarray, known: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` [F,D] at ``at`` [F], those not ``known`` [F] (some are) linear between the
    known ones (held beyond them)."""
    out = values.copy()
    cols = [np.interp(at[~known], at[known], values[known, j]) for j in range(values.shape[1])]
    out[~known] = np.stack(cols, 1)
    return out


def partial(areas: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """Bool [F]: the regions of ``areas`` [F] (px) under ``SLIVER`` of the median of those not
    ``cut`` [F] by the border (none where all are)."""
    return areas < SLIVER * (np.median(areas[~cut]) if (~cut).any() else np.inf)


def step_lengths(windows: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """[F-1] px per window between the ``centres`` [F,2] sighted at the ``windows`` [F]."""
    return np.linalg.norm(np.diff(centres, axis=0), axis=1) / np.diff(windows)


def jump_limit(steps: np.ndarray | list[float]) -> float:
    """The longest of a track's ``steps`` [F-1] (px per window) that is its own motion: ``JUMP`` x
    their median (0 with none)."""
    return JUMP * float(np.median(steps)) if len(steps) else 0.0


@dataclass
class Track:
    """One object's regions by window index, and the windows whose region it shared with
    another object (its centre there is not this object's)."""

    blobs: dict[int, Blob] = field(default_factory=dict)
    shared: set[int] = field(default_factory=set)
    hidden: dict[int, Blob] = field(default_factory=dict)  # unseen, inside another's region
    missed: int = 0  # windows since the last sighting

    @property
    def times_us(self) -> np.ndarray:
        return np.array([self.blobs[k].t_us for k in sorted(self.blobs)], dtype=np.int64)

    @property
    def centres(self) -> np.ndarray:
        """[F,2] pixel centres at the sighted windows, in time order; where its region was
        shared, linear between its own."""
        ks = sorted(self.blobs)
        out = np.stack([self.blobs[k].centre for k in ks])
        own = np.array([k not in self.shared for k in ks])
        return filled(np.array(ks, dtype=np.float64), own, out) if own.any() else out

    @property
    def clear(self) -> list[int]:
        """Its windows, in order, whose region is its own (not ``shared``), of those clear of the
        image border where there are any (a cut region looks smaller); each rule dropped where
        it leaves none."""
        ks = sorted(self.blobs)
        own = [k for k in ks if k not in self.shared] or ks
        return [k for k in own if not touches_border(self.blobs[k].mask)] or own

    @property
    def radius(self) -> float:
        """The object's size (px): the median of its ``clear`` regions' disc radii."""
        return float(np.median([self.blobs[k].radius for k in self.clear]))

    @property
    def areas(self) -> np.ndarray:
        """[F] its regions' areas (px), in time order."""
        return np.array([self.blobs[k].area for k in sorted(self.blobs)])

    @property
    def cut(self) -> np.ndarray:
        """[F] bool: its regions, in time order, that touch the image border."""
        return np.array([touches_border(self.blobs[k].mask) for k in sorted(self.blobs)])

    @property
    def area(self) -> float:
        """How much of the events it explains: its regions' summed area (px x windows)."""
        return float(sum(b.area for b in self.blobs.values()))

    @property
    def steps(self) -> list[float]:
        """Px per window between its consecutive sightings."""
        ks = sorted(self.blobs)
        return step_lengths(np.array(ks), np.stack([self.blobs[k].centre for k in ks])).tolist()

    def part(self, first: int, last: int) -> Track:
        """The track at only its sightings in windows ``first`` to ``last``."""
        kept = {k: b for k, b in self.blobs.items() if first <= k <= last}
        return Track(kept, self.shared & set(kept))

    def predict(self, window: int) -> tuple[np.ndarray, float]:
        """The object's centre at ``window``: from its last sighting (shared too, its region holds
        it) at the velocity of its last own ones (a shared region moves as the pair does), and that
        speed (px per window), held to ``JUMP`` x its median step (a jump is not its motion)."""
        ks = sorted(self.blobs)
        own = [k for k in ks if k not in self.shared] or ks
        last = self.blobs[ks[-1]].centre
        if len(own) < 2:
            return last, 0.0
        velocity = (self.blobs[own[-1]].centre - self.blobs[own[-2]].centre) / (own[-1] - own[-2])
        speed = float(np.linalg.norm(velocity))
        held = min(speed, jump_limit(self.steps))
        return last + velocity * (held / max(speed, 1e-9)) * (window - ks[-1]), held


def chain(per_window: list[list[Blob]], s: MoverConfig, still: bool = False) -> list[Track]:
    """Tracks through the windows' regions (``per_window[k]``: window k's), noise dropped and
    fragments joined; the longest first. Under a ``still`` camera the static model draws no
    change, so every region is the events' own (``segment.made_by_events``) and none is dropped
    as the warm-up's error by ``s.min_evidence`` (docs/motion.md, "Tuning numbers")."""
    live: list[Track] = []
    done: list[Track] = []
    for k, blobs in enumerate(per_window):
        blobs = _split(live, blobs, k, s)
        taken = _assign(live, blobs, k, s)
        for track in live:
            if k in track.blobs:
                track.missed = 0
                continue
            # Only a confirmed track hides in another's region (noise would mark it shared).
            host = _host(track.predict(k)[0], blobs) if len(track.blobs) >= s.min_windows else None
            if host is None:
                track.missed += 1
                continue
            track.hidden[k] = host  # the host's region is not its own object's alone there
            for other in live:
                if other.blobs.get(k) is host:
                    other.shared.add(k)
        ended = [_gone(t, s) for t in live]
        done += [t for t, e in zip(live, ended) if e]
        live = [t for t, e in zip(live, ended) if not e]
        live += [Track({k: b}) for j, b in enumerate(blobs) if j not in taken]
    pieces = _merged(done + live, lambda t: -len(t.blobs), lambda o, t: together(o, t, s))
    least = 0.0 if still else s.min_evidence
    long = [(t, evidence(t, s) >= least) for t in pieces if len(t.blobs) >= s.min_windows]
    kept = _rejoined([t for t, sure in long if sure], [t for t, sure in long if not sure], s)
    # Never clear of the border: the scene's edge coming into view, or an object never seen whole.
    kept = [t for t in kept if not all(touches_border(b.mask) for b in t.blobs.values())]
    for track in kept:  # shared with another object (not noise, nor a piece of its own)
        others = [o.hidden for o in kept if o is not track]
        track.shared = {k for k, b in track.blobs.items() if any(h.get(k) is b for h in others)}
    for track in kept:  # only the objects kept (the shape fit is the costly part)
        track.blobs = uncut(track.blobs, set(track.blobs) - track.shared)
    return sorted(kept, key=lambda t: -len(t.blobs))


def _gone(track: Track, s: MoverConfig) -> bool:
    """Whether ``track`` ends: unseen (nor hidden in another's region) for over ``s.coast``
    windows, or for two after a sighting the image border cuts to a sliver (``partial``). Then
    it left the image, and what comes next, the border's noise or its return, is a track of its
    own, which ``_returns`` joins to it or drops (docs/experiments/objects.md, "A track that left
    ends in the chaining")."""
    if track.missed > s.coast:
        return True
    last = partial(track.areas, track.cut)[-1] and track.cut[-1]
    return bool(last) and track.missed >= 2


def evidence(track: Track, s: MoverConfig) -> float:
    """Its regions' peaks over ``s.high`` summed (robust sigmas)."""
    return sum(max(b.contrast - s.high, 0.0) for b in track.blobs.values())


def _sure(track: Track, s: MoverConfig) -> bool:
    """Whether ``track`` is an object by itself: ``s.min_windows`` sightings and
    ``s.min_evidence``."""
    return len(track.blobs) >= s.min_windows and evidence(track, s) >= s.min_evidence


def _split(live: list[Track], blobs: list[Blob], k: int, s: MoverConfig) -> list[Blob]:
    """Window ``k``'s ``blobs``, each joined from pieces that two or more confirmed ``live``
    tracks reach (each the piece nearest its predicted centre, within its gate) split into one
    region per such piece, the other pieces each with the nearest of them: two objects that
    came near, not pieces of one."""
    if not any(b.parts for b in blobs):
        return blobs
    gates = [_gate(t, k, s, t.missed + 1) for t in live if len(t.blobs) >= s.min_windows]
    out = []
    for blob in blobs:
        seeds: set[int] = set()
        for guess, reach in gates if blob.parts else ():
            d = [float(np.linalg.norm(p.centre - guess)) for p in blob.parts]
            n = int(np.argmin(d))
            if _in_gate(d[n], reach, blob.parts[n], s):
                seeds.add(n)
        if len(seeds) < 2:
            out.append(blob)
            continue
        groups: dict[int, list[Blob]] = {n: [] for n in sorted(seeds)}
        for part in blob.parts:
            near = min(groups, key=lambda n: np.linalg.norm(blob.parts[n].centre - part.centre))
            groups[near].append(part)
        out += [functools.reduce(union, parts) for parts in groups.values()]
    return out


def _gate(track: Track, k: int, s: MoverConfig, unseen: int) -> tuple[np.ndarray, float]:
    """(``track``'s predicted centre at window ``k``, how far from it its object may be: ``s.gate``
    x its size or its steps over the ``unseen`` windows since its last sighting)."""
    guess, speed = track.predict(k)
    return guess, s.gate * max(track.radius, speed * unseen)


def _in_gate(d: float, reach: float, blob: Blob, s: MoverConfig) -> bool:
    """Whether a region ``blob`` whose centre is ``d`` px from a track's prediction is within
    the track's ``reach`` (``_gate``) widened by ``s.gate`` x the region's size."""
    return d <= reach + blob.radius * s.gate


def _host(guess: np.ndarray, blobs: list[Blob]) -> Blob | None:
    """The region an unseen object's predicted centre lies in, if any (it passes behind that
    object or merges with it in the image)."""
    px = np.floor(guess).astype(np.int64)
    return next((b for b in blobs if in_image(px, b.mask.shape) and b.mask[px[1], px[0]]), None)


def _assign(live: list[Track], blobs: list[Blob], k: int, s: MoverConfig) -> set[int]:
    """Give window ``k``'s ``blobs`` to the ``live`` tracks (Hungarian on the distance from each
    track's prediction, within its gate); the indices taken. Confirmed tracks choose first
    (SORT's cascade): a new track must not take an object's next region."""
    confirmed = [len(t.blobs) >= s.min_windows for t in live]
    sides = [borders(b.mask) for b in blobs]
    taken: set[int] = set()
    for tracks in (
        [t for t, c in zip(live, confirmed) if c],
        [t for t, c in zip(live, confirmed) if not c],
    ):
        free = [j for j in range(len(blobs)) if j not in taken]
        cost = np.full((len(tracks), len(free)), UNASSIGNED)
        for i, track in enumerate(tracks):
            guess, reach = _gate(track, k, s, track.missed + 1)
            # Unseen since a sighting at a border, it left the image: it comes back there.
            out = borders(track.blobs[max(track.blobs)].mask) if track.missed else set()
            for n, j in enumerate(free):
                d = float(np.linalg.norm(blobs[j].centre - guess))
                back = not out or out & sides[j]
                if _in_gate(d, reach, blobs[j], s) and back:
                    cost[i, n] = d
        for i, n in zip(*linear_sum_assignment(cost)):
            if cost[i, n] < UNASSIGNED:
                tracks[i].blobs[k] = blobs[free[n]]
                taken.add(free[n])
    return taken


def together(a: Track, b: Track, s: MoverConfig) -> bool:
    """Whether ``a`` and ``b`` are pieces of one object: in four in five of their shared windows
    their centres lie within ``s.together`` x the tracks' summed sizes (a piece's region looks
    smaller than its object); or, in ``s.min_windows`` or more, they moved by the smaller one's
    size with their offset held within ``RIGID`` of it (a plain object's two edges)."""
    shared = sorted(set(a.blobs) & set(b.blobs))
    if not shared:
        return False
    offset = np.stack([a.blobs[k].centre - b.blobs[k].centre for k in shared])
    radii = (a.radius, b.radius)
    near = np.linalg.norm(offset, axis=1) <= s.together * sum(radii)
    drift = np.quantile(np.linalg.norm(offset - np.median(offset, 0), axis=1), 0.8)
    travel = np.linalg.norm(a.blobs[shared[-1]].centre - a.blobs[shared[0]].centre)
    rigid = len(shared) >= s.min_windows and drift <= RIGID * min(radii) and min(radii) <= travel
    return bool(rigid or np.mean(near) >= 0.8)


def _merged(
    tracks: list[Track], order: Callable[[Track], int], fits: Callable[[Track, Track], bool]
) -> list[Track]:
    """``tracks`` in ``order``, each merged into the first of those before it that it ``fits``:
    per shared window one region (the masks' union)."""
    out: list[Track] = []
    for track in sorted(tracks, key=order):
        home = next((o for o in out if fits(o, track)), None)
        if home is None:
            out.append(track)
            continue
        _absorb(home, track)
    return out


def _absorb(home: Track, track: Track) -> None:
    """``track``'s sightings added to ``home``'s: per shared window one region (the masks'
    union); its hidden windows where ``home`` has none."""
    for k, blob in track.blobs.items():
        home.blobs[k] = blob if k not in home.blobs else union(home.blobs[k], blob)
    home.hidden |= {k: b for k, b in track.hidden.items() if k not in home.blobs}


def _rejoined(tracks: list[Track], faint: list[Track], s: MoverConfig) -> list[Track]:
    """``tracks``, each that is an object coming back into the image joined to the latest-ending
    earlier track it ``_returns`` to, which keeps its sightings up to its exit. A ``faint`` track
    (no object by itself) joins only one it ``_resumes`` or that resumes it inside the image (an
    object's spell unseen there), not through the border, where the static model's errors lie;
    faint tracks joined only to each other are kept where their ``evidence`` together passes
    ``s.min_evidence``, the rest dropped."""
    out: list[Track] = []
    weak = {id(t) for t in faint}

    def joins(gone: Track, back: Track) -> int | None:
        return _returns(gone, back, s, through_border=not {id(gone), id(back)} & weak)

    for track in sorted([*tracks, *faint], key=lambda t: min(t.blobs)):
        exits = [(o, a) for o in out if (a := joins(o, track)) is not None]
        if not exits:
            out.append(track)
            continue
        home, a = max(exits, key=lambda e: max(e[0].blobs))
        home.blobs = {k: b for k, b in home.blobs.items() if k <= a}
        _absorb(home, track.part(a + 1, max(track.blobs)))
        if id(track) not in weak:
            weak.discard(id(home))  # joined to an object: part of it
    return [t for t in out if id(t) not in weak or _sure(t, s)]  # each has min_windows


def _returns(gone: Track, back: Track, s: MoverConfig, through_border: bool = True) -> int | None:
    """The window ``gone`` left the image at if ``back`` is it coming back, else None: after the
    exit (a sighting after which ``gone`` took no object by itself, ``_sure``) ``back`` enters by
    the border ``gone`` left through, within ``s.gate`` of the fastest speed's reach plus both
    radii, sizes ``s.gate`` apart at most, its sightings before all at the border and those
    after an object (the noise either took is dropped on joining). Or ``back`` ``_resumes``
    ``gone`` inside the image, the only way without ``through_border``."""
    clear = [not all(touches_border(r.mask) for r in t.blobs.values()) for t in (gone, back)]
    whole = [t.radius for t, c in zip((gone, back), clear) if c]  # a cut one's looks smaller
    if whole and max(gone.radius, back.radius) > s.gate * min(whole):
        return None
    if _resumes(gone, back, s):
        return max(gone.blobs)
    if not through_border:
        return None
    for a in sorted(gone.blobs)[::-1]:
        if _sure(gone.part(a + 1, max(gone.blobs)), s):
            break  # it went on as an object: no exit at or before this sighting
        exit_, later = gone.blobs[a], back.part(a + 1, max(back.blobs))
        if not later.blobs:
            continue
        b = min(later.blobs)
        entry, noise = later.blobs[b], [r for k, r in back.blobs.items() if k <= a]
        if not borders(exit_.mask) & borders(entry.mask):
            continue
        # Before the exit, only the border's noise; after it, an object by its own sightings.
        if noise and not (all(touches_border(r.mask) for r in noise) and _sure(later, s)):
            continue
        speed = max(gone.part(min(gone.blobs), a).steps + later.steps, default=0.0)
        reach = s.gate * (speed * (b - a) + exit_.radius + entry.radius)
        if np.linalg.norm(entry.centre - exit_.centre) <= reach:
            return a
    return None


def _resumes(gone: Track, back: Track, s: MoverConfig) -> bool:
    """Whether ``back`` starts where ``gone``, a kept track lost inside the image more than
    ``s.coast`` + 1 windows before, would be found had it coasted on: both clear of the border
    there, ``back``'s first region within ``gone``'s gate over the windows between. An object
    passing one that fires more can go unseen that long; within ``coast`` the chaining has
    decided already (docs/experiments/objects.md, "An object lost inside the image")."""
    a, b = max(gone.blobs), min(back.blobs)
    exit_, entry = gone.blobs[a], back.blobs[b]
    if b - a <= s.coast + 1 or touches_border(exit_.mask) or touches_border(entry.mask):
        return False
    guess, reach = _gate(gone, b, s, b - a)
    return _in_gate(float(np.linalg.norm(entry.centre - guess)), reach, entry, s)


def on_its_line(track: Track, s: MoverConfig) -> Track:
    """The ``track`` less a first or last run of regions beside its line (``beside_line``):
    something else's, taken before the object was seen (after it was last seen)."""
    ks = np.array(sorted(track.blobs))
    masks = [track.blobs[k].mask for k in ks]
    beside = beside_line(ks, track.centres, masks, s.coast, s.min_windows)
    kept = [k for k, off in zip(ks, beside) if not off]
    return track.part(kept[0], kept[-1]) if beside.any() else track


def beside_line(
    windows: np.ndarray, centres: np.ndarray, masks: list[np.ndarray], longest: int, n: int
) -> np.ndarray:
    """Bool [F] over the sightings at ``windows`` [F], ``centres`` [F,2] px: a first (last) run of
    at most ``longest`` before a jump (a step over ``JUMP`` x the median) whose regions ``masks``
    [F] all miss where the line through the ``n`` sightings after (before) it, with no jump
    between them, puts the object: something else's regions, taken before it was seen (after it
    was last seen). A region that holds the object joined with another is its own."""
    step = step_lengths(windows, centres)
    out = np.zeros(len(centres), dtype=bool)
    if step.size < 2:
        return out
    limit = jump_limit(step)
    for order in (np.arange(len(centres)), np.arange(len(centres))[::-1]):
        ahead = range(min(longest, len(order) - 1))
        jump = next((i for i in ahead if step[min(order[i], order[i + 1])] > limit), None)
        if jump is None or len(order) < jump + 1 + n:
            continue
        run, used = order[: jump + 1], order[jump + 1 : jump + 1 + n]
        if any(step[min(a, b)] > limit for a, b in zip(used, used[1:])):
            continue
        fit = np.polyfit(windows[used].astype(np.float64), centres[used], 1)  # [2,2]
        at = np.floor(fit[0] * windows[run, None] + fit[1]).astype(np.int64)
        # Beyond the image border no region can hold it: not told there.
        holds = [not in_image(p, masks[i].shape) or masks[i][p[1], p[0]] for p, i in zip(at, run)]
        out[run] = not any(holds)
    return out
